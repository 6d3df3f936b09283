"""The command line reads alike everywhere (issue 17): every sub-command is listed with its
one-line description, has -v/-q and an examples epilog, and no two sub-commands spell the same
option differently; -q silences the INFO messages, -v shows DEBUG and Ceres' iterations."""

from __future__ import annotations

import argparse
import importlib
import logging
from collections import defaultdict
from pathlib import Path

import pytest

from bimcap.cli import COMMANDS, build_parser, main

#: The one spelling of each option that several sub-commands take, by its ``dest``.
CANONICAL: dict[str, tuple[str, ...]] = {
    "out": ("-o", "--out"),
    "ifc": ("--ifc",),
    "seed": ("--seed",),
    "workers": ("--workers",),
    "config": ("--config",),
    "overwrite": ("--overwrite",),
    "verbose": ("-v", "--verbose"),
    "quiet": ("-q", "--quiet"),
    "geometric_mode": ("--geometric",),
    "frames": ("--frames",),
    "terms": ("--terms",),
    "weighting": ("--weighting",),
    "as_built": ("--as-built",),
}

#: Old spellings that may live on only as hidden, deprecated aliases.
RETIRED = ("--output", "--force", "--geometric-mode")


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return dict(sub.choices)  # type: ignore[arg-type]


def _visible_options(p: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in p._actions
            if a.option_strings and a.help is not argparse.SUPPRESS and a.dest != "help"]


def test_top_level_help_lists_every_command_with_its_description(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps the descriptions
    for name in COMMANDS:
        module = importlib.import_module(f"bimcap.cli.{name}")
        assert module.HELP and "\n" not in module.HELP, name
        assert f"{module.NAME} {' '.join(module.HELP.split())}" in text, name


@pytest.mark.parametrize("name", COMMANDS)
def test_each_command_has_verbosity_flags_and_examples(
        name: str, capsys: pytest.CaptureFixture[str]) -> None:
    module = importlib.import_module(f"bimcap.cli.{name}")
    with pytest.raises(SystemExit) as info:
        main([module.NAME, "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert "-v, --verbose" in text and "-q, --quiet" in text
    examples = text.split("\nexamples:\n", 1)[1].splitlines()
    assert examples and all(e.startswith(f"  bimcap {module.NAME}") for e in examples if e.strip())
    for flag in RETIRED:  # hidden aliases never show
        assert f"{flag} " not in text and f"{flag}," not in text, (name, flag)


def test_no_two_commands_spell_the_same_option_differently() -> None:
    spellings: dict[str, set[tuple[str, ...]]] = defaultdict(set)
    dests: dict[str, set[str]] = defaultdict(set)
    for name, p in _subparsers().items():
        for a in _visible_options(p):
            assert a.help, f"{name} {a.option_strings}: no help"
            strings = tuple(a.option_strings)
            spellings[a.dest].add(strings)
            for s in strings:
                dests[s].add(a.dest)
                assert s not in RETIRED, f"{name}: {s} is a retired spelling"
            if a.dest in CANONICAL:
                assert strings == CANONICAL[a.dest], (name, a.dest, strings)
    assert {d: s for d, s in spellings.items() if len(s) > 1} == {}
    assert {s: d for s, d in dests.items() if len(d) > 1} == {}
    for dest, strings in CANONICAL.items():
        assert spellings[dest] == {strings}, dest  # the table names options that exist


def test_retired_spellings_still_work_with_a_warning(capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser()
    args = parser.parse_args(["bim", "house.ifc", "--output", "bim/"])
    assert args.out == Path("bim/")
    args = parser.parse_args(["solve-demo", "--geometric-mode", "landmark"])
    assert args.geometric_mode == "landmark"
    err = capsys.readouterr().err
    assert "--output is deprecated, use -o/--out" in err
    assert "--geometric-mode is deprecated, use --geometric" in err
    with pytest.raises(SystemExit):
        parser.parse_args(["bim", "house.ifc"])  # -o stays required
    # a building preset is --building; --preset is the drift command's alone
    for cmd in ("generate-building", "demo", "experiment"):
        out = ["-o", "x.ifc" if cmd == "generate-building" else "d/"]
        assert parser.parse_args([cmd, *out, "--preset", "tiny"]).building == "tiny"
    assert "--preset is deprecated, use --building" in capsys.readouterr().err


def _stderr_lines(capsys: pytest.CaptureFixture[str]) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[bimcap]")]


def test_quiet_silences_info_and_verbose_shows_debug(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    def run(*flags: str) -> list[str]:
        out = tmp_path / f"house{len(flags)}{''.join(flags)}.ifc"
        assert main(["generate-building", "-o", str(out), "--building", "tiny", *flags]) == 0
        return _stderr_lines(capsys)

    default = run()
    assert any(ln.startswith("[bimcap] wrote the design building") for ln in default)
    assert not any("DEBUG" in ln for ln in default)
    assert run("-q") == []
    verbose = run("-v")
    assert any(ln.startswith("[bimcap] INFO bimcap.sim.building: wrote") for ln in verbose)
    assert any(ln.startswith("[bimcap] DEBUG bimcap.sim.building:") for ln in verbose)
    assert any("DEBUG" in ln for ln in run("-vv"))  # -v is repeatable
    # main leaves the logging as it found it (it runs in-process here)
    assert logging.getLogger("bimcap").handlers == []
    assert logging.getLogger("bimcap").level == logging.NOTSET


def test_verbose_shows_the_ceres_iterations_on_stderr(capfd: pytest.CaptureFixture[str]) -> None:
    assert main(["solve-demo", "--frames", "10", "-v"]) == 0
    out, err = capfd.readouterr()
    assert "iter      cost" in err and "Solver Summary" in err  # Ceres' own progress and report
    assert "iter      cost" not in out and "pose error" in out  # stdout keeps the results
    assert main(["solve-demo", "--frames", "10"]) == 0
    out, err = capfd.readouterr()
    assert "iter      cost" not in err + out
