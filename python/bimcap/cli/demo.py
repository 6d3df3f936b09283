"""``bimcap demo``: the whole pipeline on the embedded synthetic world."""

from __future__ import annotations

import argparse

from bimcap.cli.refine import add_config_arguments, config_from_args

NAME = "demo"
HELP = "end-to-end demo on a generated building (no data needed)"
EXAMPLES = ("bimcap demo -o demo_out",
            "bimcap demo --building tiny --frames 20 --no-facap -o /tmp/demo -q")


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    from bimcap.cli import add_building_argument, add_out_argument

    p = sub.add_parser(
        NAME,
        help=HELP,
        description=(
            "Generate a building, simulate a camera + LiDAR walk through its as-built variant, "
            "drift the trajectory (exp2 by default), refine it with FACaP and BIMCaP, and print "
            "a before/after table; writes every artefact and report.html into OUT."
        ),
    )
    add_out_argument(p, "output directory (default demo_out)", default="demo_out",
                     metavar="DIR")
    add_building_argument(p)
    p.add_argument("--seed", type=int, default=0, help="seed of building, walk and drift")
    p.add_argument("--frames", type=int, default=60, help="simulated frames (default 60)")
    p.add_argument("--scale", type=float, default=0.25,
                   help="image size relative to ConSLAM's 2064x1544 (default 0.25 -> 516x386)")
    p.add_argument("--drift", default="exp2", choices=["exp1", "exp2", "exp3"],
                   help="drift preset of the initial trajectory (default exp2)")
    p.add_argument("--no-facap", action="store_true", help="skip the FACaP comparison")
    p.add_argument("--overwrite", action="store_true",
                   help="replace files in OUT/refine that bimcap did not write (default: refuse)")
    add_config_arguments(p)
    p.set_defaults(func=run, output_dirs=["out"])


def run(args: argparse.Namespace) -> int:
    from bimcap.pipeline.demo import DemoOptions, run_demo

    opts = DemoOptions(preset=args.building, seed=args.seed, frames=args.frames, scale=args.scale,
                       drift=args.drift, config=config_from_args(args), facap=not args.no_facap)
    res = run_demo(args.out, opts, overwrite=args.overwrite)
    print(res.table)
    print(f"demo finished in {res.seconds:.1f} s; report: {res.report}")
    return 0
