"""Benchmark of the global alignment (issue 15): a trajectory in its own SLAM frame, placed in
the BIM with no initial guess.

Two levels:

* ``registration`` (default, fast): per world and seed, 60 poses of the building's walk (0.25 m
  apart) are ray-cast into labelled samples (:mod:`bimcap.registration.synthetic`, 5 % clutter),
  drifted with the Exp 2 preset and moved into a random SLAM frame (``bimcap drift
  --slam-frame``: yaw 0-360°, x/y ±50 m, z ±5 m). :func:`bimcap.registration.global_align`
  then either places it (right: mean camera error < 1 m and yaw error < 10°, inside
  the coarse stage's 2 m / 20° reach; wrong otherwise), flags it as ambiguous, or raises an
  error. "Silently wrong" = a wrong placement that was not flagged: the target is 0.
* ``--pipeline N``: the whole ``bimcap refine`` on N simulated demo-building sequences (60
  frames at 1/8 resolution) from a ``--slam-frame`` trajectory and from the same drift in the
  BIM frame (an aligned start): final ATE of both, target ≤ 2 cm / 0.3° (the Exp 2 level).

Worlds (generated buildings, :mod:`bimcap.sim.building`): ``demo`` (a corridor with 3 + 3 rooms
and columns), ``long`` (a 24 m corridor, 5 + 4 rooms of jittered widths), ``tiny`` (a corridor
and two rooms: nearly symmetric), ``stack`` (two storeys of different layouts, demo below and
long above: the storey must be found), ``tower`` (three identical storeys: every run must be
flagged, the storey cannot be known). Run::

    PYTHONPATH=python python bench/bench_global.py --seeds 20 [--worlds demo,long] [--csv F]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/'s own helpers
from shared_paths import shared_ifc_dir

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class World:
    """A world of the registration level: its plan and, per storey, the scene to ray-cast and
    the walk."""

    name: str
    plan: Any  # FloorPlan
    scenes: list[Any]  # Scene per storey
    tours: list[F64]  # (T, 2) per storey
    closed: bool = True  # the tours are closed loops (walked three times round)


def _building(spec: Any, seed: int) -> Any:
    from bimcap.sim.building import generate_building

    return generate_building(spec, seed=seed).truth


def _storey_parts(truth: Any, k: int, dx: float = 0.0) -> tuple[Any, F64, tuple[float, float]]:
    from bimcap.registration.synthetic import Scene

    st = truth.storeys[k]
    out = truth.plan_outline(k, st.floor_z + 1.0)
    seg = out.segments + np.array([dx, 0.0, dx, 0.0])
    scene = Scene(seg, out.segment_class.astype(np.int32), st.floor_z, st.ceiling_z)
    tour = truth.free_space[k].tour_xy() + np.array([dx, 0.0])
    return scene, tour, (st.floor_z - 0.05, st.wall_top_z)


def _world(name: str) -> World:
    from bimcap.registration import FloorPlan
    from bimcap.registration.synthetic import Scene
    from bimcap.sim.building import BuildingSpec

    specs = {"demo": (BuildingSpec.demo(), 0), "tiny": (BuildingSpec.tiny(), 0),
             "long": (BuildingSpec(corridor_length_m=24.0, rooms_north=5, rooms_south=4,
                                   room_width_jitter=0.3), 1),
             "tower": (BuildingSpec.tower(), 0)}
    parts: list[tuple[Any, F64, tuple[float, float]]] = []
    if name == "stack":
        lower = _building(*specs["demo"])
        upper = _building(BuildingSpec(storeys=2, corridor_length_m=24.0, rooms_north=5,
                                       rooms_south=4, room_width_jitter=0.3), 1)
        parts = [_storey_parts(lower, 0), _storey_parts(upper, 1, dx=-3.0)]
    else:
        truth = _building(*specs[name])
        parts = [_storey_parts(truth, k) for k in range(len(truth.storeys))]
    seg = np.concatenate([p[0].segments for p in parts])
    cls = np.concatenate([p[0].segment_class for p in parts])
    seg_z = np.concatenate([np.tile(p[2], (len(p[0].segments), 1)) for p in parts])
    plan = FloorPlan(seg, cls, seg_z, np.array([p[0].floor_z for p in parts]),
                     np.array([p[0].ceiling_z for p in parts]))
    scenes: list[Scene] = [p[0] for p in parts]
    return World(name, plan, scenes, [p[1] for p in parts])



def _ifc_world(name: str, ifc_dir: Path, min_walkable_m2: float = 10.0,
               height_tol_m: float | None = None) -> World:
    """A real model as a world of the registration level: the plan is the BIM reference's
    (every storey, as ``bimcap refine`` builds it; cached in ``$BIMCAP_CACHE_DIR``); each storey
    the walker can walk (:func:`bimcap.sim.walkable.survey_level` on the model's meshes, door
    leaves removed, at least ``min_walkable_m2``) gives a scene, its plan section extruded from
    its floor to its ceiling (2.5 m above the floor where the plan has none: a pitched roof),
    and a walk through its free space (:func:`bimcap.sim.walk.plan_walk`, 120 s, one fixed
    draw: the seeds pick where along it the 60 frames start). ``height_tol_m``: floor planes
    merged within this (:class:`bimcap.bim.planes.PlaneOptions`; None: the default, and the
    reference comes from the cache; otherwise it is built here, uncached)."""
    from bimcap.bim import load_model
    from bimcap.bim.cache import reference_for
    from bimcap.bim.planes import PlaneOptions
    from bimcap.bim.reference import ReferenceOptions, build_reference
    from bimcap.labels import Label
    from bimcap.registration import FloorPlan, GlobalAlignOptions
    from bimcap.registration.global_align import _storeys
    from bimcap.registration.synthetic import Scene
    from bimcap.sim.render import World as MeshWorld
    from bimcap.sim.simulator import missing_floor_parts, model_parts
    from bimcap.sim.walk import WalkConfig, plan_walk
    from bimcap.sim.walkable import Level, WalkableOptions, door_footprints, survey_level

    ifc = ifc_dir / f"{name.removeprefix('ifc-')}.ifc"
    if not ifc.is_file():
        raise SystemExit(f"{ifc}: not found (the real IFCs live in ../shared/data/ifc)")
    model = load_model(ifc)
    if height_tol_m is None:
        ref, _ = reference_for(ifc, None)
    else:
        ref = build_reference(model, ReferenceOptions(planes=PlaneOptions(
            height_tol_m=height_tol_m)))
    plan = FloorPlan.from_planes(ref.segments, ref.segment_class, ref.segment_z, ref.planes,
                                 ref.plane_kind)
    sections = _storeys(plan, GlobalAlignOptions().plan_cut_height_m)
    parts = model_parts(model)
    parts += missing_floor_parts(model)[0]
    doors = door_footprints([p for p in parts if p.label == Label.DOOR])
    mesh = MeshWorld.from_parts([p for p in parts if p.label != Label.DOOR], seed=0)
    cfg = WalkConfig()
    scenes, tours = [], []
    for st in model.storeys:
        survey, free = survey_level(mesh, Level(st.name, st.elevation_m), doors, cfg,
                                    WalkableOptions(resolution_m=cfg.grid_m))
        if survey.walkable_m2 < min_walkable_m2:
            continue
        near = [s for s in sections if s.floor_z is not None
                and abs(s.floor_z - free.z_floor) < 0.5]
        if not near:
            continue
        sec = min(near, key=lambda s: abs(s.floor_z - free.z_floor))  # type: ignore[operator]
        floor = float(sec.floor_z)  # type: ignore[arg-type]
        ceiling = floor + 2.5 if sec.ceiling_z is None else float(sec.ceiling_z)
        scenes.append(Scene(plan.segments[sec.rows], plan.segment_class[sec.rows].astype(
            np.int32), floor, ceiling))
        tours.append(plan_walk(free, 120.0, np.random.default_rng([len(tours), 7]),
                               cfg).path_xy)
    if not scenes:
        raise SystemExit(f"{ifc}: no storey the walker can walk")
    return World(name, plan, scenes, tours, closed=False)


def run_registration(world: World, seed: int, frames: int) -> dict[str, Any]:
    """One global alignment on ``world``; the outcome and its numbers."""
    from bimcap.geometry import Trajectory
    from bimcap.geometry.poses import compose, invert
    from bimcap.registration import (
        AmbiguousAlignmentError,
        GlobalAlignmentError,
        global_align,
    )
    from bimcap.registration.synthetic import poses_along, scan_sequence
    from bimcap.sim.drift import DriftParams, apply_drift, to_slam_frame

    rng = np.random.default_rng([seed, 77])
    k = int(rng.integers(len(world.scenes)))
    scene = world.scenes[k]
    walk = poses_along(np.concatenate([world.tours[k]] * (3 if world.closed else 1)), 0.25,
                       height=scene.floor_z + 1.5)
    start = int(rng.integers(0, len(walk) - frames))
    gt = walk[start:start + frames]
    drift = apply_drift(Trajectory(np.arange(frames) * 0.5, gt),
                        DriftParams.from_preset("exp2", seed=seed))
    samples = scan_sequence(gt, scene, seed=seed, clutter_fraction=0.05)
    slam = to_slam_frame(drift.init, seed)
    t0, c0 = time.perf_counter(), time.process_time()
    outcome, res = "placed", None
    try:
        res = global_align(slam.trajectory.poses, samples, world.plan)
    except AmbiguousAlignmentError as exc:
        outcome, res = "ambiguous", exc.result
    except GlobalAlignmentError as exc:
        outcome, res = "error", exc.result
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    row: dict[str, Any] = {"world": world.name, "seed": seed, "storey": k, "outcome": outcome,
                           "seconds": seconds, "cpu_seconds": cpu}
    if res is None:
        nan = float("nan")
        return {**row, "right": False, "cam_err_m": nan, "yaw_err_deg": nan, "ratio": nan,
                "right_storey": False, "score": nan, "fit": nan, "free": nan,
                "see_through": nan, "agreement": nan, "constraint": nan, "alias_ratio": nan,
                "alias_difference": nan, "alias_fit": nan, "twins": 0, "vote_rays": nan,
                "vote_best": nan, "vote_alias": nan, "vote_frames": nan, "vote_low": nan}
    est = compose(res.world_from_slam, slam.trajectory.poses)
    true = compose(invert(slam.slam_from_world), slam.trajectory.poses)
    cam_err = float(np.linalg.norm(est[:, :3] - true[:, :3], axis=1).mean())
    rel = compose(res.world_from_slam, slam.slam_from_world)
    yaw_err = float(np.rad2deg(2 * np.arccos(min(abs(rel[6]), 1.0))))
    right = cam_err < 1.0 and yaw_err < 10.0
    best = res.hypotheses[0]
    floor = best.floor_z
    return {**row, "right": right, "cam_err_m": cam_err, "yaw_err_deg": yaw_err,
            "ratio": res.ratio, "right_storey": floor is not None
            and abs(floor - scene.floor_z) < 0.3, "score": best.score, "fit": best.fit_score,
            "free": best.free_fraction, "see_through": best.see_through,
            "agreement": best.range_agreement, "constraint": best.constraint,
            "alias_ratio": float("nan") if res.alias is None else res.alias.score_ratio,
            "alias_difference": float("nan") if res.alias is None else res.alias.difference,
            "alias_fit": float("nan") if res.alias is None else res.alias.fit_score,
            "twins": len(res.twin_floors), **_vote_columns(res)}


def _vote_columns(res: Any) -> dict[str, float]:
    """The discriminating-ray vote at the result's alias (NaN: none cast)."""
    vote = None if res.alias is None else res.alias.vote
    if vote is None:
        return dict.fromkeys(("vote_rays", "vote_best", "vote_alias", "vote_frames",
                              "vote_low"), float("nan"))
    return {"vote_rays": vote.rays, "vote_best": vote.for_best, "vote_alias": vote.for_alias,
            "vote_frames": vote.frames, "vote_low": vote.share_low}


def summarise(rows: list[dict[str, Any]]) -> str:
    lines = [f"{'world':<7}{'runs':>5}{'right':>7}{'flagged':>9}{'errors':>8}{'silently':>10}"
             f"{'storey':>8}{'cam err':>9}{'time mean':>11}{'time max':>10}{'cpu mean':>10}"
             f"{'cpu max':>9}",
             f"{'':<7}{'':>5}{'':>7}{'':>9}{'':>8}{'wrong':>10}{'right':>8}{'[m]':>9}"
             f"{'[s]':>11}{'[s]':>10}{'[s]':>10}{'[s]':>9}"]
    groups = sorted({r["world"] for r in rows}, key=[r["world"] for r in rows].index)
    for name in [*groups, "all"]:
        rs = [r for r in rows if name in ("all", r["world"])]
        placed = [r for r in rs if r["outcome"] == "placed"]
        right = sum(r["right"] for r in placed)
        wrong = sum(not r["right"] for r in placed)
        err = [r["cam_err_m"] for r in placed if r["right"]]
        lines.append(
            f"{name:<7}{len(rs):>5}{right / len(rs):>7.0%}"
            f"{sum(r['outcome'] == 'ambiguous' for r in rs):>9}"
            f"{sum(r['outcome'] == 'error' for r in rs):>8}{wrong:>10}"
            f"{sum(r['right_storey'] for r in placed):>8}"
            f"{np.median(err) if err else float('nan'):>9.2f}"
            f"{np.mean([r['seconds'] for r in rs]):>11.2f}"
            f"{np.max([r['seconds'] for r in rs]):>10.2f}"
            f"{np.mean([r['cpu_seconds'] for r in rs]):>10.2f}"
            f"{np.max([r['cpu_seconds'] for r in rs]):>9.2f}")
    return "\n".join(lines)


def run_pipeline(n: int, work: Path, frames: int) -> list[dict[str, Any]]:
    """``bimcap refine`` from a SLAM-frame trajectory and from the aligned drift, per seed."""
    import json

    from bimcap.cli import main
    from bimcap.pipeline.demo import DemoOptions, make_sequence, make_world

    rows = []
    for seed in range(n):
        base = work / f"demo-{seed}"
        opts = DemoOptions(preset="demo", frames=frames, scale=0.125, fps=2.0, seed=seed)
        design, built = make_world(base, opts, quiet=True)
        seq = make_sequence(base, design, built, opts, quiet=True)
        row: dict[str, Any] = {"seed": seed}
        for kind in ("slam", "aligned"):
            init = base / f"{kind}.tum"
            extra = ["--slam-frame"] if kind == "slam" else []
            if not init.exists():
                assert main(["drift", str(seq), "--preset", "exp2", "--seed", str(seed + 1),
                             "-o", str(init), *extra]) == 0
            out = base / f"run-{kind}"
            t0 = time.perf_counter()
            rc = main(["refine", str(seq), "--ifc", str(design), "--init", str(init), "-o",
                       str(out), "--no-report", "-q", "--workers", "1", "--overwrite"])
            row[f"{kind}_rc"] = rc
            row[f"{kind}_seconds"] = time.perf_counter() - t0
            res = json.loads((out / "result.json").read_text())
            if rc == 0:
                row[f"{kind}_ate_cm"] = 100 * res["metrics_after"]["ate_pos_m"]["rmse"]
                row[f"{kind}_ate_deg"] = res["metrics_after"]["ate_rot_deg"]["rmse"]
            ga = res["solve"].get("global_align")
            if kind == "slam" and ga is not None:
                row["global_seconds"] = ga["timings"]["total"]
                row["ratio"] = ga["ratio"]
        rows.append(row)
        print(row, flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--seed-list", default=None, metavar="S,S",
                   help="run these seeds only (instead of 0..seeds-1)")
    p.add_argument("--worlds", default="demo,long,tiny,stack,tower")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--csv", type=Path, default=None)
    p.add_argument("--pipeline", type=int, default=0, metavar="N",
                   help="also run the whole refine on N demo sequences")
    p.add_argument("--work", type=Path, default=Path("/tmp/bench_global"))
    p.add_argument("--ifc-dir", type=Path, default=shared_ifc_dir(),
                   help="where the real models (worlds ifc-<name>) live")
    p.add_argument("--plane-height-tol-m", type=float, default=None, metavar="M",
                   help="real models: floor planes merged within M (PlaneOptions.height_tol_m; "
                   "default: the package default, cached reference)")
    args = p.parse_args(argv)
    rows = []
    for name in args.worlds.split(","):
        world = (_ifc_world(name, args.ifc_dir, height_tol_m=args.plane_height_tol_m)
                 if name.startswith("ifc-") else _world(name))
        seeds = (range(args.seeds) if args.seed_list is None
                 else [int(v) for v in args.seed_list.split(",")])
        for seed in seeds:
            row = run_registration(world, seed, args.frames)
            rows.append(row)
            print(f"{name} seed {seed}: {row['outcome']}, right {row['right']}, cam error "
                  f"{row['cam_err_m']:.2f} m, ratio {row['ratio']:.2f}, alias ratio "
                  f"{row['alias_ratio']:.3f} (difference {row['alias_difference']:.3f}), "
                  f"{row['seconds']:.1f} s", file=sys.stderr, flush=True)
    print(summarise(rows))
    placed = [r for r in rows if r["outcome"] == "placed"]
    silent = sum(not r["right"] for r in placed)
    t = max(r["seconds"] for r in rows)
    c = max(r["cpu_seconds"] for r in rows)
    print(f"\nsilently wrong: {silent} (target 0); slowest alignment {t:.1f} s wall, {c:.1f} s "
          "CPU (target < 10 s)")
    if args.csv is not None:
        with open(args.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    if args.pipeline:
        prow = run_pipeline(args.pipeline, args.work, args.frames)
        ok = [r for r in prow if r.get("slam_rc") == 0]
        print(f"\npipeline: {len(ok)}/{len(prow)} SLAM-frame runs aligned and refined")
        for r in prow:
            print(r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
