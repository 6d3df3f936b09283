"""``bimcap simulate``: ray-cast a handheld camera + VLP-16 walk through a building."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="simulate a camera + LiDAR sequence (raw RGB, labels, depth, VLP-16) in a building",
        description="Walk a handheld ConSLAM-like rig (raw RGB through the distorted camera, "
        "VLP-16 LiDAR at ConSLAM's extrinsic) through the building and write a sequence "
        "directory with ground-truth poses, label images and depth. Same seed, same files.",
    )
    p.add_argument("model", type=Path, help="the design IFC (what the manifest refers to)")
    p.add_argument("-o", "--output", required=True, type=Path, help="sequence directory to write")
    p.add_argument("--frames", type=int, default=200, help="number of frames (default 200)")
    p.add_argument("--seed", type=int, default=0, help="seed of the walk, clutter and noise")
    p.add_argument("--fps", type=float, default=3.0, help="camera frame rate in Hz (default 3)")
    p.add_argument("--scale", type=float, default=0.5,
                   help="image size relative to ConSLAM's 2064x1544 (default 0.5 -> 1032x772)")
    p.add_argument("--small", action="store_true",
                   help="the fast test configuration (320x239) unless --scale is given too")
    p.add_argument("--as-built", type=Path, default=None, metavar="FILE.ifc",
                   help="render this (as-built) IFC instead of the design model")
    p.add_argument("--no-clutter", action="store_true", help="do not add clutter")
    p.add_argument("--no-lidar", action="store_true", help="write empty LiDAR scans")
    p.add_argument("--no-depth", action="store_true", help="do not write ground-truth depth")
    p.add_argument("--speed", type=float, default=1.0, help="walking speed in m/s (default 1)")
    p.add_argument("--storey", default=None, metavar="NAME",
                   help="walk this storey of the model (its IfcBuildingStorey name); default: "
                   "the generator's sidecar storey, or for any other IFC the storey with the "
                   "largest connected walkable area (floor under foot, roof overhead, walls "
                   "around, 0.42 m clearance, doors passable)")
    p.add_argument("--z-floor", type=float, default=None,
                   help="walk the floor at this height in metres instead of a storey "
                   "(overrides --storey)")
    p.add_argument("--workers", type=int, default=2,
                   help="render processes (default 2; 0 = one per CPU; 1 = in-process)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing sequence in the output directory")
    p.set_defaults(func=run, output_dirs=["output"], input_paths=["model", "as_built"])


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from bimcap.sim.lidar import LidarConfig
    from bimcap.sim.simulator import CONSLAM_CAMERA, SimulatorConfig, simulate
    from bimcap.sim.walk import WalkConfig

    base = SimulatorConfig.small() if args.small else SimulatorConfig()
    camera = base.camera
    if not args.small or args.scale != 0.5:
        camera = CONSLAM_CAMERA.scaled(args.scale)
    cfg = replace(
        base,
        camera=camera,
        frames=args.frames,
        fps=args.fps,
        lidar=None if args.no_lidar else LidarConfig(),
        walk=replace(WalkConfig(), speed_mps=args.speed),
        z_floor=args.z_floor,
        storey=args.storey,
        write_depth=not args.no_depth,
        workers=args.workers,
        threads_per_worker=1 if args.workers != 1 else 0,
    )
    seq = simulate(args.model, args.output, cfg, args.seed, args.as_built,
                   clutter=not args.no_clutter, overwrite=args.overwrite)
    cam = seq.camera
    span = seq.frames[-1].timestamp - seq.frames[0].timestamp
    print(
        f"wrote {len(seq.frames)} frames ({cam.width}x{cam.height}, "
        f"{span:.1f} s at {args.fps:g} Hz) to {seq.root}"
    )
    walkable = seq.source.get("walkable")
    if walkable:
        chosen = next(s for s in walkable["surveys"] if s["name"] == walkable["storey"])
        print(f"walked storey {walkable['storey']!r} (floor at {walkable['z_floor']:+.2f} m, "
              f"{chosen['walkable_m2']:.0f} m² walkable; free space found in "
              f"{walkable['seconds']:.1f} s)")
    for note in seq.source.get("synthetic_floors", []):
        print(f"note: {note}")
    return 0
