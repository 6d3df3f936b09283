"""``bimcap experiment``: the paper's Tables 1 and 2 on the synthetic world."""

from __future__ import annotations

import argparse

from bimcap.cli.refine import add_config_arguments, config_from_args

NAME = "experiment"
HELP = "the paper's experiments (drift presets x ablations x seeds) on the synthetic world"
EXAMPLES = ("bimcap experiment -o exp/",
            "bimcap experiment -o exp/ --experiments exp2 --seeds 1,2 --building tiny")


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    from bimcap.cli import add_building_argument, add_out_argument

    p = sub.add_parser(
        NAME,
        help=HELP,
        description=(
            "For each drift preset and seed, drift the simulated sequence, run the front end once "
            "and solve every ablation row of the paper's Table 1 (BIMCaP and FACaP). Writes "
            "results.csv, table1.md, table2.md (paper numbers beside) and ate.png into OUT."
        ),
    )
    add_out_argument(p, "output directory", required=True, metavar="DIR")
    p.add_argument("--experiments", default="exp1,exp2,exp3", help="comma-separated drift presets")
    p.add_argument("--seeds", default="1,2,3", help="comma-separated drift seeds")
    add_building_argument(p)
    p.add_argument("--frames", type=int, default=60, help="simulated frames (default 60)")
    p.add_argument("--scale", type=float, default=0.25,
                   help="image size relative to ConSLAM's 2064x1544 (default 0.25)")
    p.add_argument("--world-seed", type=int, default=0,
                   help="seed of the building and the walk (default 0); --seeds are the "
                        "drifts'")
    p.add_argument("--deviations", action="store_true",
                   help="also score the scan-vs-BIM deviations of every row against the "
                        "as-built's truth (columns dev_*)")
    add_config_arguments(p)
    p.set_defaults(func=run, output_dirs=["out"])


def run(args: argparse.Namespace) -> int:
    from bimcap.errors import InputError
    from bimcap.pipeline.experiment import ExperimentOptions, run_experiment, table2_markdown

    try:
        seeds = tuple(int(s) for s in args.seeds.split(",") if s.strip())
    except ValueError:
        raise InputError(f"--seeds must be integers, got {args.seeds!r}", field="--seeds") from None
    exps = tuple(e.strip() for e in args.experiments.split(",") if e.strip())
    bad = [e for e in exps if e not in ("exp1", "exp2", "exp3")]
    if bad or not exps or not seeds:
        raise InputError(f"--experiments must name exp1/exp2/exp3, got {args.experiments!r}",
                         field="--experiments")
    opts = ExperimentOptions(experiments=exps, seeds=seeds, preset=args.building,
                             frames=args.frames, scale=args.scale, world_seed=args.world_seed,
                             config=config_from_args(args), deviations=args.deviations)
    records = run_experiment(args.out, opts)
    print(table2_markdown(records))
    print(f"wrote {args.out}/results.csv, table1.md, table2.md, ate.png")
    return 0
