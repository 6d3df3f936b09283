"""Issue 12, items 1, 3 and 6 on the solver side: a non-finite cost is a failed solve (Python
``SolverError``, ``bimcap_solve`` exit 3, ``success: false``) naming the term and frame; a full
disk leaves no temporary file; a directory or a non-ASCII option key given as a problem file is a
clear ``InputError`` in both readers."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from _solver_helpers import bimcap_solve_binary, core
from bimcap.errors import InputError
from bimcap.optimize import (
    Problem,
    SolverError,
    SolverOptions,
    read_problem,
    solve,
    write_problem,
)
from bimcap.optimize.problem_file import ProblemFileError, problem_to_bytes
from bimcap.optimize.synthetic import make_synthetic_problem

EXIT_SOLVE_FAILED = 3
EXIT_OUTPUT = 4


@pytest.fixture(scope="module")
def arrays() -> dict[str, np.ndarray]:
    core()
    problem = make_synthetic_problem(num_frames=8, seed=3).problem
    return {k: v.copy() for k, v in problem.arrays().items()}


def _overflowing(arrays: dict[str, np.ndarray], case: str) -> tuple[Problem, SolverOptions, str]:
    """A problem whose initial cost overflows, the options, and the term the message must name."""
    a = {k: v.copy() for k, v in arrays.items()}
    opts = SolverOptions()
    term = "G (geometric)"
    if case == "pose at 1e300":
        a["poses"][3, 0] = 1e300
    elif case == "match_uv at 1e308":
        a["match_uv"][5, 0] = 1e308
    elif case == "focal length 1e-300":
        a["cameras"][0, 0] = 1e-300
    elif case == "wall.sigma 1e-300":
        opts.wall.sigma = 1e-300
        term = "W (wall)"
    return Problem.from_arrays(a), opts, term


CASES = ("pose at 1e300", "match_uv at 1e308", "focal length 1e-300", "wall.sigma 1e-300")


@pytest.mark.parametrize("case", CASES)
def test_non_finite_cost_raises_solver_error(arrays: dict[str, np.ndarray], case: str) -> None:
    problem, opts, term = _overflowing(arrays, case)
    with pytest.raises(SolverError) as info:
        solve(problem, opts)
    msg = str(info.value)
    assert "NON_FINITE_COST" in msg and "initial cost is not finite" in msg
    assert f"term {term}" in msg and "residual block" in msg and "frame" in msg
    res = solve(problem, opts, check=False)
    assert not res.summary.success
    assert res.summary.iterations == 0
    np.testing.assert_array_equal(res.poses[:, :3], problem.poses[:, :3])  # nothing moved


def test_pose_at_1e300_names_its_frame(arrays: dict[str, np.ndarray]) -> None:
    problem, opts, _ = _overflowing(arrays, "pose at 1e300")
    res = solve(problem, opts, check=False)
    inside = res.summary.message.split("(frame", 1)[1].split(")", 1)[0]
    assert "3" in inside.replace(",", " ").split()


@pytest.mark.parametrize("case", CASES)
def test_bimcap_solve_exits_3_with_success_false(arrays: dict[str, np.ndarray], case: str,
                                                 tmp_path: Path) -> None:
    exe = bimcap_solve_binary()
    problem, opts, term = _overflowing(arrays, case)
    path = tmp_path / "p.bcp"
    write_problem(path, problem, opts)
    out = tmp_path / "out"
    r = subprocess.run([str(exe), str(path), "-o", str(out)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == EXIT_SOLVE_FAILED, r.stderr
    assert f"term {term}" in r.stderr and "initial cost is not finite" in r.stderr
    assert "Error in evaluating the ResidualBlock" not in r.stderr  # no page of Ceres logging
    summary = json.loads((out / "summary.json").read_text())
    assert summary["success"] is False
    assert summary["termination"] == "NON_FINITE_COST"


def test_finite_problem_still_solves(arrays: dict[str, np.ndarray]) -> None:
    res = solve(Problem.from_arrays(arrays))
    assert res.summary.success and np.isfinite(res.summary.final_cost)


def _fsize_limit(limit: int):
    def apply() -> None:
        # Writing past RLIMIT_FSIZE fails with EFBIG once SIGXFSZ is ignored: the same code path
        # as ENOSPC (a failing write), without root, a tmpfs or a full disk.
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


def test_bimcap_solve_on_a_full_disk_leaves_no_tmp(arrays: dict[str, np.ndarray],
                                                   tmp_path: Path) -> None:
    exe = bimcap_solve_binary()
    path = tmp_path / "p.bcp"
    write_problem(path, Problem.from_arrays(arrays), SolverOptions(max_iterations=2))
    out = tmp_path / "out"
    out.mkdir()
    r = subprocess.run([str(exe), str(path), "-o", str(out)], capture_output=True, text=True,
                       timeout=60, preexec_fn=_fsize_limit(300))
    assert r.returncode == EXIT_OUTPUT, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "cannot write the outputs" in lines[0] and "refined.tum" in lines[0]
    assert "file too large" in lines[0]
    assert sorted(p.name for p in out.iterdir()) == []  # no refined.tum.tmp, no half set


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="/dev/full is not available")
def test_bimcap_solve_enospc_through_dev_full(arrays: dict[str, np.ndarray],
                                              tmp_path: Path) -> None:
    """A real ENOSPC without privileges: the temporary file bimcap_solve writes is a symlink to
    /dev/full, whose every write fails with ENOSPC."""
    exe = bimcap_solve_binary()
    path = tmp_path / "p.bcp"
    write_problem(path, Problem.from_arrays(arrays), SolverOptions(max_iterations=2))
    out = tmp_path / "out"
    out.mkdir()
    (out / "refined.tum.tmp").symlink_to("/dev/full")
    r = subprocess.run([str(exe), str(path), "-o", str(out)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == EXIT_OUTPUT, r.stderr
    assert "no space left on the device" in r.stderr
    assert not (out / "refined.tum").exists() and not (out / "summary.json").exists()
    assert not os.path.lexists(out / "refined.tum.tmp")


def test_bimcap_solve_output_is_a_file(arrays: dict[str, np.ndarray], tmp_path: Path) -> None:
    exe = bimcap_solve_binary()
    path = tmp_path / "p.bcp"
    write_problem(path, Problem.from_arrays(arrays), SolverOptions(max_iterations=2))
    target = tmp_path / "a_file"
    target.write_text("mine\n")
    r = subprocess.run([str(exe), str(path), "-o", str(target)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == EXIT_OUTPUT
    assert "not a directory" in r.stderr
    assert target.read_text() == "mine\n"


def test_directory_as_problem_file(tmp_path: Path) -> None:
    with pytest.raises(ProblemFileError, match="is a directory"):
        read_problem(tmp_path)
    _core = core()
    with pytest.raises(_core.InputError, match="is a directory"):
        _core.read_problem_file(str(tmp_path))
    r = subprocess.run([str(bimcap_solve_binary()), str(tmp_path), "-o", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "is a directory" in r.stderr


@pytest.mark.parametrize("raw", [b"\xff", b"\xc3\xa9"])
def test_non_ascii_option_key_is_an_input_error(arrays: dict[str, np.ndarray], raw: bytes,
                                                tmp_path: Path) -> None:
    data = bytearray(problem_to_bytes(Problem.from_arrays(arrays), SolverOptions()))
    at = bytes(data).index(b"association_change_tolerance=")  # the options text
    data[at + 1 : at + 1 + len(raw)] = raw
    path = tmp_path / "p.bcp"
    path.write_bytes(bytes(data))
    with pytest.raises(ProblemFileError) as info:
        read_problem(path)
    assert isinstance(info.value, InputError)
    assert "options" in str(info.value) and f"byte 0x{raw[0]:02x}" in str(info.value)
    _core = core()
    with pytest.raises(_core.InputError, match=f"byte 0x{raw[0]:02x}"):
        _core.read_problem_file(str(path))
    with pytest.raises(_core.InputError, match=f"byte 0x{raw[0]:02x}"):
        _core.parse_problem_bytes(bytes(data))
