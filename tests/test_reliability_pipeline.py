"""Issue 12 on ``bimcap refine`` and ``bimcap demo``: one validation pass before any expensive
stage (item 5), an unusable IFC named before the front end (item 2), outputs written as one set
with ``result.json`` hashes and user files never replaced (item 4), OS errors as one line and
exit 4 (item 3), LiDAR scans with NaN or no points named by file and frame (item 6).

Every refine here runs on an 8-frame sequence of the tiny building at 1/8 ConSLAM resolution.
"""

from __future__ import annotations

import errno
import functools
import json
import os
import resource
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bimcap
from _ifc_edits import cut, length_unit_prefix
from bimcap.cli import main

pytest.importorskip("bimcap._core", reason="the C++ core is not built")

SOURCES = Path(bimcap.__file__).resolve().parents[1]
RESULT_NAME = "result.json"
STAGING_PREFIX = ".bimcap-staging-"


def verify_outputs(out: Path) -> list[str]:
    """The test's own check of a run's set: result.json lists files whose SHA-256 match."""
    import hashlib

    doc = json.loads((out / RESULT_NAME).read_text())
    bad = []
    for rel, info in doc["outputs"].items():
        p = out / rel
        if not p.is_file() or hashlib.sha256(p.read_bytes()).hexdigest() != info["sha256"]:
            bad.append(rel)
    return bad
FAST = ["-q", "--workers", "1", "--no-coarse", "--terms", "G+F+W"]


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The tiny building (design + as-built) and an 8-frame drifted sequence in it."""
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.demo import DemoOptions, make_sequence, make_world

    out = tmp_path_factory.mktemp("world")
    opts = DemoOptions(preset="tiny", frames=8, scale=0.125, fps=2.0,
                       config=RefineConfig(workers=1))
    design, built = make_world(out, opts, quiet=True)
    seq = make_sequence(out, design, built, opts, quiet=True)
    return {"root": out, "design": design, "seq": seq}


@pytest.fixture(scope="module")
def first_run(world: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One complete refine with the report, into a fresh directory."""
    out = tmp_path_factory.mktemp("runs") / "first"
    assert main(["refine", str(world["seq"]), "-o", str(out), *FAST]) == 0
    return out


def _err_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err  # one clear line, no traceback
    assert "Traceback" not in err[0]
    return err[0]


def _run_files(out: Path) -> set[str]:
    """Every file under ``out`` except the caches and result.json."""
    return {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()
            and p.relative_to(out).parts[0] not in ("bim", "cache") and p.name != RESULT_NAME}


# ----------------------------------------------------------------------------- item 5: settings
def _bad_settings(world: dict[str, Path], tmp: Path) -> dict[str, tuple[list[str], list[str]]]:
    seq = world["seq"]
    gt = (seq / "poses" / "gt.tum").read_text().splitlines()
    short = tmp / "short_gt.tum"
    short.write_text("\n".join(gt[:5]) + "\n")
    shifted = tmp / "shifted_init.tum"
    lines = [ln.split() for ln in (seq / "poses" / "init.tum").read_text().splitlines()
             if ln.strip() and not ln.startswith("#")]
    shifted.write_text("".join(" ".join([str(float(r[0]) + 0.5), *r[1:]]) + "\n" for r in lines))
    toml = tmp / "bad.toml"
    toml.write_text("[solver]\nmax_iterations = -1\n")
    return {
        "unknown term": (["--terms", "G+X"], ["terms", "unknown term", "X"]),
        "short gt": (["--gt", str(short)], [str(short), "poses", "4 ground-truth poses for 8"]),
        "init timestamps": (["--init", str(shifted)], [str(shifted), "timestamps"]),
        "missing onnx model": (["--completion", "onnx", "--completion-model",
                                str(tmp / "none.onnx")], ["no such model file", "none.onnx"]),
        "bad solver option": (["--config", str(toml)], ["max_iterations"]),
        "negative distance": (["--max-match-distance", "-1"], ["max_match_distance"]),
        "zero workers": (["--workers", "0"], ["workers"]),
        "unreachable dask scheduler": (["--dask-scheduler", _nothing_listens()],
                                       ["dask.scheduler", _nothing_listens()]),
    }


@functools.cache
def _nothing_listens() -> str:
    """``tcp://127.0.0.1:PORT`` of a port that nothing listens on (probed once)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


CASES = ("unknown term", "short gt", "init timestamps", "missing onnx model", "bad solver option",
         "negative distance", "zero workers", "unreachable dask scheduler")


@pytest.mark.parametrize("case", CASES)
def test_settings_and_inputs_are_checked_before_any_work(world: dict[str, Path], tmp_path: Path,
                                                          case: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    args, words = _bad_settings(world, tmp_path)[case]
    out = tmp_path / "out"
    rc = main(["refine", str(world["seq"]), "-o", str(out), "-q", "--workers", "1", *args])
    assert rc == 2
    line = _err_line(capsys)
    for w in words:
        assert w in line, (w, line)
    assert not out.exists()  # no front end ran (no cache), no empty -o left behind


# ----------------------------------------------------------------------------- item 2: the IFC
@pytest.mark.parametrize(("edit", "words"), [(length_unit_prefix, ["LENGTHUNIT", "MILLIMETRE"]),
                                        (lambda t: cut(t, 0.6), ["damaged IFC file"])])
def test_unusable_ifc_fails_before_the_front_end(world: dict[str, Path], tmp_path: Path,
                                                 edit, words: list[str],
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.ifc"
    bad.write_text(edit(world["design"].read_text()))
    out = tmp_path / "out"
    rc = main(["refine", str(world["seq"]), "-o", str(out), "--ifc", str(bad), *FAST])
    assert rc == 2
    line = _err_line(capsys)
    assert str(bad) in line
    for w in words:
        assert w in line
    assert not out.exists()  # the front end never ran; no empty -o


# ----------------------------------------------------------------------------- item 4: outputs
def test_result_json_lists_every_file_with_its_hash(first_run: Path) -> None:
    doc = json.loads((first_run / RESULT_NAME).read_text())
    assert set(doc["outputs"]) == _run_files(first_run)
    assert {"refined.tum", "summary.json", "map_before.ply", "map_after.ply",
            "map_refined.ply", "report.html"} <= set(doc["outputs"])
    assert any(k.startswith("figures/") for k in doc["outputs"])
    assert verify_outputs(first_run) == []
    assert not list(first_run.glob(f"{STAGING_PREFIX}*"))


def test_a_users_file_is_never_replaced(world: dict[str, Path], tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    mine = out / "refined.tum"
    mine.write_text("# my own trajectory\n0 0 0 0 0 0 0 1\n")
    rc = main(["refine", str(world["seq"]), "-o", str(out), *FAST])
    assert rc == 2
    line = _err_line(capsys)
    assert str(mine) in line and "not written by bimcap" in line and "--overwrite" in line
    assert mine.read_text().startswith("# my own trajectory")
    assert sorted(p.name for p in out.iterdir()) == ["refined.tum"]  # refused before any work
    assert main(["refine", str(world["seq"]), "-o", str(out), *FAST, "--overwrite"]) == 0
    assert not mine.read_text().startswith("# my own trajectory")
    assert verify_outputs(out) == []


def test_a_file_edited_after_the_run_is_not_replaced(first_run: Path, world: dict[str, Path],
                                                     tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "edited"
    shutil.copytree(first_run, out)
    with open(out / "summary.json", "a") as fh:
        fh.write("\n")
    rc = main(["refine", str(world["seq"]), "-o", str(out), *FAST])
    assert rc == 2
    assert "changed after bimcap wrote it" in _err_line(capsys)


def test_a_rerun_replaces_the_whole_set(first_run: Path, world: dict[str, Path],
                                        tmp_path: Path) -> None:
    """A rerun without the report removes the earlier run's report and figures: the directory
    holds exactly the files of the last run, all listed in result.json."""
    out = tmp_path / "rerun"
    shutil.copytree(first_run, out)
    assert main(["refine", str(world["seq"]), "-o", str(out), *FAST, "--no-report"]) == 0
    assert not (out / "report.html").exists() and not (out / "figures").exists()
    doc = json.loads((out / RESULT_NAME).read_text())
    assert set(doc["outputs"]) == _run_files(out)
    assert verify_outputs(out) == []


def test_an_interrupted_rerun_leaves_the_earlier_set_whole(first_run: Path,
                                                           world: dict[str, Path], tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Interrupted while writing (here: in the report, after the trajectory, summary and maps
    were written): the earlier set and its result.json are untouched (before: the new
    refined.tum / summary.json / maps sat beside the old result.json and report)."""
    from bimcap.pipeline import refine as refine_module
    from bimcap.pipeline import report as report_module
    from bimcap.pipeline.config import Method, RefineConfig

    out = tmp_path / "interrupted"
    shutil.copytree(first_run, out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()
              and p.relative_to(out).parts[0] not in ("bim", "cache")}

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(report_module, "write_refine_report", interrupt)
    cfg = RefineConfig(method=Method.FACAP, workers=1)
    with pytest.raises(KeyboardInterrupt):
        refine_module.refine(world["seq"], out, cfg, quiet=True)
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()
             and p.relative_to(out).parts[0] not in ("bim", "cache")}
    assert after == before
    assert verify_outputs(out) == []
    assert not list(out.glob(f"{STAGING_PREFIX}*"))


@pytest.mark.slow
def test_demo_writes_a_consistent_set_and_keeps_users_files(tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    args = ["demo", "-o", str(tmp_path / "demo"), "--building", "tiny", "--frames", "8",
            "--scale", "0.125", "--no-facap", "-q", "--workers", "1"]
    assert main(args) == 0
    run = tmp_path / "demo" / "refine"
    doc = json.loads((run / RESULT_NAME).read_text())
    assert {"refined.tum", "report.html"} <= set(doc["outputs"])
    assert set(doc["outputs"]) == _run_files(run)
    assert verify_outputs(run) == []
    capsys.readouterr()
    (run / "refined.tum").write_text("# edited by hand\n")
    assert main(args) == 2
    assert "changed after bimcap wrote it" in _err_line(capsys)
    assert main([*args, "--overwrite"]) == 0
    assert verify_outputs(run) == []


def test_demo_settings_are_checked_first(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "--building", "tiny", "--terms", "G+X", "-q"]) == 2
    assert "unknown term" in _err_line(capsys)
    assert not out.exists()  # no building generated, nothing simulated


# ----------------------------------------------------------------------------- item 3: OS errors
def test_output_path_is_an_existing_file(world: dict[str, Path], tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "a_file"
    target.write_text("mine\n")
    seq = world["seq"]
    for args in (["refine", str(seq), "-o", str(target), *FAST],
                 ["bim", str(world["design"]), "-o", str(target)],
                 ["demo", "-o", str(target), "--building", "tiny", "-q"],
                 ["simulate", str(world["design"]), "-o", str(target), "--frames", "2"],
                 ["evaluate", str(seq / "poses/init.tum"), str(seq / "poses/gt.tum"),
                  "-o", str(target / "metrics.json")]):
        assert main(args) == 4, args
        line = _err_line(capsys)
        assert f"{target}: is a file, not a directory" in line, line
        assert target.read_text() == "mine\n"


@pytest.mark.parametrize(("code", "words"), [(errno.ENOSPC, "no space left on the device"),
                                        (errno.EROFS, "read-only file system"),
                                        (errno.EACCES, "permission denied")])
def test_os_errors_while_writing_are_one_line_and_exit_4(world: dict[str, Path], tmp_path: Path,
                                                         code: int, words: str,
                                                         monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The OSError a full disk / read-only file system / denied directory raises at the write,
    injected where bimcap's atomic writer flushes (os.fsync): every command maps it alike, and
    no temporary file stays behind."""
    import bimcap.io.atomic as atomic

    def refuse(fd: int) -> None:
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(atomic.os, "fsync", refuse)
    seq = world["seq"]
    for args, out in (
        (["evaluate", str(seq / "poses/init.tum"), str(seq / "poses/gt.tum"), "-o",
          str(tmp_path / "m" / "metrics.json")], tmp_path / "m"),
        (["bim", str(world["design"]), "-o", str(tmp_path / "b")], tmp_path / "b"),
        (["refine", str(seq), "-o", str(tmp_path / "r"), *FAST], tmp_path / "r"),
        (["generate-building", "-o", str(tmp_path / "g" / "x.ifc"), "--building", "tiny"],
         tmp_path / "g"),
    ):
        assert main(args) == 4, args
        line = _err_line(capsys)
        assert line.startswith(f"bimcap {args[0]}: error: ") and words in line, line
        leftovers = list(out.rglob("*.tmp")) if out.exists() else []
        assert leftovers == [], leftovers
    monkeypatch.undo()


def _as_unprivileged() -> list[str] | None:
    """A command prefix that runs without the power to ignore file permissions: nothing for a
    normal user; for root, setpriv dropping CAP_DAC_OVERRIDE / CAP_DAC_READ_SEARCH (no other
    privilege needed); None when neither works."""
    if os.geteuid() != 0:
        return []
    exe = shutil.which("setpriv")
    if exe is None:
        return None
    prefix = [exe, "--inh-caps=-dac_override,-dac_read_search",
              "--bounding-set=-dac_override,-dac_read_search"]
    probe = subprocess.run([*prefix, "true"], capture_output=True)
    return prefix if probe.returncode == 0 else None


def test_read_only_directory_for_real(world: dict[str, Path], tmp_path: Path) -> None:
    prefix = _as_unprivileged()
    if prefix is None:
        pytest.skip("running as root without setpriv: cannot drop the permission override")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    seq = world["seq"]
    env = {"PYTHONPATH": str(SOURCES), "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
           "PYTHONDONTWRITEBYTECODE": "1"}
    try:
        for args in (["refine", str(seq), "-o", str(ro / "out"), *FAST],
                     ["bim", str(world["design"]), "-o", str(ro)],
                     ["evaluate", str(seq / "poses/init.tum"), str(seq / "poses/gt.tum"),
                      "-o", str(ro / "metrics.json")]):
            r = subprocess.run([*prefix, sys.executable, "-m", "bimcap", *args],
                               capture_output=True, text=True, timeout=120, env=env)
            assert r.returncode == 4, (args, r.stderr)
            lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
            assert len(lines) == 1 and f"{ro}: permission denied" in lines[0], r.stderr
        # bimcap_solve: the same exit status and words.
        from _solver_helpers import bimcap_solve_binary
        from bimcap.optimize import SolverOptions, write_problem
        from bimcap.optimize.synthetic import make_synthetic_problem

        problem = tmp_path / "p.bcp"
        write_problem(problem, make_synthetic_problem(num_frames=4, seed=1).problem,
                      SolverOptions(max_iterations=2))
        r = subprocess.run([*prefix, str(bimcap_solve_binary()), str(problem), "-o", str(ro)],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 4 and "permission denied" in r.stderr, r.stderr
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


def _file_size_limit(limit: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


def test_a_write_failing_mid_run_leaves_no_partial_set(world: dict[str, Path],
                                                       tmp_path: Path) -> None:
    """A real failing write without privileges (RLIMIT_FSIZE, the same path as a full disk):
    refine stops with one line and exit 4, leaves no staging directory and no result.json."""
    out = tmp_path / "out"
    env = {"PYTHONPATH": str(SOURCES), "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
           "PYTHONDONTWRITEBYTECODE": "1",
           "BIMCAP_CACHE_DIR": os.environ.get("BIMCAP_CACHE_DIR", "off")}  # never ~/.cache
    r = subprocess.run([sys.executable, "-m", "bimcap", "refine", str(world["seq"]), "-o",
                        str(out), *FAST], capture_output=True, text=True, timeout=300, env=env,
                       preexec_fn=_file_size_limit(64 * 1024))
    assert r.returncode == 4, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith("[bimcap]")]
    assert len(lines) == 1 and "file too large" in lines[0], r.stderr
    if out.exists():
        assert not (out / RESULT_NAME).exists()
        assert not list(out.glob(f"{STAGING_PREFIX}*"))
        assert not list(out.rglob("*.tmp"))


# ----------------------------------------------------------------------------- item 6: LiDAR
def _sequence_copy(world: dict[str, Path], tmp: Path) -> Path:
    seq = tmp / "seq"
    shutil.copytree(world["seq"], seq)
    design = world["design"]
    manifest = json.loads((seq / "manifest.json").read_text())
    manifest["ifc"] = str(design)
    (seq / "manifest.json").write_text(json.dumps(manifest))
    return seq


@pytest.mark.parametrize("kind", ["all NaN", "empty"])
def test_bad_lidar_scan_names_file_frame_and_option(world: dict[str, Path], tmp_path: Path,
                                                    kind: str,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    seq = _sequence_copy(world, tmp_path)
    manifest = json.loads((seq / "manifest.json").read_text())
    scan = seq / manifest["frames"][2]["lidar"]
    if kind == "all NaN":
        n = scan.stat().st_size // 16
        scan.write_bytes(np.full((n, 4), np.nan, np.float32).tobytes())
    else:
        scan.write_bytes(b"")
    out = tmp_path / "out"
    rc = main(["refine", str(seq), "-o", str(out), *FAST])
    assert rc == 2
    line = _err_line(capsys)
    assert str(scan) in line and "frames[2].lidar" in line and "--lidar-nan drop" in line
    assert "NanPolicy" not in line
    assert main(["refine", str(seq), "-o", str(out), *FAST, "--lidar-nan", "drop"]) == 0
