"""Real IFC models as worlds: where the simulator walks, how fast it finds out, and how well
BIMCaP refines on them.

Part 1 (always): for every IFC in ``--ifc-dir`` (default ``../shared/data/ifc``), load it, lay the
missing floors, survey every storey (``bimcap.sim.walkable.choose_free_space``) and plan a 60 s
walk; print the chosen storey, its connected walkable area, the seconds of the survey and of the
planning, and the share of walk poses that are indoors (a roof within 4 m above, no triangle
within 0.2 m).

Part 2 (``--refine``): for the models named by ``--refine`` (e.g. ``AC20-FZK-Haus,Duplex``),
simulate a sequence (``--frames`` frames at ``--scale``), then refine it with the default
``RefineConfig`` from the ground truth and from the exp2 drift of each ``--seeds``; print
ATE_pos / ATE_rot before and after and the plane check. Sequences and runs go to ``--work``.

Usage::

    PYTHONPATH=python python bench/bench_real_worlds.py
    PYTHONPATH=python python bench/bench_real_worlds.py --refine AC20-FZK-Haus,Duplex \\
        --frames 50 --scale 0.25 --seeds 1,2 --work /tmp/real_worlds
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/'s own helpers
from shared_paths import shared_ifc_dir

REPO = Path(__file__).resolve().parents[1]


def survey(ifc: Path) -> dict[str, object]:
    from bimcap.bim import load_model
    from bimcap.labels import Label
    from bimcap.sim.render import World
    from bimcap.sim.simulator import missing_floor_parts, model_parts
    from bimcap.sim.walk import plan_walk
    from bimcap.sim.walkable import Level, choose_free_space, door_footprints

    t0 = time.perf_counter()
    model = load_model(ifc)
    t_load = time.perf_counter() - t0
    t0 = time.perf_counter()
    parts = model_parts(model)
    floors, _ = missing_floor_parts(model)
    doors = door_footprints([p for p in parts if p.label == Label.DOOR])
    world = World.from_parts([p for p in parts if p.label != Label.DOOR] + floors)
    t_world = time.perf_counter() - t0
    t0 = time.perf_counter()
    choice = choose_free_space(world, [Level(s.name, s.elevation_m) for s in model.storeys],
                               door_polygons=doors, model_name=ifc.name)
    t_survey = time.perf_counter() - t0
    t0 = time.perf_counter()
    walk = plan_walk(choice.free, 60.0, np.random.default_rng(0))
    t_plan = time.perf_counter() - t0
    poses = walk.poses(np.arange(0.0, walk.duration, 0.1))
    up = world.cast(poses[:, :3], np.tile([0.0, 0.0, 1.0], (len(poses), 1)))["t_hit"]
    clear = world.distance(poses[:, :3])
    chosen = next(s for s in choice.surveys if s.name == choice.level.name)
    return {
        "model": ifc.name, "storey": choice.level.name, "walkable_m2": chosen.walkable_m2,
        "storeys": len(choice.surveys), "synthetic_floors": len(floors), "load_s": t_load,
        "world_s": t_world, "survey_s": t_survey, "plan_s": t_plan,
        "indoors": float(np.mean((up < 4.0) & (clear > 0.2))),
    }


def refine_runs(ifc: Path, work: Path, frames: int, scale: float, seeds: list[int]) -> list[dict]:
    from bimcap.dataset import read_sequence
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import prepare, solve_prepared
    from bimcap.sim.drift import DriftParams, apply_drift
    from bimcap.sim.simulator import CONSLAM_CAMERA, SimulatorConfig, simulate

    seq_dir = work / ifc.stem / "sequence"
    if not (seq_dir / "manifest.json").is_file():
        simulate(ifc, seq_dir, SimulatorConfig(camera=CONSLAM_CAMERA.scaled(scale), frames=frames,
                                               workers=1), seed=0)
    seq = read_sequence(seq_dir)
    gt = seq.trajectory("gt")
    inits = {"gt": gt}
    for s in seeds:
        inits[f"exp2-{s}"] = apply_drift(gt, DriftParams.from_preset("exp2", seed=s)).init
    rows = []
    cfg = RefineConfig(workers=1)
    for name, init in inits.items():
        prep = prepare(seq, None, init, cfg, work / ifc.stem / name, quiet=True)
        out = solve_prepared(prep, cfg, quiet=True)
        before = trajectory_metrics(init.poses, gt.poses, AlignMode.NONE)
        after = trajectory_metrics(out.refined.poses, gt.poses, AlignMode.NONE)
        rows.append({"model": ifc.stem, "init": name,
                     "before": (before.ate_pos_m.rmse, before.ate_rot_deg.rmse),
                     "after": (after.ate_pos_m.rmse, after.ate_rot_deg.rmse),
                     "plane_check": [c.message() for c in out.plane_checks]})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ifc-dir", type=Path, default=shared_ifc_dir())
    ap.add_argument("--refine", default="", help="comma-separated model name prefixes")
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bimcap_real_worlds"))
    args = ap.parse_args()
    ifcs = sorted(args.ifc_dir.glob("*.ifc"))
    print(f"{'model':<26}{'storey':<14}{'walkable m2':>12}{'load s':>8}{'survey s':>9}"
          f"{'plan s':>8}{'indoors':>9}")
    for ifc in ifcs:
        r = survey(ifc)
        print(f"{r['model']:<26}{r['storey']:<14}{r['walkable_m2']:>12.1f}{r['load_s']:>8.1f}"
              f"{r['survey_s']:>9.1f}{r['plan_s']:>8.1f}{r['indoors']:>9.2f}", flush=True)
    wanted = [w for w in args.refine.split(",") if w]
    seeds = [int(s) for s in args.seeds.split(",") if s]
    for ifc in ifcs:
        if any(ifc.name.startswith(w) for w in wanted):
            for r in refine_runs(ifc, args.work, args.frames, args.scale, seeds):
                b, a = r["before"], r["after"]
                print(f"{r['model']:<22}{r['init']:<9} ATE {100 * b[0]:6.1f} cm {b[1]:5.2f}° -> "
                      f"{100 * a[0]:5.2f} cm {a[1]:5.3f}°  " + " | ".join(r["plane_check"]),
                      flush=True)


if __name__ == "__main__":
    main()
