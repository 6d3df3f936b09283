"""The optional dependencies (pyproject extras ``dask``, ``ros``, ``rerun``; and ONNX Runtime, a
core dependency that an install can still lack): bimcap imports and runs without them, and a
command that needs one says what to install, in one line, exit 2.
Each case runs in a subprocess whose imports of those packages fail, as on an install without
the extra."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import bimcap

SOURCES = Path(bimcap.__file__).resolve().parents[1]
PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"

#: Import names of the optional packages, and the extra of each (None: a core dependency).
OPTIONAL = {"distributed": "dask", "dask": "dask", "rosbags": "ros", "rerun": "rerun",
            "onnxruntime": None}

_BLOCK = f"""
import importlib.abc, sys
class _Missing(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {sorted(OPTIONAL)!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None
sys.meta_path.insert(0, _Missing())
"""


def _run(code: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {"PYTHONPATH": str(SOURCES), "PATH": "/usr/bin:/bin", "BIMCAP_CACHE_DIR": "off"}
    return subprocess.run([sys.executable, "-c", _BLOCK + code], capture_output=True, text=True,
                          env=env, timeout=300, cwd=tmp_path)


def test_the_extras_are_declared_and_the_test_extra_pulls_them() -> None:
    meta = tomllib.loads(PYPROJECT.read_text())["project"]
    extras = meta["optional-dependencies"]
    names = {extra: {r.split(">")[0].split("[")[0] for r in reqs} for extra, reqs in extras.items()}
    assert names["dask"] == {"dask"} and names["ros"] == {"rosbags"}
    assert names["rerun"] == {"rerun-sdk"}
    core = {r.split(">")[0].split("[")[0] for r in meta["dependencies"]}
    assert "onnxruntime" in core  # the product's ONNX Runtime path is not optional
    for extra in ("dask", "ros", "rerun"):
        assert names[extra] <= names["test"] and names[extra] <= names["all"]
        assert not names[extra] & core


def test_bimcap_runs_without_the_optional_packages(tmp_path: Path) -> None:
    code = """
import importlib
from bimcap.cli import COMMANDS, build_parser, main
build_parser()  # every sub-command registered in full
for m in ("bimcap.pipeline.refine", "bimcap.pipeline.demo", "bimcap.frontend.runner",
          "bimcap.frontend.executor", "bimcap.dataset.conslam", "bimcap.fusion.onnx_completion",
          "bimcap.segmentation.onnx_seg", "bimcap.pipeline.rerun_export"):
    importlib.import_module(m)
assert main(["solve-demo", "--frames", "8", "-q"]) == 0
assert not [m for m in sys.modules if m.split(".")[0] in ("dask", "distributed", "rosbags",
                                                        "rerun", "onnxruntime")]
print("OK")
"""
    r = _run(code, tmp_path)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-2000:]


@pytest.mark.parametrize(("args", "extra"), [
    (["import-conslam", "missing.bag", "-o", "seq"], "ros"),
    (["import-bag", "x.bag", "-o", "seq", "--image-topic", "/i", "--cloud-topic", "/c",
      "--calib", "c.yaml"], "ros"),
    (["refine", "no_sequence", "-o", "out", "--dask"], "dask"),  # checked before the sequence
    (["refine", "no_sequence", "-o", "out", "--rerun"], "rerun"),
    (["demo", "-o", "demo_out", "--rerun"], "rerun"),  # before the world is generated
    (["export-rerun", "no_run", "-o", "run.rrd"], "rerun"),  # before the run is read
])
def test_a_command_without_its_extra_names_it(args: list[str], extra: str,
                                              tmp_path: Path) -> None:
    r = _run(f"from bimcap.cli import main\nsys.exit(main({args!r}))", tmp_path)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert lines[0].startswith(f"bimcap {args[0]}: error: ")
    assert f"install bimcap[{extra}]: pip install 'bimcap[{extra}]'" in lines[0], lines[0]


def test_the_error_is_a_bimcap_input_error_with_exit_2(tmp_path: Path) -> None:
    code = """
from bimcap.errors import EXIT_BAD_INPUT, BimcapError, MissingDependencyError
from bimcap.frontend.executor import require_distributed
from bimcap.fusion.onnx_completion import load_session
from bimcap.pipeline.rerun_export import require_rerun
for call, how in ((require_distributed, "pip install 'bimcap[dask]'"),
                  (require_rerun, "pip install 'bimcap[rerun]'"),
                  (lambda: load_session("m.onnx"), "pip install onnxruntime")):
    try:
        call()
    except MissingDependencyError as exc:
        assert isinstance(exc, BimcapError) and isinstance(exc, ImportError)
        assert getattr(exc, "exit_code", EXIT_BAD_INPUT) == 2
        assert how in str(exc), str(exc)
    else:
        raise AssertionError(extra)
print("OK")
"""
    r = _run(code, tmp_path)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-2000:]
