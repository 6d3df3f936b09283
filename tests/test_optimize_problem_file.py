"""Problem files: numpy and C++ readers/writers agree; every corruption is a clear error."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from _solver_helpers import core
from bimcap.optimize import SolverInputError, SolverOptions, read_problem, write_problem
from bimcap.optimize.problem_file import ProblemFileError, parse_problem_buffer, problem_to_bytes
from bimcap.optimize.synthetic import make_synthetic_problem


@pytest.fixture(scope="module")
def synthetic():
    return make_synthetic_problem(num_frames=6, seed=5)


@pytest.fixture(scope="module")
def data(synthetic) -> bytes:
    return problem_to_bytes(synthetic.problem, SolverOptions.paper(max_iterations=9))


def _entry(data: bytes, name: str) -> int:
    n = struct.unpack_from("<I", data, 16)[0]
    for i in range(n):
        at = 64 + 64 * i
        if data[at : at + 32].split(b"\0")[0] == name.encode():
            return at
    raise KeyError(name)


def test_round_trip_python_and_cpp(tmp_path: Path, synthetic) -> None:
    path = tmp_path / "p.bimcap"
    opts = SolverOptions.paper(max_iterations=9)
    write_problem(path, synthetic.problem, opts)
    problem, options = read_problem(path)
    assert options == opts
    for name, arr in synthetic.problem.arrays().items():
        np.testing.assert_array_equal(getattr(problem, name), arr, err_msg=name)
    # The bytes parse to the same arrays (the C++ reader, from memory).
    arrays, _ = parse_problem_buffer(path.read_bytes())
    np.testing.assert_array_equal(arrays["poses"], synthetic.problem.poses)
    _core = core()
    c_arrays, c_options = _core.read_problem_file(str(path))
    for name, arr in synthetic.problem.arrays().items():
        np.testing.assert_array_equal(c_arrays[name], arr, err_msg=name)
    assert SolverOptions.from_flat(c_options) == opts
    # The numpy reader reads what the C++ writer writes.
    cpath = tmp_path / "c.bimcap"
    _core.write_problem_file(str(cpath), synthetic.problem.arrays(), opts.to_flat())
    problem2, options2 = read_problem(cpath)
    assert options2 == opts
    for name, arr in synthetic.problem.arrays().items():
        np.testing.assert_array_equal(getattr(problem2, name), arr, err_msg=name)


def _corruptions(data: bytes) -> list[tuple[str, bytes]]:
    out = []
    b = bytearray(data)
    b[0:1] = b"X"
    out.append(("magic", bytes(b)))
    b = bytearray(data)
    struct.pack_into("<I", b, 8, 99)
    out.append(("version", bytes(b)))
    out.append(("file_size", data[:-64]))
    out.append(("header", data[:40]))
    poses = _entry(data, "poses")
    b = bytearray(data)
    struct.pack_into("<Q", b, poses + 56, len(data) + 640)
    out.append(("past the end", bytes(b)))
    b = bytearray(data)
    struct.pack_into("<Q", b, poses + 56, struct.unpack_from("<Q", data, poses + 56)[0] + 8)
    out.append(("aligned", bytes(b)))
    b = bytearray(data)
    struct.pack_into("<Q", b, poses + 40, 2**62)
    out.append(("poses", bytes(b)))
    b = bytearray(data)
    struct.pack_into("<I", b, poses + 32, 2)
    out.append(("dtype", bytes(b)))
    off = struct.unpack_from("<Q", data, poses + 56)[0]
    b = bytearray(data)
    struct.pack_into("<d", b, off + 8, float("nan"))
    out.append(("not finite", bytes(b)))
    wall = struct.unpack_from("<Q", data, _entry(data, "wall_frame") + 56)[0]
    b = bytearray(data)
    struct.pack_into("<i", b, wall, 1000)
    out.append(("out of range", bytes(b)))
    b = bytearray(data)
    e = _entry(data, "wall_p_in_cam")
    struct.pack_into("<Q", b, e + 40, struct.unpack_from("<Q", data, e + 40)[0] - 1)
    out.append(("wall_p_in_cam", bytes(b)))
    return out


@pytest.mark.parametrize("index", range(11))
def test_each_corruption_is_rejected_by_both_readers(data: bytes, index: int) -> None:
    needle, bad = _corruptions(data)[index]
    with pytest.raises(ProblemFileError, match=needle) as info:
        parse_problem_buffer(bad)
    assert isinstance(info.value, SolverInputError)
    _core = core()
    with pytest.raises(ValueError, match=needle):
        _core.parse_problem_bytes(bad)


def test_random_mutations_never_crash(data: bytes) -> None:
    """Random byte edits go through both readers: parse or a clear ValueError, nothing else."""
    _core = core()
    rng = np.random.default_rng(0)
    rejected = 0
    for _ in range(300):
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 4))):
            kind = rng.integers(0, 3)
            if kind == 0:
                b[int(rng.integers(0, len(b)))] ^= 1 << int(rng.integers(0, 8))
            elif kind == 1:
                del b[int(rng.integers(1, len(b))) :]
            else:
                at = int(rng.integers(0, min(len(b), 64 * 30))) & ~7
                if at + 8 <= len(b):
                    struct.pack_into("<Q", b, at, int(rng.integers(0, 2**63)))
        py_ok = cpp_ok = True
        try:
            parse_problem_buffer(bytes(b))
        except SolverInputError:
            py_ok = False
        try:
            _core.parse_problem_bytes(bytes(b))
        except ValueError:
            cpp_ok = False
        assert py_ok == cpp_ok, "the numpy and C++ readers disagree"
        rejected += not py_ok
    assert rejected > 200


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ProblemFileError, match="no such file"):
        read_problem(tmp_path / "nope.bimcap")
