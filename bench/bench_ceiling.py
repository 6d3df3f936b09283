"""Does the ceiling term earn its row? Ceiling coverage and the Ce ablation on the demo world.

The demo world (``bimcap demo``'s building with its suspended ceilings, the as-built variant,
the 60-frame handheld walk at 516×386, default simulator settings) is simulated once. Then:

1. **Coverage**, per frame: ground-truth ceiling pixels in ``labels/``, LiDAR returns that land
   on them (the scan projected into the raw image, :func:`bimcap.fusion.project_lidar`), and the
   front end's ceiling samples (default ``RefineConfig``: LiDAR + linear interpolation, the
   geometric segmenter) and how many of them the problem keeps (a BIM ceiling plane over them).
2. **Ablation**: for each drift preset and seed, the default BIMCaP run with terms
   ``G+F+W+Co`` and ``G+F+W+Co+Ce`` on the same front end; ATE_pos / ATE_rot, mean and worst.

Nothing is tuned here: the solver settings are the defaults.

Usage::

    PYTHONPATH=python BIMCAP_SOLVE=build/dev/cpp/bimcap_solve \
        python bench/bench_ceiling.py --work /tmp/ceiling --experiments exp2,exp1 --seeds 1,2,3
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

TERMS = ("G+F+W+Co", "G+F+W+Co+Ce")


def coverage(seq, prepared) -> None:  # bench script
    from bimcap.fusion import project_lidar
    from bimcap.labels import Label
    from bimcap.pipeline.refine import build_problem

    n = len(seq.frames)
    gt_px, lidar_px = np.zeros(n, int), np.zeros(n, int)
    for i in range(n):
        lab = seq.load_labels(i)
        gt_px[i] = int((lab == Label.CEILING).sum())
        sparse = project_lidar(seq.load_lidar(i), seq.cam_from_lidar, seq.camera, distort=True)
        v = np.rint(sparse.uv[:, 1]).astype(int)
        u = np.rint(sparse.uv[:, 0]).astype(int)
        lidar_px[i] = int((lab[v, u] == Label.CEILING).sum())
    fe = prepared.frontend
    samples = np.bincount(fe.ceiling_frame, minlength=n)
    _, stats = build_problem(prepared)
    print(f"frames {n}: GT ceiling pixels in {np.count_nonzero(gt_px)} frames "
          f"(mean {gt_px.mean():.0f} px / frame, {gt_px.sum() / (n * lab.size):.1%} of all pixels)")
    print(f"LiDAR returns on GT ceiling pixels: {lidar_px.sum()} in {np.count_nonzero(lidar_px)} "
          f"frames (mean {lidar_px.mean():.1f} / frame, max {lidar_px.max()})")
    print(f"front-end ceiling samples: {samples.sum()} in {np.count_nonzero(samples)} frames "
          f"(mean {samples.mean():.1f} / frame, max {samples.max()}); floor "
          f"{len(fe.floor_frame)}, wall {len(fe.wall_frame)}, column {len(fe.column_frame)}")
    print(f"problem at the initial poses: {stats.to_dict()}")
    print("per frame (GT ceiling px / LiDAR returns on them / samples): "
          + " ".join(f"{i}:{gt_px[i]}/{lidar_px[i]}/{samples[i]}" for i in range(n)
                     if gt_px[i] or samples[i]))


def run(args: argparse.Namespace) -> None:
    from bimcap.dataset import add_trajectory, read_sequence
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.demo import DemoOptions, make_sequence, make_world
    from bimcap.pipeline.refine import prepare, solve_prepared
    from bimcap.sim.drift import DriftParams, apply_drift

    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    world = DemoOptions(frames=args.frames, scale=args.scale, seed=args.world_seed)
    design, built = make_world(work, world, quiet=True)
    seq_dir = make_sequence(work, design, built, world, quiet=True)
    seq = read_sequence(seq_dir)
    gt = seq.trajectory("gt")
    base = RefineConfig(workers=1)
    t0 = time.perf_counter()
    prepared = prepare(seq, design, None, base, work / "run", quiet=True)
    print(f"front end {time.perf_counter() - t0:.1f} s", flush=True)
    coverage(seq, prepared)
    if args.coverage_only:
        return
    rows: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for exp in args.experiments.split(","):
        for seed in [int(s) for s in args.seeds.split(",")]:
            name = f"init_{exp}_s{seed}"
            if not seq.has_trajectory(name):
                drift = apply_drift(gt, DriftParams.from_preset(exp, seed=seed))
                add_trajectory(seq, name, drift.init, header=f"bimcap drift {exp} seed {seed}")
                seq = read_sequence(seq_dir)
            prep = prepare(seq, design, seq.trajectory_path(name), base, work / "run", quiet=True)
            m0 = trajectory_metrics(prep.init.poses, gt.poses, AlignMode.NONE)
            line = [f"{exp} s{seed}: init {m0.ate_pos_m.rmse * 100:.1f} cm / "
                    f"{m0.ate_rot_deg.rmse:.2f}°"]
            for terms in TERMS:
                t = time.perf_counter()
                res = solve_prepared(prep, replace(base, terms=terms), quiet=True)
                m = trajectory_metrics(res.refined.poses, gt.poses, AlignMode.NONE)
                rows.setdefault((exp, terms), []).append((m.ate_pos_m.rmse, m.ate_rot_deg.rmse))
                line.append(f"{terms}: {m.ate_pos_m.rmse * 100:.2f} cm / "
                            f"{m.ate_rot_deg.rmse:.3f}° (Ce samples {res.problem_stats.ceiling}, "
                            f"{time.perf_counter() - t:.0f} s)")
            print(" | ".join(line), flush=True)
    print("\n| drift | terms | runs | ATE_pos mean / worst [cm] | ATE_rot mean / worst [°] |")
    print("|---|---|---|---|---|")
    for (exp, terms), v in rows.items():
        a = np.asarray(v)
        print(f"| {exp} | {terms} | {len(a)} | {a[:, 0].mean() * 100:.2f} / "
              f"{a[:, 0].max() * 100:.2f} | {a[:, 1].mean():.3f} / {a[:, 1].max():.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/bimcap_ceiling", help="world, sequence and caches")
    ap.add_argument("--experiments", default="exp2,exp1", help="drift presets")
    ap.add_argument("--seeds", default="1,2,3", help="drift seeds, comma list")
    ap.add_argument("--world-seed", type=int, default=0, help="building and walk seed")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--coverage-only", action="store_true", help="skip the ablation")
    run(ap.parse_args())


if __name__ == "__main__":
    main()
