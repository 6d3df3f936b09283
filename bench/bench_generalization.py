"""Accuracy on worlds bimcap was not tuned on: generated buildings of several layouts and sizes,
every real IFC in ``../shared/data/ifc`` as a simulated world, standard and hard sensor settings,
the paper's Exp. 1/2/3 drifts, 60- and 250-frame walks, and the fixed point.

Per world (built once into ``--work`` and reused):

* generated buildings (``gen-<layout>-s<seed>``): a design IFC and its as-built variant (walls
  shifted by σ 3 cm, a partition missing); the sequence is simulated in the as-built world;
* real IFCs (``ifc-<name>``): the sequence is simulated in the model itself (the simulator finds
  the storey and the region to walk).

Per world, frame count and setting, the default ``bimcap refine`` configuration is run:

* ``fixed``: from the ground truth, with the reference the world was rendered from (the as-built
  IFC, or the real IFC): how far the refinement moves poses that are already right;
* ``exp1``, ``exp2``, ``exp3``: from the paper's drift presets (seed = world seed + 1), BIMCaP
  against the same reference, and FACaP on the same front end (BIMCaP must beat it);
* ``design`` (generated buildings only): exp2 against the *design* IFC, i.e. with the 3 cm
  as-built deviations of the walls left in the BIM: how far the deviations move the result.

Settings: ``standard`` is the demo's rig (516×386, VLP-16 with 3 cm range noise, 12° down-look,
geometric segmenter); ``hard`` has 8 cm range noise with 20 % dropouts, a 1.5× focal length
(narrower view), and 15 % wrong labels (:data:`HARD_LABEL_NOISE`: blobs plus class boundaries
wandering by 2 px) that the refinement reads as its labels (``--segmentation ground_truth``
reads ``labels/``, the noisy ones; the truth is in ``labels_gt/``). A hard world simulated before
the labels were noisy (its manifest records no label noise) is refined with the default geometric
segmenter, as before. ``hard-geometric`` refines the hard worlds (the same sequences) with the
default geometric segmenter instead, as a user without a learned segmenter would.

Usage (resumable: rows already in the CSV are skipped)::

    PYTHONPATH=python python bench/bench_generalization.py --work /tmp/gen \
        --out docs/generalization.csv \
        --worlds gen-demo-s11,gen-small-s3,ifc-Duplex_A_20110907 --frames 60 --settings standard
    PYTHONPATH=python python bench/bench_generalization.py --summarise docs/generalization.csv
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/'s own helpers
from shared_paths import shared_ifc_dir

FIELDS = ("world", "kind", "frames", "setting", "run", "method", "init_pos_m", "init_rot_deg",
          "pos_m", "rot_deg", "yaw_deg", "pitch_deg", "roll_deg", "fully_observed",
          "frames_total", "solve_s", "blind_frames", "pos_seen_m", "rot_seen_deg")

#: Generated layouts: BuildingSpec changes (1 and 2 storeys, small to large).
LAYOUTS: dict[str, dict[str, Any]] = {
    "demo": {},
    "small": {"corridor_length_m": 9.0, "rooms_north": 2, "rooms_south": 2,
              "room_depth_north_m": 3.5, "room_depth_south_m": 3.8, "corridor_columns": 1},
    "large": {"corridor_length_m": 22.0, "corridor_width_m": 3.0, "rooms_north": 4,
              "rooms_south": 5, "room_depth_north_m": 5.0, "room_depth_south_m": 4.6,
              "corridor_columns": 3},
    "twostorey": {"storeys": 2},
}
DEFAULT_WORLDS = ("gen-demo-s11,gen-demo-s23,gen-small-s3,gen-small-s8,gen-large-s4,"
                  "gen-twostorey-s6,ifc-AC20-FZK-Haus,ifc-SampleHouse4,ifc-Duplex_A_20110907,"
                  "ifc-Office_A_20110811")



#: The hard setting's wrong labels: 15 % of the labelled pixels (the issue asks 10–20 %), in
#: blobs and near class boundaries (which wander by up to 2 px).
HARD_LABEL_NOISE = {"fraction": 0.15, "boundary_px": 2.0}


#: The settings: each names the simulated world it runs on.
SETTINGS = {"standard": "standard", "hard": "hard", "hard-geometric": "hard"}


def _sim_config(setting: str, frames: int) -> Any:
    from bimcap.sim.label_noise import LabelNoiseConfig
    from bimcap.sim.lidar import LidarConfig
    from bimcap.sim.simulator import CONSLAM_CAMERA, SimulatorConfig
    from bimcap.sim.walk import WalkConfig

    camera = CONSLAM_CAMERA.scaled(0.25)
    lidar = LidarConfig()
    label_noise = LabelNoiseConfig()
    if setting == "hard":
        camera = replace(camera, fx=camera.fx * 1.5, fy=camera.fy * 1.5)
        lidar = replace(lidar, range_noise_m=0.08, dropout=0.2)
        label_noise = LabelNoiseConfig(**HARD_LABEL_NOISE)
    return SimulatorConfig(camera=camera, frames=frames, fps=2.0, lidar=lidar,
                           walk=WalkConfig(pitch_deg=-12.0), workers=0, label_noise=label_noise)


def world_runs(work: Path, world: str) -> tuple[Any, Path, dict[str, Any]]:
    """A 60-frame standard world (:func:`make_world`): its sequence, reference IFC and the initial
    trajectories of the fixed point (the ground truth) and Exp. 1/2/3 (seed = world seed + 1)."""
    from bimcap.dataset import read_sequence
    from bimcap.sim.drift import DriftParams, apply_drift

    seq_dir, reference, _ = make_world(work, world, 60, "standard")
    seq = read_sequence(seq_dir)
    gt = seq.trajectory("gt")
    seed = int(world.rpartition("-s")[2]) if world.startswith("gen") else 1
    inits = {"fixed": gt, **{e: apply_drift(gt, DriftParams.from_preset(e, seed=seed + 1)).init
                             for e in ("exp1", "exp2", "exp3")}}
    return seq, reference, inits


def make_world(work: Path, world: str, frames: int, setting: str,
               ifc_dir: Path | None = None) -> tuple[Path, Path, Path | None]:
    """(sequence dir, reference IFC the world was rendered from, design IFC or None); a real
    world ``ifc-<name>`` is ``<name>.ifc`` in ``ifc_dir`` (default: the shared real IFCs)."""
    from bimcap.sim.building import BuildingSpec, as_built, generate_building
    from bimcap.sim.simulator import simulate

    root = work / world
    seq = root / f"seq_{frames}_{setting}"
    kind, _, rest = world.partition("-")
    if kind == "gen":
        layout, _, seed_text = rest.rpartition("-s")
        seed = int(seed_text)
        design, built = root / "design.ifc", root / "as_built.ifc"
        if not built.is_file():
            root.mkdir(parents=True, exist_ok=True)
            spec = BuildingSpec(**LAYOUTS[layout])
            gb = generate_building(spec, seed=seed, ifc_path=design)
            as_built(gb, seed=seed + 1, ifc_path=built)
        if not (seq / "manifest.json").is_file():
            simulate(design, seq, _sim_config(setting, frames), seed=seed, as_built_ifc=built)
        return seq, built, design
    ifc = (ifc_dir or shared_ifc_dir()) / f"{rest}.ifc"
    if not ifc.is_file():
        raise SystemExit(f"{ifc}: not found (the real IFCs live in ../shared/data/ifc; "
                         "--ifc-dir names another folder)")
    if not (seq / "manifest.json").is_file():
        simulate(ifc, seq, _sim_config(setting, frames), seed=1)
    return seq, ifc, None


def _row(world: str, frames: int, setting: str, run: str, method: str, init: Any, gt: Any,
         outcome: Any, frontend: Any) -> dict[str, Any]:
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics

    m0 = trajectory_metrics(init.poses, gt.poses, AlignMode.NONE)
    m = trajectory_metrics(outcome.refined.poses, gt.poses, AlignMode.NONE)
    obs = outcome.observability
    # "blind" frames: no feature match and no associated BIM sample, nothing but the input's pose
    # (and the odometry) to go by; the ATE over the other frames is reported beside the full one.
    seen = np.zeros(len(gt), dtype=bool)
    for f in (frontend.match_frames, frontend.track_obs_frame):
        seen[np.asarray(f, dtype=np.int64).ravel()] = True
    if obs is not None:
        seen[[f.frame for f in obs.frames if sum(f.samples.values()) > 0]] = True
    ms = trajectory_metrics(outcome.refined.poses[seen], gt.poses[seen], AlignMode.NONE)
    return {"world": world, "kind": world.split("-")[0], "frames": frames, "setting": setting,
            "run": run, "method": method, "init_pos_m": m0.ate_pos_m.rmse,
            "init_rot_deg": m0.ate_rot_deg.rmse, "pos_m": m.ate_pos_m.rmse,
            "rot_deg": m.ate_rot_deg.rmse, "yaw_deg": m.yaw_rmse_deg,
            "pitch_deg": m.pitch_rmse_deg, "roll_deg": m.roll_rmse_deg,
            "fully_observed": obs.fully_observed() if obs is not None else -1,
            "frames_total": len(gt), "solve_s": outcome.seconds,
            "blind_frames": int((~seen).sum()), "pos_seen_m": ms.ate_pos_m.rmse,
            "rot_seen_deg": ms.ate_rot_deg.rmse}


def run(args: argparse.Namespace) -> None:
    from bimcap.dataset import read_sequence
    from bimcap.pipeline.config import LabelSource, Method, RefineConfig
    from bimcap.pipeline.refine import prepare, solve_prepared
    from bimcap.sim.drift import DriftParams, apply_drift

    work = Path(args.work)
    out = Path(args.out)
    done: set[tuple[str, ...]] = set()
    if out.exists():
        with out.open(newline="") as fh:
            done = {(r["world"], r["frames"], r["setting"], r["run"], r["method"])
                    for r in csv.DictReader(fh)}
    _upgrade_header(out)
    new = not out.exists()
    with out.open("a", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS)
        if new:
            w.writeheader()
        for world in args.worlds.split(","):
            for frames in (int(f) for f in args.frames.split(",")):
                for setting in args.settings.split(","):
                    if setting not in SETTINGS:
                        raise SystemExit(f"--settings: {setting!r} is not one of "
                                         f"{', '.join(SETTINGS)}")
                    t0 = time.perf_counter()
                    seq_dir, reference, design = make_world(work, world, frames,
                                                            SETTINGS[setting], args.ifc_dir)
                    seq = read_sequence(seq_dir)
                    gt = seq.trajectory("gt")
                    seed = int(world.rpartition("-s")[2]) if world.startswith("gen") else 1
                    base = RefineConfig(workers=args.workers, features=dict(args.features),
                                        matching=dict(args.matching),
                                        geometric=dict(args.geometric))
                    if setting == "hard" and seq.has_labels and _labels_are_noisy(seq):
                        base = replace(base, segmentation=LabelSource.GROUND_TRUTH)
                    runs: list[tuple[str, Any, Path]] = [("fixed", gt, reference)]
                    runs += [(e, apply_drift(gt, DriftParams.from_preset(e, seed=seed + 1)).init,
                              reference) for e in ("exp1", "exp2", "exp3")]
                    if design is not None:
                        runs.append(("design", runs[2][1], design))
                    for name, init, ifc in runs:
                        if args.runs and name not in args.runs.split(","):
                            continue
                        methods = ["bimcap"] + (["facap"] if name.startswith("exp") else [])
                        methods = [m for m in methods if m in args.methods.split(",")]
                        for method in methods:
                            key = (world, str(frames), setting, name, method)
                            if key in done:
                                continue
                            cfg = base if method == "bimcap" else replace(
                                base, method=Method.FACAP)
                            tag = "design" if name == "design" else "ref"
                            prep = prepare(seq, ifc, init, cfg,
                                           work / world / f"run_{frames}_{setting}_{tag}",
                                           quiet=True)
                            outcome = solve_prepared(prep, cfg, quiet=True)
                            row = _row(world, frames, setting, name, method, init, gt, outcome,
                                       prep.frontend)
                            w.writerow(row)
                            fh.flush()
                            print(f"{world:28s} {frames:4d} {setting:8s} {name:6s} {method:6s} "
                                  f"{row['init_pos_m']:.3f} m/{row['init_rot_deg']:.2f}° → "
                                  f"{row['pos_m'] * 100:.2f} cm/{row['rot_deg']:.3f}° "
                                  f"({row['solve_s']:.1f} s; {row['blind_frames']} blind frames, "
                                  f"seen {row['pos_seen_m'] * 100:.2f} cm/"
                                  f"{row['rot_seen_deg']:.3f}°)",
                                  flush=True)
                    print(f"{world} {frames} {setting}: {time.perf_counter() - t0:.0f} s",
                          flush=True)


def _upgrade_header(out: Path) -> None:
    """Rewrite a CSV written before columns were added with the current header (blanks)."""
    if not out.exists():
        return
    with out.open(newline="") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is not None and list(reader.fieldnames) == list(FIELDS):
            return
        rows = list(reader)
    with out.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS, restval="")
        w.writeheader()
        w.writerows(rows)


def _labels_are_noisy(seq: Any) -> bool:
    """Whether the simulator wrote wrong labels on purpose: its manifest's ``source`` records
    the label noise it measured (``label_noise_measured``, None without noise) and the one it
    was asked for (``config.label_noise``)."""
    src = getattr(seq, "source", None) or {}
    if not isinstance(src, dict):
        return False
    if src.get("label_noise_measured"):
        return True
    cfg = src.get("config")
    noise = cfg.get("label_noise") if isinstance(cfg, dict) else None
    if isinstance(noise, dict):
        return float(noise.get("fraction", 0.0) or 0.0) > 0 or float(
            noise.get("boundary_px", 0.0) or 0.0) > 0
    return False


def summarise(paths: list[str]) -> None:
    rows: list[dict[str, Any]] = []
    for p in paths:
        with open(p, newline="") as fh:
            rows += list(csv.DictReader(fh))
    for r in rows:
        for k in ("pos_m", "rot_deg", "init_pos_m", "init_rot_deg", "solve_s"):
            r[k] = float(r[k])
        for k in ("pos_seen_m", "rot_seen_deg"):
            r[k] = float(r[k]) if r.get(k) not in (None, "") else None
    groups = sorted({(r["setting"], int(r["frames"])) for r in rows})
    print("| setting | frames | runs | BIMCaP Exp 1/2/3: mean ATE_pos / ATE_rot | worst run "
          "| without blind frames: mean / worst | fixed point: mean / worst "
          "| design IFC (exp2): mean / worst | BIMCaP beats FACaP |")
    print("|---|---|---|---|---|---|---|---|---|")
    for setting, frames in groups:
        g = [r for r in rows if r["setting"] == setting and int(r["frames"]) == frames]
        exp = [r for r in g if r["run"].startswith("exp") and r["method"] == "bimcap"]
        fix = [r for r in g if r["run"] == "fixed"]
        des = [r for r in g if r["run"] == "design"]
        worst = max(exp, key=lambda r: (r["pos_m"], r["rot_deg"])) if exp else None
        worst_rot = max(exp, key=lambda r: r["rot_deg"]) if exp else None
        beats = total = 0
        for r in exp:
            f = [q for q in g if q["world"] == r["world"] and q["run"] == r["run"]
                 and q["method"] == "facap"]
            if f:
                total += 1
                beats += int(r["pos_m"] < f[0]["pos_m"] and r["rot_deg"] < f[0]["rot_deg"])

        def mean(rs: list[dict[str, Any]]) -> str:
            if not rs:
                return "–"
            return (f"{np.mean([r['pos_m'] for r in rs]) * 100:.2f} cm / "
                    f"{np.mean([r['rot_deg'] for r in rs]):.3f}°")

        def worst_of(rs: list[dict[str, Any]]) -> str:
            if not rs:
                return "–"
            return (f"{max(r['pos_m'] for r in rs) * 100:.2f} cm / "
                    f"{max(r['rot_deg'] for r in rs):.3f}°")

        wtext = "–" if worst is None else (
            f"{worst['pos_m'] * 100:.2f} cm ({worst['world']} {worst['run']}); "
            f"{worst_rot['rot_deg']:.3f}° ({worst_rot['world']} {worst_rot['run']})")
        seen = [{**r, "pos_m": r["pos_seen_m"], "rot_deg": r["rot_seen_deg"]} for r in exp
                if r["pos_seen_m"] is not None]
        print(f"| {setting} | {frames} | {len(exp)} | {mean(exp)} | {wtext} | "
              f"{mean(seen)} / {worst_of(seen)} ({len(seen)} runs) | {mean(fix)} / "
              f"{worst_of(fix)} | {mean(des)} / {worst_of(des)} | {beats}/{total} |")
    print()
    print("| world | frames | setting | fixed | exp1 | exp2 | exp3 | FACaP exp2 | design exp2 |")
    print("|---|---|---|---|---|---|---|---|---|")
    keys = sorted({(r["world"], int(r["frames"]), r["setting"]) for r in rows})
    for world, frames, setting in keys:
        g = {(r["run"], r["method"]): r for r in rows
             if r["world"] == world and int(r["frames"]) == frames and r["setting"] == setting}

        def cell(run: str, method: str = "bimcap",
                 g: dict[tuple[str, str], dict[str, Any]] = g) -> str:
            r = g.get((run, method))
            return "–" if r is None else f"{r['pos_m'] * 100:.2f} cm / {r['rot_deg']:.3f}°"

        print(f"| {world} | {frames} | {setting} | {cell('fixed')} | {cell('exp1')} | "
              f"{cell('exp2')} | {cell('exp3')} | {cell('exp2', 'facap')} | {cell('design')} |")
    if any(math.isnan(r["pos_m"]) for r in rows):
        print("(some runs gave NaN)")


def _feature_setting(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` of ``--features``: VALUE as a bool (``true``, ``false``), an int or a float
    where it reads as one."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    if value in ("true", "false"):
        return key, value == "true"
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            pass
    return key, value


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/bimcap_generalization", help="worlds and caches")
    ap.add_argument("--worlds", default=DEFAULT_WORLDS, help="comma list (see the module doc)")
    ap.add_argument("--frames", default="60", help="comma list of walk lengths, e.g. 60,250")
    ap.add_argument("--settings", default="standard",
                    help="comma list of standard, hard, hard-geometric")
    ap.add_argument("--workers", type=int, default=None, help="front-end processes")
    ap.add_argument("--runs", default="",
                    help="comma list of fixed, exp1, exp2, exp3, design (default: all)")
    ap.add_argument("--methods", default="bimcap,facap", help="comma list: bimcap, facap")
    ap.add_argument("--ifc-dir", type=Path, default=None,
                    help="folder of the real IFCs ifc-<name> reads (default: ../shared/data/ifc); "
                         "e.g. the variants bench/ifc_variants.py writes")
    ap.add_argument("--out", default="generalization.csv", help="CSV, appended to (resumable)")
    ap.add_argument("--features", action="append", default=[], metavar="KEY=VALUE",
                    type=_feature_setting,
                    help="a [features] setting of the refine config (SiftOptions field), e.g. "
                         "backend=orb; repeatable (default: the config's defaults, SIFT)")
    ap.add_argument("--matching", action="append", default=[], metavar="KEY=VALUE",
                    type=_feature_setting,
                    help="a [matching] setting of the refine config (MatchOptions field), e.g. "
                         "ransac_min_trials=30; repeatable (default: the config's defaults)")
    ap.add_argument("--geometric", action="append", default=[], metavar="KEY=VALUE",
                    type=_feature_setting,
                    help="a [geometric] setting of the refine config (GeometricOptions field of "
                         "the geometric segmenter), e.g. work_width=194; repeatable (default: "
                         "the config's defaults)")
    ap.add_argument("--summarise", nargs="+", metavar="CSV", help="only print the tables")
    args = ap.parse_args()
    if args.summarise:
        summarise(args.summarise)
    else:
        run(args)
        summarise([args.out])


if __name__ == "__main__":
    main()
