"""``bimcap refine SEQUENCE --ifc MODEL.ifc --init poses.tum -o OUT/``."""

from __future__ import annotations

import argparse
import shlex
import sys
from typing import Any

from bimcap.methods import CompletionMethod, ExecutorKind
from bimcap.pipeline.config import (
    GEOMETRIC_MODES,
    LOSSES,
    ColmapExport,
    LabelSource,
    Method,
    RefineConfig,
)

NAME = "refine"
HELP = "refine a sequence's trajectory against the BIM"
EXAMPLES = ("bimcap refine seq/ --ifc house.ifc --init seq/poses/init.tum -o out/",
            "bimcap refine seq/ -o out_facap/ --method facap --terms G+F+W",
            "bimcap refine --print-config > settings.toml; bimcap refine seq/ -o out/ "
            "--config settings.toml -v")


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    """The flags shared by ``refine`` and ``demo`` (each overrides the config file)."""
    g = p.add_argument_group("method (flags override --config)")
    g.add_argument("--config", metavar="FILE.toml",
                   help="settings file (see bimcap.pipeline.config; --print-config writes one)")
    g.add_argument("--method", choices=[m.value for m in Method], help="bimcap (default) or facap")
    g.add_argument("--terms",
                   help="terms to use, e.g. G+F+W+Co+Ce (default: the method's full set)")
    g.add_argument("--weighting", choices=["robust", "paper"],
                   help="the solver preset. robust: noise scales + robust losses (BIMCaP "
                        "default); paper: the peers' means, plain L2 (FACaP default)")
    g.add_argument("--loss", choices=list(LOSSES),
                   help="robust loss of the paper's terms (default: the preset's, cauchy)")
    g.add_argument("--geometric", dest="geometric_mode", choices=list(GEOMETRIC_MODES),
                   help="the G term's residual (default: the preset's)")
    g.add_argument("--completion", choices=[d.value for d in CompletionMethod],
                   help="dense depth source")
    g.add_argument("--completion-model", metavar="MODEL.onnx", help="for --completion onnx/hybrid")
    g.add_argument("--segmentation", choices=[s.value for s in LabelSource], help="label source")
    g.add_argument("--segmentation-model", metavar="MODEL.onnx", help="for --segmentation onnx")
    g.add_argument("--labels-dir", metavar="DIR", help="for --segmentation disk")
    g.add_argument("--coarse", action=argparse.BooleanOptionalAction, default=None,
                   help="coarse registration to the floor plan before the bundle adjustment "
                        "(default: on for BIMCaP, off for FACaP)")
    g.add_argument("--global-align", action=argparse.BooleanOptionalAction, default=None,
                   help="the initial trajectory is in its own (SLAM) frame: place it in the BIM "
                        "first (x, y, yaw, storey; default: auto, when most initial cameras lie "
                        "outside the building's free space)")
    g.add_argument("--accept-ambiguous", action="store_true", default=None,
                   help="take the best global alignment even when another placement scores "
                        "nearly as well (default: refuse, listing the placements)")
    g.add_argument("--lidar-scan", action=argparse.BooleanOptionalAction, default=None,
                   help="the LiDAR scan outside the camera's view gives wall, floor and ceiling "
                        "samples too (default: on for BIMCaP, off for FACaP)")
    g.add_argument("--rotation-first", action=argparse.BooleanOptionalAction, default=None,
                   help="rotations first (translations held), then translations, then both")
    g.add_argument("--staged", action=argparse.BooleanOptionalAction, default=None,
                   help="solve with the BIM terms only and 4x wider robust losses before all terms")
    g.add_argument("--window", type=int, help="match each frame with its next N frames")
    g.add_argument("--max-match-distance", type=float,
                   help="drop matches whose points are further apart under the initial poses (m)")
    g.add_argument("--workers", type=int,
                   help="front-end processes, and the global alignment's threads (default: all "
                        "cores)")
    g.add_argument("--dask", action="store_true", default=None,
                   help="run the front end's per-frame work on Dask: a LocalCluster on this "
                        "machine, or the cluster of --dask-scheduler (docs/dask.md)")
    g.add_argument("--dask-scheduler", metavar="tcp://HOST:PORT",
                   help="use the running Dask cluster of this scheduler (implies --dask)")
    g.add_argument("--dask-workers", type=int, metavar="N",
                   help="worker processes of the LocalCluster (implies --dask; default: "
                        "--workers, else all cores)")
    g.add_argument("--lidar-nan", choices=["raise", "drop"],
                   help="a LiDAR scan with NaN/inf points: stop with an error naming the scan "
                        "(raise, default) or drop those points (drop; a scan without any valid "
                        "point gives its frame no depth)")
    g.add_argument("--max-lost-fraction", type=float, metavar="F",
                   help="refuse an IFC that lost more than this share of its building elements "
                        "to damage (default 0.02); smaller losses are warnings")
    g.add_argument("--colmap", choices=[c.value for c in ColmapExport],
                   help="the COLMAP model of the refined reconstruction in OUT/colmap: images "
                        "(default: sparse/0 and the undistorted images), model (sparse/0 "
                        "alone), off")
    g.add_argument("--rerun", action="store_true", default=None,
                   help="also write the run as a Rerun recording, OUT/run.rrd (BIM, "
                        "trajectories, cameras with images, map, errors; needs "
                        "pip install 'bimcap[rerun]'; bimcap export-rerun does it afterwards)")


def config_from_args(args: argparse.Namespace) -> RefineConfig:
    """The run's settings: ``--config`` with the flags over it; ``-v`` turns the solver's
    ``verbose`` on."""
    from bimcap.cli import verbosity

    keys = ("method", "terms", "weighting", "loss", "geometric_mode", "completion",
            "completion_model", "segmentation", "segmentation_model", "labels_dir", "coarse",
            "rotation_first", "staged", "window", "max_match_distance", "workers", "lidar_nan",
            "max_lost_fraction", "colmap", "accept_ambiguous", "lidar_scan", "rerun", "datum",
            "datum_fit", "map_storey")
    overrides: dict[str, Any] = {k: getattr(args, k) for k in keys
                                 if getattr(args, k, None) is not None}
    if getattr(args, "global_align", None) is not None:
        overrides["global_align"] = "on" if args.global_align else "off"
    cfg = (RefineConfig.from_toml(args.config, **overrides) if args.config
           else RefineConfig(**overrides))
    dask = {key: getattr(args, flag) for key, flag in
            (("scheduler", "dask_scheduler"), ("workers", "dask_workers"))
            if getattr(args, flag, None) is not None}
    if dask or getattr(args, "dask", None):  # the flags add to the file's [dask] table
        cfg = cfg.with_(executor=ExecutorKind.DASK, dask={**cfg.dask, **dask})
    if verbosity(args) > 0:  # -v: Ceres' per-iteration progress (SolverOptions.verbose)
        cfg = cfg.with_(solver={**cfg.solver, "verbose": True})
    return cfg


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    from bimcap.cli import add_out_argument

    p = sub.add_parser(
        NAME,
        help=HELP,
        description=(
            "Refine the initial trajectory of a sequence directory against the building's IFC: "
            "BIM reference, front end (depth, labels, matches), Ceres bundle adjustment. Writes "
            "refined.tum, summary.json, map_before/after.ply, the COLMAP model colmap/sparse/0 "
            "(with the undistorted images in colmap/images), report.html, with --rerun the Rerun "
            "recording run.rrd, and result.json (every file of the run with its SHA-256) into "
            "OUT as one set. Every setting and input is "
            "checked before any expensive stage."
        ),
    )
    p.add_argument("sequence", nargs="?",
                   help="sequence directory (bimcap simulate / import-conslam)")
    add_out_argument(p, "output directory (required unless --print-config)", metavar="DIR")
    p.add_argument("--ifc", metavar="MODEL.ifc",
                   help="the BIM (default: the sequence manifest's ifc)")
    p.add_argument("--init", help="initial poses, TUM (default: SEQUENCE/poses/init.tum)")
    p.add_argument("--gt",
                   help="ground truth TUM for metrics (default: SEQUENCE/poses/gt.tum if any)")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument("--deviations", action="store_true",
                   help="also write the scan-vs-BIM deviations under the refined poses "
                        "(deviations.json/.csv/.ply; see bimcap deviations)")
    p.add_argument("--datum", action="append", metavar="SEL",
                   help="with --deviations: an element declared as built right (IFC GUID, "
                        "name:PATTERN or class:IfcClass; repeat or comma-separate): the "
                        "deviations are measured after the rigid correction (x, y, yaw; z from "
                        "slabs) that puts the datum on the design (overrides the config's datum)")
    p.add_argument("--datum-fit", choices=["frames", "rigid"],
                   help="with --datum: frames (default: rigid, then per frame jointly with the "
                        "other elements' offsets) or rigid (one correction of the trajectory)")
    p.add_argument("--map-storey", metavar="NAME",
                   help="crop map_refined.ply to this storey of the IFC (by name; checked "
                        "before the front end; default: every return)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace files in OUT that bimcap did not write (default: refuse)")
    p.add_argument("--print-config", action="store_true",
                   help="print every setting of the run (solver and registration options "
                        "included) as TOML that --config reads back, and exit")
    add_config_arguments(p)
    p.set_defaults(func=run, output_dirs=["out"])


def run(args: argparse.Namespace) -> int:
    from bimcap.pipeline.config import ConfigError, toml_text
    from bimcap.pipeline.refine import effective_settings, refine, summary_table

    cfg = config_from_args(args)
    if args.print_config:
        print(toml_text(effective_settings(cfg), header=f"{command_line()}\nbimcap refine "
                        "settings: pass this file to --config to run with them"), end="")
        return 0
    for name, flag in (("sequence", "SEQUENCE"), ("out", "-o/--out")):
        if getattr(args, name) is None:
            raise ConfigError(f"{flag} is required (unless --print-config)", field=name)
    result = refine(args.sequence, args.out, cfg, ifc=args.ifc, init=args.init, gt=args.gt,
                    report=not args.no_report, command=command_line(),
                    overwrite=args.overwrite, deviations=args.deviations)
    print(result.outcome.summary.table())
    if result.metrics_after is not None:
        print(summary_table({"initial": result.metrics_before, "refined": result.metrics_after}))
    if result.deviations is not None:
        print("deviations: " + ", ".join(f"{n} {k}" for k, n in
                                         result.deviations["counts"].items()))
    print(f"wrote {result.out_dir}/refined.tum" + (
        f" and {result.out_dir}/{result.files['report']}" if "report" in result.files else ""))
    return 0


def command_line(argv: list[str] | None = None) -> str:
    return "bimcap " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
