"""Convergence basin of the whole refinement (front end + [coarse stage +] bundle adjustment) on
the demo world, with and without the coarse stage.

The demo world (``bimcap demo``'s building, as-built deviations, 60-frame walk at 516×386) is
simulated once and its front end (linear depth interpolation, geometric segmenter, SIFT) run
once; each drift level then draws ``--seeds`` initial trajectories with the paper's drift model
(``bimcap.sim.drift``, the exp1 preset's shape: a translation random walk and per-frame pitch and
yaw offsets) rescaled to exactly ATE_pos = k × 1.391 m and ATE_rot = k × 9.99° (k = 1 is the
paper's Exp. 1), and solves each one with the default ``RefineConfig`` (coarse on) and with
``coarse=False``. A run converges when ATE_pos ≤ 5 cm and ATE_rot ≤ 0.5° (the issue's Exp. 1
target). The basin is the largest level up to which (that level and every smaller one) at
least 95 % of the seeds converge.

Usage (two processes on two cores: split the seeds, then summarise both files)::

    PYTHONPATH=python python bench/bench_basin_pipeline.py --work /tmp/basin \
        --levels 0.5,1,1.5,2,2.5 --seeds 1-10 --out /tmp/basin/a.csv
    PYTHONPATH=python python bench/bench_basin_pipeline.py \
        --summarise /tmp/basin/a.csv /tmp/basin/b.csv
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

EXP1_POS_M, EXP1_ROT_DEG = 1.391, 9.99
CONVERGED_POS_M, CONVERGED_ROT_DEG = 0.05, 0.5
FIELDS = ("level", "seed", "variant", "init_pos_m", "init_rot_deg", "init_yaw_deg", "pos_m",
          "rot_deg", "yaw_deg", "converged", "solve_s", "coarse_s")


def _seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def run(args: argparse.Namespace) -> None:
    from bimcap.dataset import read_sequence
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.demo import DemoOptions, make_sequence, make_world
    from bimcap.pipeline.refine import prepare, solve_prepared
    from bimcap.sim.drift import DriftParams, apply_drift

    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    world = DemoOptions(frames=args.frames, scale=args.scale)
    design, built = make_world(work, world, quiet=True)
    seq = read_sequence(make_sequence(work, design, built, world, quiet=True))
    gt = seq.trajectory("gt")
    base = RefineConfig(workers=1)
    t0 = time.perf_counter()
    prepare(seq, design, gt, base, work / "run", quiet=True)  # the front end, cached
    print(f"front end {time.perf_counter() - t0:.1f} s", flush=True)

    out = Path(args.out)
    new = not out.exists()
    with out.open("a", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS)
        if new:
            w.writeheader()
        for level in [float(x) for x in args.levels.split(",")]:
            for seed in _seeds(args.seeds):
                params = DriftParams.from_preset("exp1", seed=seed,
                                                 target_ate_pos_m=level * EXP1_POS_M,
                                                 target_ate_rot_deg=level * EXP1_ROT_DEG)
                init = apply_drift(gt, params).init
                prep = prepare(seq, design, init, base, work / "run", quiet=True)
                m0 = trajectory_metrics(init.poses, gt.poses, AlignMode.NONE)
                for variant in args.variants.split(","):
                    cfg = replace(base, coarse=variant == "coarse")
                    t = time.perf_counter()
                    res = solve_prepared(prep, cfg, quiet=True)
                    dt = time.perf_counter() - t
                    m = trajectory_metrics(res.refined.poses, gt.poses, AlignMode.NONE)
                    ok = (m.ate_pos_m.rmse <= CONVERGED_POS_M
                          and m.ate_rot_deg.rmse <= CONVERGED_ROT_DEG)
                    row = {"level": level, "seed": seed, "variant": variant,
                           "init_pos_m": m0.ate_pos_m.rmse, "init_rot_deg": m0.ate_rot_deg.rmse,
                           "init_yaw_deg": m0.yaw_rmse_deg, "pos_m": m.ate_pos_m.rmse,
                           "rot_deg": m.ate_rot_deg.rmse, "yaw_deg": m.yaw_rmse_deg,
                           "converged": int(ok), "solve_s": dt,
                           "coarse_s": (res.coarse or {}).get("seconds", 0.0)}
                    w.writerow(row)
                    fh.flush()
                    print(f"k={level:g} seed {seed:2d} {variant:9s} "
                          f"{m0.ate_pos_m.rmse:.2f} m/{m0.ate_rot_deg.rmse:.1f}° → "
                          f"{m.ate_pos_m.rmse:.3f} m/{m.ate_rot_deg.rmse:.2f}° "
                          f"{'ok' if ok else 'FAIL'} ({dt:.1f} s)", flush=True)


def summarise(paths: list[str]) -> None:
    rows = []
    for p in paths:
        with open(p, newline="") as fh:
            rows += list(csv.DictReader(fh))
    variants = sorted({r["variant"] for r in rows})
    levels = sorted({float(r["level"]) for r in rows})
    print("| level k | initial ATE_pos / ATE_rot / yaw RMSE | "
          + " | ".join(f"{v}: converged, median ATE_pos / ATE_rot, median time" for v in variants)
          + " |")
    print("|---|---|" + "---|" * len(variants))
    basin: dict[str, float | None] = dict.fromkeys(variants)
    broken = dict.fromkeys(variants, False)  # the basin ends at the first level that fails
    for k in levels:
        at = [r for r in rows if float(r["level"]) == k]
        init = at[0]
        cells = []
        for v in variants:
            rv = [r for r in at if r["variant"] == v]
            n_ok = sum(int(r["converged"]) for r in rv)
            frac = n_ok / len(rv) if rv else math.nan
            if frac >= 0.95 and not broken[v]:
                basin[v] = k
            else:
                broken[v] = True
            cells.append(f"{n_ok}/{len(rv)}, {np.median([float(r['pos_m']) for r in rv]):.3f} m / "
                         f"{np.median([float(r['rot_deg']) for r in rv]):.2f}°, "
                         f"{np.median([float(r['solve_s']) for r in rv]):.1f} s")
        yaw = np.mean([float(r["init_yaw_deg"]) for r in at])
        print(f"| {k:g} | {float(init['init_pos_m']):.2f} m / {float(init['init_rot_deg']):.1f}° / "
              f"{yaw:.1f}° | " + " | ".join(cells) + " |")
    for v in variants:
        k = basin[v]
        print(f"basin ({v}): " + ("none of the levels" if k is None else
                                   f"k = {k:g} → ATE_pos {k * EXP1_POS_M:.2f} m, "
                                   f"ATE_rot {k * EXP1_ROT_DEG:.1f}°"))
    coarse = [r for r in rows if r["variant"] == "coarse"]
    if coarse:
        share = [float(r["coarse_s"]) / float(r["solve_s"]) for r in coarse]
        print(f"coarse stage share of the solve time: median {np.median(share):.0%}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/bimcap_basin", help="world, sequence and caches")
    ap.add_argument("--levels", default="0.5,1,1.5,2,2.5", help="multiples of the Exp. 1 drift")
    ap.add_argument("--seeds", default="1-20", help="'a-b' or a comma list")
    ap.add_argument("--variants", default="coarse,no_coarse")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--out", default="basin.csv", help="CSV, appended to")
    ap.add_argument("--summarise", nargs="+", metavar="CSV", help="only print the table")
    args = ap.parse_args()
    if args.summarise:
        summarise(args.summarise)
    else:
        run(args)
        summarise([args.out])


if __name__ == "__main__":
    main()
