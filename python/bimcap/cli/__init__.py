"""The ``bimcap`` command line. Each sub-command lives in its own module here and exposes
``register(subparsers)``; this module imports everything, and nothing imports it.

Every failure prints one clear line and exits with a documented status (``bimcap.errors``,
docs/reliability.md): 2 bad input or settings (:class:`bimcap.errors.BimcapError`), 3 a failed
solve or pipeline step, 4 the operating system refused a file operation (any :class:`OSError`:
permission denied, read-only file system, disk full, a file where a directory is needed; mapped in
one place, :func:`bimcap.errors.describe_os_error`), 130 interrupted. No traceback unless
``--debug``.

Sub-commands declare their outputs and inputs with ``set_defaults(output_dirs=[...],
output_files=[...], input_paths=[...])`` (names of ``args`` attributes): before the command runs,
:func:`main` checks that no output is an input and that each can be written
(:func:`bimcap.io.outputs.check_output_dir` / ``check_output_file``), so that a read-only or
mistyped ``-o`` fails at once, not after the expensive stages.

Messages: every sub-command takes ``-v/--verbose`` (DEBUG, and the Ceres solver's per-iteration
progress) and ``-q/--quiet`` (warnings and errors only, no progress bars), added here
(:func:`add_verbosity_arguments`) and applied here (:func:`configure_logging`): the library
logs through :mod:`logging` (:mod:`bimcap.logs`) and draws its progress bars through
:mod:`bimcap.progress`; only the commands' result lines are printed, on stdout.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from bimcap import __version__
from bimcap.errors import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OS_ERROR,
    BimcapError,
    clean_message,
    describe_os_error,
)

#: Sub-command modules, in the order ``bimcap --help`` lists them. Every one must import: a
#: missing module is a broken install, never a silently missing command.
COMMANDS: tuple[str, ...] = (
    "demo",
    "refine",
    "deviations",
    "evaluate",
    "experiment",
    "generate_building",
    "bim",
    "simulate",
    "drift",
    "import_conslam",
    "import_bag",
    "import_folder",
    "export_rerun",
    "solve_demo",
)

EXIT_SOLVE_FAILED = EXIT_FAILED

__all__ = ["EXIT_BAD_INPUT", "EXIT_OS_ERROR", "EXIT_SOLVE_FAILED", "add_out_argument",
           "add_overwrite_argument", "add_verbosity_arguments", "build_parser",
           "configure_logging", "main", "verbosity"]


class _DeprecatedAlias(argparse.Action):
    """A store_true flag kept under an old name: says which name to use instead."""

    def __init__(self, option_strings: Sequence[str], dest: str, new: str = "", **kw: Any) -> None:
        self.new = new
        super().__init__(option_strings, dest, nargs=0, default=False, **kw)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        print(f"bimcap: warning: {option_string} is deprecated, use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, True)


class _DeprecatedOption(argparse.Action):
    """An option kept under an old name, hidden from the help: stores its value where the new
    name does and says which name to use instead."""

    def __init__(self, option_strings: Sequence[str], dest: str, new: str = "", **kw: Any) -> None:
        self.new = new
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        print(f"bimcap: warning: {option_string} is deprecated, use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_deprecated_option(p: Any, old: str, new: str, dest: str, **kw: Any) -> None:
    """``old`` as a hidden alias of the option ``new`` (same ``dest``; ``kw``: its ``type``,
    ``choices``)."""
    p.add_argument(old, dest=dest, action=_DeprecatedOption, new=new, help=argparse.SUPPRESS,
                   default=argparse.SUPPRESS, **kw)


#: The building presets of bimcap.sim.building (generate-building, demo, experiment).
BUILDING_PRESETS = ("demo", "tiny", "tower")


def add_building_argument(p: argparse.ArgumentParser) -> None:
    """The one spelling of a building preset: ``--building`` (``args.building``); ``--preset``,
    its old spelling, kept hidden (``--preset`` is the drift command's drift preset)."""
    p.add_argument("--building", choices=BUILDING_PRESETS, default="demo",
                   help="building preset: the generator's starting parameters (default demo)")
    add_deprecated_option(p, "--preset", "--building", "building", choices=BUILDING_PRESETS)


def add_out_argument(p: argparse.ArgumentParser, help: str, required: bool = False,
                     **kw: Any) -> None:
    """The one spelling of a command's output, file or directory: ``-o/--out`` (``args.out``);
    ``--output``, the old spelling of some commands, kept as a hidden deprecated alias. ``kw``:
    ``type``, ``default``, ``metavar``."""
    group: Any = p.add_mutually_exclusive_group(required=True) if required else p
    group.add_argument("-o", "--out", dest="out", help=help, **kw)
    add_deprecated_option(group, "--output", "-o/--out", "out", type=kw.get("type"))


def add_overwrite_argument(p: argparse.ArgumentParser, what: str,
                           deprecated_force: bool = False) -> None:
    """The one flag that lets a command replace existing outputs: ``--overwrite`` (``--force``
    kept as a deprecated alias where a command had it)."""
    p.add_argument("--overwrite", action="store_true", help=f"replace {what}")
    if deprecated_force:
        p.add_argument("--force", dest="overwrite", action=_DeprecatedAlias, new="--overwrite",
                       help=argparse.SUPPRESS)  # hidden, like every retired spelling


def add_verbosity_arguments(p: argparse.ArgumentParser) -> None:
    """``-v/--verbose`` (repeatable) and ``-q/--quiet``, on every sub-command
    (:func:`build_parser` adds them; :func:`verbosity` reads them)."""
    g = p.add_argument_group("messages").add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", action="count", default=0,
                   help="more messages: DEBUG, with the module of each line, and the Ceres "
                        "solver's per-iteration progress")
    g.add_argument("-q", "--quiet", action="store_true",
                   help="warnings and errors only; no progress messages or bars")


def verbosity(args: argparse.Namespace) -> int:
    """-1 with ``-q``, else the number of ``-v`` (0 by default)."""
    return -1 if getattr(args, "quiet", False) else int(getattr(args, "verbose", 0) or 0)


def _check_outputs(args: argparse.Namespace) -> None:
    """The outputs a command declared: never one of its declared inputs (exit 2), and writable
    (the OSError the write would meet, exit 4)."""
    from bimcap.io.atomic import check_not_input
    from bimcap.io.outputs import check_output_dir, check_output_file

    inputs = [v for v in (getattr(args, n, None) for n in getattr(args, "input_paths", ()))
              if v is not None]
    for names, check in ((getattr(args, "output_dirs", ()), check_output_dir),
                         (getattr(args, "output_files", ()), check_output_file)):
        for name in names:
            value = getattr(args, name, None)
            if value is not None:
                check_not_input(value, inputs)
                check(value)


#: ``build_parser``'s default: register every sub-command in full.
ALL = "*"


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, but the ``examples:`` epilog keeps its lines as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith("examples:"):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def _finish_subparser(p: argparse.ArgumentParser, module: Any) -> None:
    """What every sub-command has, added in one place: ``-v``/``-q`` and the ``examples:``
    epilog of its module's ``EXAMPLES``."""
    add_verbosity_arguments(p)
    p.formatter_class = _HelpFormatter
    p.epilog = "examples:\n" + "\n".join(f"  {e}" for e in module.EXAMPLES)


def build_parser(command: str | None = ALL) -> argparse.ArgumentParser:
    """The ``bimcap`` parser.

    ``command`` is the sub-command to register in full (its options, which may import its stage);
    the others get their name and one-line help only, from their modules' ``NAME`` and ``HELP``
    (the modules import nothing heavy at module level). ``None`` registers none in full, as
    ``bimcap --help`` needs; :data:`ALL` (the default) registers all.
    """
    parser = argparse.ArgumentParser(
        prog="bimcap",
        description="Refine a drifting camera + LiDAR trajectory against the building's BIM (IFC).",
    )
    parser.add_argument("--version", action="version", version=f"bimcap {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"bimcap.cli.{name}")  # a missing one is an error
        if command == ALL or command == module.NAME:
            module.register(sub)
            _finish_subparser(sub.choices[module.NAME], module)
        else:
            sub.add_parser(module.NAME, help=module.HELP)
    return parser


class _StderrHandler(logging.Handler):
    """Writes to the ``sys.stderr`` of the moment (a test's capture, a redirect made after the
    command started), above any progress bar being drawn (:func:`bimcap.progress.write_line`)."""

    def emit(self, record: logging.LogRecord) -> None:
        from bimcap.progress import write_line

        try:
            write_line(self.format(record))
        except Exception:
            self.handleError(record)


class _Formatter(logging.Formatter):
    """``[bimcap] message`` at INFO, ``[bimcap] WARNING: message`` at the other levels; with
    ``names`` (``-v``), the module after the level: ``[bimcap] DEBUG bimcap.optimize.solve:``."""

    def __init__(self, names: bool) -> None:
        super().__init__()
        self.names = names

    def format(self, record: logging.LogRecord) -> str:
        head = "" if record.levelno == logging.INFO and not self.names else record.levelname
        if self.names:
            head = f"{head} {record.name}"
        text = record.getMessage()
        if record.exc_info:
            text += "\n" + self.formatException(record.exc_info)
        return f"[bimcap] {head}: {text}" if head else f"[bimcap] {text}"


#: ``-q`` / default / ``-v``: the level of the ``bimcap`` logger.
LEVELS = {-1: logging.WARNING, 0: logging.INFO, 1: logging.DEBUG}


@contextmanager
def configure_logging(verbosity: int) -> Iterator[None]:
    """The one place where bimcap's messages are set up, for the time of one command: the
    ``bimcap`` logger (every module's logger hangs under it) at WARNING (``verbosity`` -1,
    ``-q``), INFO (0, the default) or DEBUG (1 and more, ``-v``), written to stderr in a short
    format. Restored afterwards (``main`` runs in-process in the tests)."""
    logger = logging.getLogger("bimcap")
    handler = _StderrHandler()
    handler.setFormatter(_Formatter(names=verbosity > 0))
    previous = logger.level
    logger.setLevel(LEVELS[max(-1, min(1, verbosity))])
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(previous)


def _command_in(argv: Sequence[str]) -> str | None:
    """The sub-command named in ``argv``: its first argument that is not an option (the top-level
    options take no value)."""
    return next((a for a in argv if not a.startswith("-")), None)


def _warnings_as_lines(command: str) -> Any:
    """A ``warnings.showwarning`` that prints bimcap's own warnings (a damaged IFC, storey heights
    taken from the geometry ...) as one ``bimcap COMMAND: warning: ...`` line on stderr."""
    import warnings

    original = warnings.showwarning

    def show(message: Any, category: type[Warning], filename: str, lineno: int,
             file: Any = None, line: str | None = None) -> None:
        if category.__module__.startswith("bimcap."):
            print(f"bimcap {command}: warning: {clean_message(str(message))}", file=sys.stderr)
        else:
            original(message, category, filename, lineno, file, line)

    return show


def main(argv: Sequence[str] | None = None) -> int:
    import warnings

    parser = build_parser(_command_in(sys.argv[1:] if argv is None else argv))
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    previous = warnings.showwarning
    warnings.showwarning = _warnings_as_lines(args.command)
    try:
        with configure_logging(verbosity(args)):
            _check_outputs(args)
            return int(args.func(args) or 0)
    except BimcapError as exc:
        if args.debug:
            raise
        print(f"bimcap {args.command}: error: {clean_message(str(exc))}", file=sys.stderr)
        return getattr(exc, "exit_code", EXIT_BAD_INPUT)
    except OSError as exc:
        if args.debug:
            raise
        print(f"bimcap {args.command}: error: {describe_os_error(exc)}", file=sys.stderr)
        return EXIT_OS_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        warnings.showwarning = previous


if __name__ == "__main__":
    sys.exit(main())
