"""``bimcap simulate``: ray-cast a handheld camera + VLP-16 walk through a building."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

NAME = "simulate"
HELP = "simulate a camera + LiDAR sequence (raw RGB, labels, depth, VLP-16) in a building"
EXAMPLES = ("bimcap simulate house.ifc -o seq/ --seed 0",
            "bimcap simulate house.ifc --as-built house_as_built.ifc -o seq/ --frames 60 "
            "--workers 0",
            'bimcap simulate Duplex_A.ifc -o seq2/ --storey "Level 1" --small')


def register(subparsers: Any) -> None:
    from bimcap.cli import add_out_argument
    from bimcap.sim.lidar import LidarConfig
    from bimcap.sim.walk import WalkConfig

    walk, lidar = WalkConfig(), LidarConfig()
    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description="Walk a handheld ConSLAM-like rig (raw RGB through the distorted camera, "
        "VLP-16 LiDAR at ConSLAM's extrinsic) through the building and write a sequence "
        "directory with ground-truth poses, label images and depth. Same seed, same files. "
        "The realism flags (pitch, field of view, LiDAR noise and dropout, clutter, label "
        "noise) make harder worlds; every setting goes into the manifest's 'source'.",
    )
    p.add_argument("model", type=Path, metavar="MODEL.ifc",
                   help="the design IFC (what the manifest refers to)")
    add_out_argument(p, "sequence directory to write", required=True, type=Path, metavar="SEQ")
    p.add_argument("--frames", type=int, default=200, help="number of frames (default 200)")
    p.add_argument("--seed", type=int, default=0, help="seed of the walk, clutter and noise")
    p.add_argument("--fps", type=float, default=3.0, help="camera frame rate in Hz (default 3)")
    p.add_argument("--scale", type=float, default=0.5,
                   help="image size relative to ConSLAM's 2064x1544 (default 0.5 -> 1032x772)")
    p.add_argument("--small", action="store_true",
                   help="the fast test configuration (320x239) unless --scale is given too")
    p.add_argument("--as-built", type=Path, default=None, metavar="FILE.ifc",
                   help="render this (as-built) IFC instead of the design model")
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

    g = p.add_argument_group("camera and walk")
    g.add_argument("--pitch-deg", type=float, default=walk.pitch_deg, metavar="DEG",
                   help="mean camera pitch while walking, degrees, negative looks down "
                   "(default %(default)s, as bimcap demo)")
    g.add_argument("--pitch-amplitude-deg", type=float, default=walk.pitch_amplitude_deg,
                   metavar="DEG", help="largest glance up above the walking pitch, degrees; "
                   "the walker looks up now and then and sees the ceiling; 0 = never "
                   "(default %(default)s)")
    g.add_argument("--look-up-interval", type=float, default=walk.look_up_interval_s,
                   metavar="S", help="mean seconds between glances up (default %(default)s)")
    fov = g.add_mutually_exclusive_group()
    fov.add_argument("--focal-scale", type=float, default=1.0, metavar="F",
                     help="multiply the focal length by F: 1.5 = a narrower view "
                     "(default %(default)s, ConSLAM's lens)")
    fov.add_argument("--hfov-deg", type=float, default=None, metavar="DEG",
                     help="horizontal field of view in degrees instead of --focal-scale "
                     "(pinhole across the image width; ConSLAM's is about 47)")

    g = p.add_argument_group("LiDAR")
    g.add_argument("--lidar-noise", type=float, default=lidar.range_noise_m, metavar="M",
                   help="range noise sigma in metres at short range facing the surface; it "
                   "grows with range and at grazing incidence (default %(default)s)")
    g.add_argument("--lidar-dropout", type=float, default=lidar.dropout, metavar="FRAC",
                   help="fraction of returns lost, half at random and half where the beam "
                   "grazes the surface, besides glass and beams too grazing to return "
                   "(default %(default)s)")

    g = p.add_argument_group("clutter and labels")
    g.add_argument("--clutter", type=float, default=None, metavar="PER_M2",
                   help="clutter objects (boxes, pallets, scaffolds, people) per m^2 of free "
                   "floor (default 0.08)")
    g.add_argument("--no-clutter", action="store_true", help="do not add clutter (= --clutter 0)")
    g.add_argument("--label-noise", type=float, default=0.0, metavar="FRAC",
                   help="fraction of labelled pixels written with a wrong class, in blobs; the "
                   "true labels go to labels_gt/ (default %(default)s)")
    g.add_argument("--label-boundary-px", type=float, default=0.0, metavar="PX",
                   help="class boundaries in labels/ wander by up to PX pixels: errors near "
                   "boundaries, counted in --label-noise (default %(default)s)")
    p.set_defaults(func=run, output_dirs=["out"], input_paths=["model", "as_built"])


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from bimcap.errors import InputError
    from bimcap.sim.label_noise import LabelNoiseConfig
    from bimcap.sim.lidar import LidarConfig
    from bimcap.sim.simulator import (
        CONSLAM_CAMERA,
        SimulatorConfig,
        focal_scale_for_hfov,
        simulate,
        with_focal_scale,
    )
    from bimcap.sim.walk import WalkConfig

    if args.no_clutter and args.clutter:
        raise InputError("--no-clutter contradicts --clutter", field="--clutter")
    base = SimulatorConfig.small() if args.small else SimulatorConfig()
    camera = base.camera
    if not args.small or args.scale != 0.5:
        camera = CONSLAM_CAMERA.scaled(args.scale)
    focal_scale = (args.focal_scale if args.hfov_deg is None
                   else focal_scale_for_hfov(camera, args.hfov_deg))
    if focal_scale != 1.0:
        camera = with_focal_scale(camera, focal_scale)
    density = base.clutter_density_per_m2 if args.clutter is None else args.clutter
    cfg = replace(
        base,
        camera=camera,
        frames=args.frames,
        fps=args.fps,
        lidar=None if args.no_lidar else LidarConfig(range_noise_m=args.lidar_noise,
                                                     dropout=args.lidar_dropout),
        walk=replace(WalkConfig(), speed_mps=args.speed, pitch_deg=args.pitch_deg,
                     pitch_amplitude_deg=args.pitch_amplitude_deg,
                     look_up_interval_s=args.look_up_interval),
        clutter_density_per_m2=0.0 if args.no_clutter else density,
        label_noise=LabelNoiseConfig(args.label_noise, args.label_boundary_px),
        z_floor=args.z_floor,
        storey=args.storey,
        write_depth=not args.no_depth,
        workers=args.workers,
        threads_per_worker=1 if args.workers != 1 else 0,
    )
    cli = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()
           if k not in ("func", "verbose", "quiet")}  # what the files depend on
    seq = simulate(args.model, args.out, cfg, args.seed, args.as_built,
                   clutter=not args.no_clutter, overwrite=args.overwrite,
                   source={"command_line": cli, "focal_scale": focal_scale})
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
    noise = seq.source.get("label_noise_measured")
    if noise:
        print(f"label noise: {noise['wrong_fraction_mean']:.1%} of labelled pixels wrong "
              f"(true labels in labels_gt/)")
    return 0
