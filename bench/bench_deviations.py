"""Scan-vs-BIM deviations against the simulator's truth: recall of shifted elements, false alarms,
missing elements, offset RMSE and run time, with ground-truth and with refined poses.

Per world (``<layout>-s<seed>``, built once into ``--work`` and reused): the design IFC, its
as-built (walls shifted along their normals and columns offset by σ ``--shift-sigma`` (3 cm),
``--missing`` (20 %) of the partitions, columns, door and window fills left out), a sequence
simulated in the as-built (``--frames`` frames at the demo's rig: 516×386, VLP-16, 2 fps), the
paper's exp2 drift as the initial poses and a default ``bimcap refine`` against the *design* (the
deviations are in the scan, not in the BIM). The deviations (:mod:`bimcap.deviations`) are then
computed with the ground-truth poses and with the refined poses, each without and with the
datum, and scored (:mod:`bimcap.deviations.scoring`) against ``as_built.truth.json``.

The datum: the as-built keeps :data:`DATUM_WALLS` (one exterior wall along x, one along y)
exactly at design, like surveyed control lines, and records them in the truth sidecar
(``deviations.datum``); the floor slabs are never shifted by the generator, so the ground floor's
slab joins them for z. Rows ``+datum-rigid`` / ``+datum-frames`` pass them as the datum
(:mod:`bimcap.deviations.datum`: the rigid correction that puts them on the design first, then,
for ``-frames``, one per frame fitted jointly with the other elements' offsets); every row scores
the other elements only, so the rows with and without datum count the same elements.

Usage (resumable: worlds already in the CSV are skipped)::

    PYTHONPATH=python python bench/bench_deviations.py --work /tmp/devbench \
        --out docs/deviations.csv --worlds demo-s1,demo-s2,demo-s3,small-s4,small-s5
    PYTHONPATH=python python bench/bench_deviations.py --summarise docs/deviations.csv
    PYTHONPATH=python python bench/bench_deviations.py --work /tmp/devbench \
        --worlds demo-s1,demo-s2 --elements /tmp/devbench/elements.csv   # per element, why
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path
from typing import Any

FIELDS = ("world", "poses", "frames", "pose_err_cm", "elements", "observed", "shifted",
          "detected", "recall", "false_alarms", "false_alarm_rate", "missing_seen",
          "missing_found", "false_missing", "offset_rmse_cm", "seconds")

LAYOUTS: dict[str, dict[str, Any]] = {
    "demo": {},
    "small": {"corridor_length_m": 9.0, "rooms_north": 2, "rooms_south": 2,
              "room_depth_north_m": 3.5, "room_depth_south_m": 3.8, "corridor_columns": 1},
    "tiny": {"corridor_length_m": 5.0, "rooms_north": 1, "rooms_south": 1,
             "room_depth_north_m": 3.6, "room_depth_south_m": 4.0, "corridor_columns": 1},
}

#: The summary's last row: refined runs whose poses are within this of the truth (ATE, cm).
GOOD_POSES_CM = 5.0

#: The issue's targets.
TARGETS = {"recall": 0.95, "false_alarm_rate": 0.05, "offset_rmse_cm_gt": 1.0,
           "offset_rmse_cm_refined": 1.5, "seconds": 10.0}


#: The as-built's datum: walls built exactly as designed (surveyed control lines), one along x
#: and one along y, on every storey; with the ground floor slab (never shifted) for z.
DATUM_WALLS = ("ext-south", "ext-west")


def make_world(work: Path, world: str, frames: int, shift_sigma: float, missing: float
               ) -> tuple[Path, Path, Path]:
    """(sequence dir, design IFC, as-built truth sidecar) of ``world``, built once; the
    as-built keeps :data:`DATUM_WALLS` exactly at design."""
    from bimcap.dataset import add_trajectory, read_sequence
    from bimcap.sim.building import BuildingSpec, as_built, generate_building
    from bimcap.sim.drift import DriftParams, apply_drift
    from bimcap.sim.simulator import CONSLAM_CAMERA, SimulatorConfig, simulate
    from bimcap.sim.walk import WalkConfig

    layout, _, seed_text = world.rpartition("-s")
    seed = int(seed_text)
    root = work / world
    design, built = root / "design.ifc", root / "as_built.ifc"
    if not built.is_file():
        root.mkdir(parents=True, exist_ok=True)
        gb = generate_building(BuildingSpec(**LAYOUTS[layout]), seed=seed, ifc_path=design)
        as_built(gb, seed=seed + 1, shift_sigma_m=shift_sigma, missing_fraction=missing,
                 datum=DATUM_WALLS, ifc_path=built)
    seq = root / f"seq_{frames}"
    if not (seq / "manifest.json").is_file():
        cfg = SimulatorConfig(camera=CONSLAM_CAMERA.scaled(0.25), frames=frames, fps=2.0,
                              walk=WalkConfig(pitch_deg=-12.0), workers=0)
        simulate(design, seq, cfg, seed=seed, as_built_ifc=built)
    s = read_sequence(seq)
    if not s.has_trajectory("init"):
        drift = apply_drift(s.trajectory("gt"), DriftParams.from_preset("exp2", seed=seed + 1))
        add_trajectory(s, "init", drift.init, header="bimcap drift exp2")
    return seq, design, root / "as_built.truth.json"


def refined_poses(work: Path, world: str, seq_dir: Path, design: Path, workers: int) -> Any:
    """The default refine (BIMCaP) of the world's exp2 drift against the design; cached as
    ``refined.tum`` in the world's folder."""
    from bimcap.dataset import read_sequence
    from bimcap.geometry import read_tum, write_tum
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import prepare, solve_prepared

    path = work / world / f"refined_{seq_dir.name}.tum"
    if path.is_file():
        return read_tum(path)
    seq = read_sequence(seq_dir)
    cfg = RefineConfig(workers=workers)
    prep = prepare(seq, design, None, cfg, work / world / "run", quiet=True)
    outcome = solve_prepared(prep, cfg, quiet=True)
    write_tum(path, outcome.refined, header="bench_deviations refined world_from_cam")
    return outcome.refined


def datum_spec(truth: Any) -> Any:
    """The bench's datum (:class:`bimcap.deviations.datum.DatumSpec`): the truth's datum
    elements by name, and the ground floor's slab (never shifted) for z."""
    from bimcap.deviations.datum import DatumSpec

    if not truth.datum:
        raise SystemExit("the as-built has no datum (a world built before it had one): "
                         "use a new --work")
    return DatumSpec.parse([f"name:{n}" for n in truth.datum] + ["name:S0/slab/floor"],
                           "bench datum")


def pose_runs(seq: Any, refined: Any, truth: Any) -> list[tuple[str, Any, Any]]:
    """``(row name, world_from_cam trajectory, datum or None)`` of the five analyses: without a
    datum, with the rigid correction (``-rigid``) and with the per-frame joint fit
    (``-frames``)."""
    from dataclasses import replace

    from bimcap.deviations.datum import DatumFitMode

    gt = seq.trajectory("gt")
    frames = datum_spec(truth)
    rigid = replace(frames, fit=DatumFitMode.RIGID)
    return [("gt", gt, None), ("gt+datum-frames", gt, frames), ("refined", refined, None),
            ("refined+datum-rigid", refined, rigid), ("refined+datum-frames", refined, frames)]


def score_world(work: Path, world: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    from bimcap.dataset import read_sequence
    from bimcap.deviations.analysis import analyse_deviations, load_design
    from bimcap.deviations.refined_map import load_scans
    from bimcap.deviations.scoring import score_deviations
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics
    from bimcap.sim.building_truth import load_building_truth

    seq_dir, design, truth_path = make_world(work, world, args.frames, args.shift_sigma,
                                             args.missing)
    truth = load_building_truth(truth_path).deviations
    assert truth is not None
    seq = read_sequence(seq_dir)
    gt = seq.trajectory("gt")
    refined = refined_poses(work, world, seq_dir, design, args.workers)
    rows = []
    for name, traj, datum in pose_runs(seq, refined, truth):
        t0 = time.perf_counter()
        model = load_design(design)
        scans = load_scans(seq, traj.poses)
        report = analyse_deviations(model, scans, ifc_path=design, datum=datum)
        seconds = time.perf_counter() - t0
        sc = score_deviations(report, truth.wall_shifts, truth.column_offsets, truth.missing,
                              exclude=truth.datum)
        poses = traj.poses
        if report.datum.get("mode") == "datum":  # the corrected poses' error
            poses = _corrected(report.datum, poses)
        err = trajectory_metrics(poses, gt.poses, AlignMode.NONE).ate_pos_m.rmse
        rows.append({
            "world": world, "poses": name, "frames": len(gt), "pose_err_cm": 100 * err,
            "elements": sc.elements, "observed": sc.observed, "shifted": sc.shifted,
            "detected": sc.detected, "recall": sc.recall, "false_alarms": sc.false_alarms,
            "false_alarm_rate": sc.false_alarm_rate, "missing_seen": sc.missing_seen,
            "missing_found": sc.missing_found, "false_missing": sc.false_missing,
            "offset_rmse_cm": 100 * sc.offset_rmse_m, "seconds": seconds,
        })
        print(f"{world:10s} {name:8s} pose {100 * err:5.2f} cm | shifted>=3cm "
              f"{sc.detected}/{sc.shifted} | false alarms {sc.false_alarms}/{sc.observed} | "
              f"missing {sc.missing_found}/{sc.missing_seen} (false {sc.false_missing}) | "
              f"offset RMSE {100 * sc.offset_rmse_m:.2f} cm | {seconds:.1f} s", flush=True)
    return rows


def _corrected(datum: dict[str, Any], world_from_cam: Any) -> Any:
    """(N, 7) poses moved by a report's datum correction (per frame with the joint fit)."""
    import numpy as np

    from bimcap.geometry.poses import compose, matrix_to_pose

    if "frames" in datum:
        return compose(np.asarray(datum["frames"]["world_datum_from_world"]), world_from_cam)
    t = matrix_to_pose(np.asarray(datum["world_datum_from_world"])[None])[0]
    return compose(np.repeat(t[None], len(world_from_cam), axis=0), world_from_cam)


ELEMENT_FIELDS = ("world", "poses", "name", "ifc_class", "status", "true_m", "offset_m",
                  "error_m", "coverage", "n_points", "verdict")


def element_rows(work: Path, world: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    """Per observed wall and column of ``world`` (built and refined before: the cached worlds of
    ``--work``), with the ground-truth and the refined poses: the applied shift (``true_m``:
    walls signed along the normal, columns the length of (dx, dy)), the measured ``offset_m``,
    the error, and the verdict against the truth: ``found`` / ``missed`` (shifted ≥ 3 cm),
    ``false_alarm`` / ``ok`` (shifted < tolerance), ``between`` (tolerance … 3 cm),
    ``missing_found`` / ``missing_missed``."""
    from bimcap.dataset import read_sequence
    from bimcap.deviations.analysis import ElementStatus, analyse_deviations, load_design
    from bimcap.deviations.refined_map import load_scans
    from bimcap.sim.building_truth import load_building_truth

    seq_dir, design, truth_path = make_world(work, world, args.frames, args.shift_sigma,
                                             args.missing)
    truth = load_building_truth(truth_path).deviations
    assert truth is not None
    seq = read_sequence(seq_dir)
    refined = refined_poses(work, world, seq_dir, design, args.workers)
    model = load_design(design)
    rows = []
    for name, traj, datum in pose_runs(seq, refined, truth):
        report = analyse_deviations(model, load_scans(seq, traj.poses), ifc_path=design,
                                    datum=datum)
        tol = report.options.tolerance_m
        for e in report.elements:
            if e.status is ElementStatus.UNOBSERVED or e.name in truth.datum:
                continue
            flagged = e.status in (ElementStatus.DEVIATING, ElementStatus.MISSING)
            err: float | None = None
            if e.name in truth.missing:
                true, verdict = float("nan"), ("missing_found" if e.status is
                                               ElementStatus.MISSING else "missing_missed")
            else:
                if e.name in truth.wall_shifts:
                    true = truth.wall_shifts[e.name]
                    err = None if e.offset_m is None else e.offset_m - true
                elif e.name in truth.column_offsets:
                    dx, dy = truth.column_offsets[e.name]
                    true = math.hypot(dx, dy)
                    if e.offset_xy_m is not None:
                        err = math.hypot(e.offset_xy_m[0] - dx, e.offset_xy_m[1] - dy)
                elif e.ifc_class.startswith(("IfcWall", "IfcColumn")):
                    true = 0.0
                else:
                    continue  # slabs and coverings: in the false alarms only when flagged
                if abs(true) >= 0.03:
                    verdict = "found" if e.status is ElementStatus.DEVIATING else "missed"
                elif abs(true) < tol:
                    verdict = "false_alarm" if flagged else "ok"
                else:
                    verdict = "between"
            rows.append({"world": world, "poses": name, "name": e.name,
                         "ifc_class": e.ifc_class, "status": e.status.value, "true_m": true,
                         "offset_m": e.offset_m, "error_m": err, "coverage": e.coverage,
                         "n_points": e.n_points, "verdict": verdict})
    return rows


def summarise(path: Path) -> str:
    """The table for docs/: totals per pose source, next to the targets."""
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    lines = ["| poses | worlds | pose ATE [cm] | recall ≥ 3 cm | false alarms | missing found "
             "| false missing | offset RMSE [cm] | time [s] (max) |",
             "|---|---|---|---|---|---|---|---|---|"]
    kinds = list(dict.fromkeys(r["poses"] for r in rows))
    groups = [(k, [r for r in rows if r["poses"] == k]) for k in kinds]
    groups += [(f"{k}, pose ATE ≤ {GOOD_POSES_CM:g} cm",
                [r for r in rows if r["poses"] == k and float(r["pose_err_cm"]) <= GOOD_POSES_CM])
               for k in kinds if k.startswith("refined")]
    for poses, sel in groups:
        if not sel:
            continue

        def total(key: str, sel: list[dict[str, str]] = sel) -> int:
            return sum(int(r[key]) for r in sel)

        # offsets: root of the mean over worlds of each world's mean square error
        sq = [float(r["offset_rmse_cm"]) ** 2 for r in sel
              if not math.isnan(float(r["offset_rmse_cm"]))]
        rmse = math.sqrt(sum(sq) / len(sq)) if sq else float("nan")
        pose = sum(float(r["pose_err_cm"]) for r in sel) / len(sel)
        lines.append(
            f"| {poses} | {len(sel)} | {pose:.2f} | {total('detected')}/{total('shifted')} "
            f"({100 * total('detected') / max(total('shifted'), 1):.0f} %) | "
            f"{total('false_alarms')}/{total('observed')} "
            f"({100 * total('false_alarms') / max(total('observed'), 1):.1f} %) | "
            f"{total('missing_found')}/{total('missing_seen')} | {total('false_missing')} | "
            f"{rmse:.2f} | {max(float(r['seconds']) for r in sel):.1f} |")
    lines += ["", "Worst world per column (the table above pools the worlds):", "",
              "| poses | recall ≥ 3 cm | false alarms | offset RMSE [cm] | pose ATE [cm] "
              "| time [s] |", "|---|---|---|---|---|---|"]
    for poses in kinds:
        sel = [r for r in rows if r["poses"] == poses]
        if not sel:
            continue

        def worst(key: str, low: bool, sel: list[dict[str, str]] = sel
                  ) -> tuple[float, dict[str, str]]:
            valid = [r for r in sel if not math.isnan(float(r[key]))]
            r = (min if low else max)(valid, key=lambda r: float(r[key]))
            return float(r[key]), r

        rec, r_rec = worst("recall", True)
        fa, r_fa = worst("false_alarm_rate", False)
        rmse, r_rmse = worst("offset_rmse_cm", False)
        ate, r_ate = worst("pose_err_cm", False)
        sec, r_sec = worst("seconds", False)
        lines.append(
            f"| {poses} | {100 * rec:.0f} % ({r_rec['detected']}/{r_rec['shifted']}, "
            f"{r_rec['world']}) | {100 * fa:.1f} % ({r_fa['false_alarms']}/{r_fa['observed']}, "
            f"{r_fa['world']}) | {rmse:.2f} ({r_rmse['world']}) | {ate:.2f} ({r_ate['world']}) "
            f"| {sec:.1f} ({r_sec['world']}) |")
    lines.append(f"\nTargets: recall ≥ {100 * TARGETS['recall']:.0f} %, false alarms ≤ "
                 f"{100 * TARGETS['false_alarm_rate']:.0f} % of observed elements, offset RMSE "
                 f"≤ {TARGETS['offset_rmse_cm_gt']} cm (gt) / ≤ "
                 f"{TARGETS['offset_rmse_cm_refined']} cm (refined), < {TARGETS['seconds']:.0f} s"
                 " per 60-frame sequence.")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", default="/tmp/bimcap-devbench")
    ap.add_argument("--out", default="docs/deviations.csv")
    ap.add_argument("--worlds", default="demo-s1,demo-s2,demo-s3,small-s4,small-s5")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--shift-sigma", type=float, default=0.03)
    ap.add_argument("--missing", type=float, default=0.2)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--summarise", metavar="CSV", help="print the table of a CSV and exit")
    ap.add_argument("--elements", metavar="CSV",
                    help="write one row per observed wall and column of the (already built and "
                         "refined) --worlds, with its verdict, to CSV and exit")
    args = ap.parse_args()
    if args.summarise:
        print(summarise(Path(args.summarise)))
        return
    if args.elements:
        with Path(args.elements).open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=ELEMENT_FIELDS)
            w.writeheader()
            for world in args.worlds.split(","):
                w.writerows(element_rows(Path(args.work), world, args))
                fh.flush()
        return
    out = Path(args.out)
    done: set[str] = set()
    if out.exists():
        with out.open(newline="") as fh:
            done = {r["world"] for r in csv.DictReader(fh)}
    new = not out.exists()
    with out.open("a", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS)
        if new:
            w.writeheader()
        for world in args.worlds.split(","):
            if world in done:
                continue
            for row in score_world(Path(args.work), world, args):
                w.writerow(row)
            fh.flush()
    print(summarise(out))


if __name__ == "__main__":
    main()
