"""``bimcap export-rerun RUN_DIR -o run.rrd``: a finished refine run as a Rerun recording."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "export-rerun"
HELP = "a refine run as a Rerun recording (.rrd): BIM, trajectories, cameras, images, map, errors"
EXAMPLES = ("bimcap export-rerun out/ -o out/run.rrd",
            "bimcap export-rerun demo_out/refine -o demo.rrd --no-images; rerun demo.rrd")


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    from bimcap.cli import add_out_argument, add_overwrite_argument

    p = sub.add_parser(
        NAME,
        help=HELP,
        description=(
            "Write the run in RUN_DIR (what bimcap refine writes, or OUT/refine of bimcap demo) "
            "as a Rerun recording, in the BIM frame (z up, metres): the floor plan's walls and "
            "columns, the initial, refined and ground-truth trajectories, the refined camera of "
            "each frame with its image on the timelines 'frame' and 'time', the refined LiDAR "
            "map and the per-frame position and rotation errors. Open it with `rerun FILE.rrd` "
            "(pip install 'bimcap[rerun]'). The images come from the sequence result.json names; "
            "without it the recording has none."
        ),
    )
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR",
                   help="a refine output directory (with result.json)")
    add_out_argument(p, "the recording to write (.rrd)", required=True, type=Path,
                     metavar="FILE.rrd")
    p.add_argument("--no-images", action="store_true",
                   help="leave the frames' images out (a much smaller file)")
    p.add_argument("--image-scale", type=float, default=0.5, metavar="S",
                   help="image size relative to the camera's (default 0.5)")
    p.add_argument("--max-points", type=int, default=100_000, metavar="N",
                   help="at most N points of map_refined.ply (default 100000)")
    add_overwrite_argument(p, "an existing FILE.rrd")
    p.set_defaults(func=run, output_files=["out"], input_paths=["run_dir"])


def run(args: argparse.Namespace) -> int:
    import logging

    from bimcap.errors import InputError
    from bimcap.pipeline.rerun_export import RecordingOptions, export_run, require_rerun

    require_rerun()  # before any file is read
    options = RecordingOptions(images=not args.no_images, image_scale=args.image_scale,
                               max_points=args.max_points)
    if args.out.exists() and not args.overwrite:
        raise InputError("exists; pass --overwrite to replace it", args.out)
    summary = export_run(args.run_dir, args.out, options)
    logging.getLogger("bimcap").debug("recording: %s", summary.to_dict())
    print(f"wrote {summary.path}: {summary.frames} frames, {summary.images} images, "
          f"{summary.map_points} map points, {summary.bim_segments} BIM segments, "
          f"{summary.bytes / 1e6:.1f} MB")
    return 0
