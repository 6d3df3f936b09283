"""``bimcap generate-building``: write a parametric IFC4 building and its ground-truth sidecar."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

NAME = "generate-building"
HELP = "write a parametric IFC4 building (corridor, rooms, columns, doors, windows)"
EXAMPLES = ("bimcap generate-building -o house.ifc --seed 0",
            "bimcap generate-building -o house.ifc --as-built house_as_built.ifc --storeys 2")

#: Spec fields the command line can override, with their flags.
_OVERRIDES: tuple[tuple[str, str, type], ...] = (
    ("--storeys", "storeys", int),
    ("--storey-height", "storey_height_m", float),
    ("--corridor-length", "corridor_length_m", float),
    ("--corridor-width", "corridor_width_m", float),
    ("--rooms-north", "rooms_north", int),
    ("--rooms-south", "rooms_south", int),
    ("--corridor-columns", "corridor_columns", int),
    ("--ceiling-height", "ceiling_height_m", float),
    ("--corridor-ceiling-height", "corridor_ceiling_height_m", float),
)


def register(subparsers: Any) -> None:
    from bimcap.cli import add_building_argument, add_out_argument

    p = subparsers.add_parser(
        NAME,
        help=HELP,
        description="Write a parametric IFC4 building and NAME.truth.json (walls, columns, "
        "openings, storey heights, walkable space in metres). Same seed, same bytes.",
    )
    add_out_argument(p, "the IFC file to write", required=True, type=Path, metavar="FILE.ifc")
    p.add_argument("--seed", type=int, default=0, help="design seed (default 0)")
    add_building_argument(p)
    for flag, name, kind in _OVERRIDES:
        p.add_argument(flag, dest=name, type=kind, default=None, help=f"override {name}")
    p.add_argument("--as-built", type=Path, default=None, metavar="FILE.ifc",
                   help="also write the as-built variant there")
    p.add_argument("--as-built-seed", type=int, default=1, help="seed of the deviations")
    p.add_argument("--shift-sigma", type=float, default=0.03,
                   help="as-built wall shift / column offset sigma in metres (default 0.03)")
    p.add_argument("--missing-fraction", type=float, default=0.1,
                   help="as-built fraction of removable elements left out (default 0.1)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing IFC files and their .truth.json sidecars")
    p.set_defaults(func=run, output_files=["out", "as_built"])


def run(args: argparse.Namespace) -> int:
    from bimcap.io.atomic import check_not_input
    from bimcap.sim.building import (
        PRESETS,
        BuildingSpecError,
        as_built,
        generate_building,
        replace_spec,
        truth_path_for,
    )

    outputs = [args.out]
    if args.as_built is not None:
        check_not_input(args.as_built, [args.out])
        outputs.append(args.as_built)
    if not args.overwrite:
        for path in outputs:
            for target in (path, truth_path_for(path)):
                if target.exists():
                    raise BuildingSpecError("already exists (use --overwrite to replace it)",
                                            target, "-o" if path == args.out else "--as-built")
    changes = {name: getattr(args, name) for _, name, _ in _OVERRIDES
               if getattr(args, name) is not None}
    spec = replace_spec(PRESETS[args.building], **changes)
    design = generate_building(spec, args.seed)
    design.write(args.out)
    _summary(design)
    if args.as_built is not None:
        built = as_built(design, args.as_built_seed, args.shift_sigma, args.missing_fraction)
        built.write(args.as_built)
        _summary(built)
    return 0


def _summary(b: Any) -> None:
    t = b.truth
    counts = ", ".join(f"{k[3:]} {v}" for k, v in t.counts.items())
    print(f"{b.ifc_path}: {t.variant.value}, seed {b.seed}: {counts}")
    for s in t.storeys:
        ceilings = sorted({c.z_min for c in t.coverings if c.storey == s.index})
        print(f"  storey {s.name}: elevation {s.elevation:.3f} m, floor {s.floor_z:.3f} m, "
              f"suspended ceilings at {', '.join(f'{z:.3f}' for z in ceilings)} m, "
              f"slab above from {s.wall_top_z:.3f} m")
    if t.deviations is not None:
        d = t.deviations
        worst = max((abs(v) for v in d.wall_shifts.values()), default=0.0)
        print(f"  deviations: {len(d.wall_shifts)} walls shifted (max {worst * 100:.1f} cm), "
              f"missing {len(d.missing)}: {', '.join(d.missing) or '-'}")
    print(f"  ground truth: {b.truth_path}")
