"""``bimcap deviations RUN_DIR`` / ``bimcap deviations --sequence SEQ --poses P.tum --ifc M.ifc
-o OUT``: which element was built differently from the model, from the refined scans."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

NAME = "deviations"
HELP = "scan-vs-BIM deviations per IFC element (offset, coverage, missing, unobserved)"
EXAMPLES = ("bimcap deviations out/",
            "bimcap deviations --sequence seq/ --poses out/refined.tum --ifc house.ifc "
            "-o dev/ --tolerance 0.03")


def register(sub: Any) -> None:
    from bimcap.cli import add_out_argument, add_overwrite_argument

    p = sub.add_parser(
        NAME,
        help=HELP,
        description=(
            "Per IFC element (walls, columns, slabs, coverings): the share of its visible faces "
            "the scans saw, its offset along its face normal (robust), a wall's tilt, and a "
            "status: ok, deviating (offset beyond --tolerance), missing (free space seen "
            "through it), unobserved; plus the clusters of points no element explains. Reads a "
            "refine run directory (its result.json names the sequence and the IFC; poses "
            "refined.tum) or explicit --sequence/--poses/--ifc. Writes deviations.json, "
            "deviations.csv, deviations.ply (the map coloured by offset), deviations.png (the "
            "floor plan coloured by offset), deviations.ifc (the design with a "
            "BIMCaP_Deviation property set per element) and deviations.bcfzip (BCF 2.1: one "
            "topic per deviating or missing element, with a viewpoint on it) into -o (default "
            "RUN_DIR/deviations)."
        ),
    )
    p.add_argument("run_dir", nargs="?", type=Path, help="a bimcap refine output directory")
    p.add_argument("--sequence", type=Path, help="sequence directory (default: the run's)")
    p.add_argument("--poses", type=Path,
                   help="world_from_cam TUM, one pose per frame (default: RUN_DIR/refined.tum)")
    p.add_argument("--ifc", type=Path, metavar="MODEL.ifc",
                   help="the design IFC (default: the run's)")
    add_out_argument(p, "output directory (default RUN_DIR/deviations)", type=Path,
                     metavar="DIR")
    p.add_argument("--tolerance", type=float, default=0.02, metavar="M",
                   help="offsets beyond this are 'deviating' (default 0.02 m)")
    p.add_argument("--storey", help="analyse only this storey's elements (by name)")
    p.add_argument("--datum", action="append", metavar="SEL",
                   help="an element declared as built right: its IFC GUID, name:PATTERN (shell "
                        "pattern on the Name) or class:IfcClass; repeat or comma-separate. The "
                        "poses are first corrected by the rigid motion (x, y, yaw; z when a "
                        "slab or ceiling is in it) that puts the datum on the design, so the "
                        "other elements' offsets are relative to it (default: relative to the "
                        "poses)")
    p.add_argument("--datum-fit", choices=["frames", "rigid"], default=None,
                   help="with --datum: frames (default) = the rigid correction, then one small "
                        "correction per frame fitted jointly with the other elements' offsets; "
                        "rigid = one rigid correction of the whole trajectory")
    p.add_argument("--no-datum", action="store_true",
                   help="ignore the datum of the refine run in RUN_DIR (by default its "
                        "--datum / datum and --datum-fit are used again when --datum is not "
                        "given)")
    p.add_argument("--voxel", type=float, default=0.03, metavar="M",
                   help="voxel of the map the clusters and the PLY use (default 0.03 m)")
    p.add_argument("--top", type=int, default=10, metavar="N",
                   help="print the N largest deviations (default 10)")
    add_overwrite_argument(p, "existing deviations.* files in OUT")
    p.set_defaults(func=run, output_dirs=["out"], input_paths=["run_dir", "sequence", "poses",
                                                              "ifc"])


def run_datum(args: argparse.Namespace) -> tuple[list[str], str]:
    """The datum selectors and fit to use: ``--datum`` / ``--datum-fit`` when given, else (unless
    ``--no-datum``) those the refine run in ``RUN_DIR`` was given (its ``result.json`` →
    ``config``), else none. ``([], "frames")`` for no datum."""
    from bimcap.io.outputs import read_result

    fit = args.datum_fit
    if args.datum or args.no_datum or args.run_dir is None:
        return list(args.datum or []) if not args.no_datum else [], fit or "frames"
    doc = read_result(args.run_dir) or {}
    config = doc.get("config") if isinstance(doc.get("config"), dict) else {}
    selectors = config.get("datum") or []
    if not isinstance(selectors, list) or not all(isinstance(x, str) for x in selectors):
        return [], fit or "frames"
    run_fit = config.get("datum_fit")
    return list(selectors), fit or (run_fit if isinstance(run_fit, str) else "frames")


def resolve_inputs(args: argparse.Namespace) -> tuple[Path, Path, Path, Path]:
    """``(sequence, poses, ifc, out)`` from ``args``: explicit flags first, then the run
    directory's ``result.json`` (``inputs``) and ``refined.tum``; raises
    :class:`bimcap.deviations.analysis.DeviationInputError` naming what is missing."""
    from bimcap.deviations.analysis import DeviationInputError
    from bimcap.io.outputs import RESULT_NAME, read_result

    run: Path | None = args.run_dir
    inputs: dict[str, Any] = {}
    if run is not None:
        if not run.is_dir():
            raise DeviationInputError("not a directory", run, "RUN_DIR")
        doc = read_result(run)
        if doc is None:
            raise DeviationInputError(f"no bimcap {RESULT_NAME} here: not a refine run", run,
                                      RESULT_NAME)
        inputs = dict(doc.get("inputs") or {})
    seq = args.sequence or (Path(inputs["sequence"]) if "sequence" in inputs else None)
    ifc = args.ifc or (Path(inputs["ifc"]) if "ifc" in inputs else None)
    poses = args.poses or (run / "refined.tum" if run is not None else None)
    out = args.out or (run / "deviations" if run is not None else None)
    where = run / RESULT_NAME if run is not None else None
    for value, name in ((seq, "sequence"), (ifc, "ifc"), (poses, "poses"), (out, "out")):
        if value is None:
            raise DeviationInputError(f"--{name} is required (the run directory does not name "
                                      "it)" if run is not None else
                                      f"give RUN_DIR or --{name}", where, name)
    assert seq is not None and ifc is not None and poses is not None and out is not None
    return seq, poses, ifc, out


def run(args: argparse.Namespace) -> int:
    from bimcap.bim.ingest import check_ifc_file
    from bimcap.dataset import read_sequence
    from bimcap.deviations.analysis import DeviationInputError, DeviationOptions, load_design
    from bimcap.deviations.datum import DatumSpec, check_datum
    from bimcap.deviations.outputs import DEVIATION_OUTPUTS, run_deviations
    from bimcap.geometry.trajectory import read_tum
    from bimcap.io.atomic import check_not_input
    from bimcap.pipeline.refine import check_trajectory

    seq_path, poses_path, ifc, out = resolve_inputs(args)
    options = DeviationOptions(tolerance_m=args.tolerance)
    if args.no_datum and args.datum:
        raise DeviationInputError("--no-datum and --datum exclude each other", None, "--datum")
    selectors, fit = run_datum(args)
    from_run = bool(selectors) and not args.datum
    datum = DatumSpec.parse(selectors, "datum of RUN_DIR/result.json" if from_run else "--datum",
                            fit)
    if from_run:
        print(f"datum of the refine run: {', '.join(selectors)} (fit: {fit}); --no-datum "
              "ignores it", file=sys.stderr)
    check_ifc_file(ifc)
    seq = read_sequence(seq_path)
    traj = check_trajectory(seq, read_tum(poses_path), poses_path, "refined")
    for name in DEVIATION_OUTPUTS:
        check_not_input(out / name, [poses_path, ifc, seq.manifest_path])
        if (out / name).exists() and not args.overwrite:
            raise DeviationInputError("exists; pass --overwrite to replace it", out / name)
    model = load_design(ifc)
    if datum is not None:  # before the scans: an unknown GUID or a free yaw fails fast
        free = check_datum(model, datum.resolve(model), datum.source, ifc)
        if free:
            print(f"warning: the datum leaves {', '.join(free)} free: the poses' "
                  f"{', '.join(free)} is kept", file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    result = run_deviations(seq, traj.poses, ifc, out, options, args.storey, args.voxel,
                            datum=datum, model=model)
    rep = result.report
    d = rep.datum
    if d.get("mode") == "datum":
        tx, ty, tz = (100 * v for v in d["translation_m"])
        print(f"datum: {len(d['guids'])} element(s); poses corrected by ({tx:+.1f}, {ty:+.1f}, "
              f"{tz:+.1f}) cm, yaw {d['yaw_deg']:+.3f} deg"
              + (f"; {', '.join(d['free'])} left free" if d["free"] else "")
              + (f"; then per frame, {100 * d['frames']['frame_step_rms_m']:.1f} cm RMS"
                 if "frames" in d else ""))
    else:
        print("offsets are relative to the given poses (no datum)")
    print("elements: " + ", ".join(f"{n} {k}" for k, n in rep.counts().items())
          + f"; {len(rep.clusters)} unexplained clusters; {result.seconds:.1f} s")
    judged = [e for e in rep.elements if e.offset_m is not None]
    judged.sort(key=lambda e: -abs(e.offset_m or 0.0))
    for e in judged[:args.top]:
        print(f"  {e.status.value:<10} {(e.offset_m or 0.0) * 100:+7.1f} cm  {e.ifc_class:<14} "
              f"{e.name or e.guid}  (coverage {e.coverage:.0%}, {e.n_points} points)")
    for e in rep.elements:
        if e.status.value == "missing":
            print(f"  missing              {e.ifc_class:<14} {e.name or e.guid}")
    print(f"wrote {out}/" + ", ".join(DEVIATION_OUTPUTS))
    return 0
