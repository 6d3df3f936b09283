"""The ``bimcap`` command line. Each sub-command lives in its own module here and exposes
``register(subparsers)``; this module imports everything, and nothing imports it.

Errors a user can cause (:class:`bimcap.errors.BimcapError`) print one clear line and exit with
status 2; a failed solve exits with 3. No traceback unless ``--debug``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from bimcap import __version__
from bimcap.errors import BimcapError

#: Sub-command modules, in the order ``bimcap --help`` lists them. A name whose module is not
#: part of this build is skipped (any other import error is raised).
COMMANDS: tuple[str, ...] = (
    "demo",
    "refine",
    "evaluate",
    "experiment",
    "generate_building",
    "bim",
    "simulate",
    "drift",
    "import_conslam",
    "solve_demo",
)

EXIT_BAD_INPUT = 2
EXIT_SOLVE_FAILED = 3


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bimcap",
        description="Refine a drifting camera + LiDAR trajectory against the building's BIM (IFC).",
    )
    parser.add_argument("--version", action="version", version=f"bimcap {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"bimcap.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"bimcap.cli.{name}":
                continue
            raise
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    try:
        return int(args.func(args) or 0)
    except BimcapError as exc:
        if args.debug:
            raise
        print(f"bimcap {args.command}: error: {exc}", file=sys.stderr)
        return getattr(exc, "exit_code", EXIT_BAD_INPUT)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
