"""Every sub-command: --help works; missing or malformed inputs give one clear line, exit 2,
and no traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import bimcap
from bimcap.cli import COMMANDS, build_parser, main

#: Where the bimcap under test lives (the source tree with its built ``_core``, or an installed
#: package): the sub-processes import the same one.
SOURCES = Path(bimcap.__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {"PYTHONPATH": str(SOURCES), "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, "-m", "bimcap", *args], capture_output=True, text=True,
                          env=env, timeout=120)


def registered() -> list[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return list(sub.choices)  # type: ignore[arg-type]


def test_every_command_is_registered() -> None:
    names = registered()
    for module in COMMANDS:
        assert module.replace("_", "-") in names


@pytest.mark.parametrize("command", [c.replace("_", "-") for c in COMMANDS])
def test_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    if command not in registered():
        pytest.skip(f"{command} is not part of this build")
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    assert "usage: bimcap " + command in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["refine", "/nonexistent/seq", "-o", "/tmp/bimcap-out-x"], "/nonexistent/seq"),
        (["evaluate", "/nonexistent/a.tum", "/nonexistent/b.tum"], "/nonexistent/a.tum"),
        (["bim", "/nonexistent/model.ifc", "-o", "/tmp/bimcap-out-y"], "/nonexistent/model.ifc"),
        (["simulate", "/nonexistent/model.ifc", "-o", "/tmp/bimcap-out-z"],
         "/nonexistent/model.ifc"),
        (["drift", "/nonexistent/seq"], "/nonexistent/seq"),
    ],
)
def test_missing_inputs_exit_2_without_traceback(args: list[str], needle: str) -> None:
    if args[0] not in registered():
        pytest.skip(f"{args[0]} is not part of this build")
    proc = _run(*args)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert needle in proc.stderr
    assert len(proc.stderr.strip().splitlines()) <= 3


def test_malformed_config_exits_2(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text("method = 'nope'\n")
    proc = _run("refine", str(tmp_path), "-o", str(tmp_path / "o"), "--config", str(cfg))
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr


def test_no_command_prints_help(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 2
    assert "usage: bimcap" in capsys.readouterr().out


HEAVY = ("numpy", "scipy", "open3d", "cv2", "map_metrics", "ifcopenshell", "onnxruntime",
         "pycolmap", "matplotlib", "bimcap._core")


def test_top_level_help_imports_no_stage() -> None:
    # `bimcap --help` lists the commands from their modules' NAME and HELP: no numpy, no stage.
    code = ("import sys, runpy; sys.argv = ['bimcap', '--help']\n"
            "try:\n    runpy.run_module('bimcap', run_name='__main__')\n"
            "except SystemExit:\n    pass\n"
            f"print('HEAVY', sorted(m for m in {HEAVY!r} if m in sys.modules))")
    env = {"PYTHONPATH": str(SOURCES), "PATH": "/usr/bin:/bin"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert "HEAVY []" in out.stdout, out.stdout[-400:]
    for name in COMMANDS:
        assert name.replace("_", "-") in out.stdout


def test_a_command_registers_only_itself_in_full() -> None:
    parser = build_parser("drift")
    sub = next(a for a in parser._actions if a.dest == "command")
    drift = {o for a in sub.choices["drift"]._actions for o in a.option_strings}
    refine = {o for a in sub.choices["refine"]._actions for o in a.option_strings}
    assert "--preset" in drift and refine == {"-h", "--help"}
