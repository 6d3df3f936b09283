"""Problem files: the versioned binary format of ``cpp/bimcap/problem_file.h``, read and written
by the C++ core (the only implementation; ``bimcap_solve`` uses the same code).

Layout (little-endian, every offset a multiple of 64 so that arrays map without copying)::

    header 64 B   magic "BIMCAPPF", u32 version, u32 header_size=64, u32 num_arrays,
                  u32 entry_size=64, u64 file_size, 32 reserved bytes
    directory     num_arrays × 64 B: char[32] name, u32 dtype (1 f64, 2 i32, 3 u8), u32 ndim,
                  u64 rows, u64 cols, u64 offset
    data          each array C-contiguous at its offset

The ``options`` array (uint8) holds the solver options as ``key=value`` lines.
"""

from __future__ import annotations

from collections.abc import Callable
from os import PathLike
from pathlib import Path
from typing import Any, TypeVar

from numpy.typing import NDArray

from bimcap.io.atomic import atomic_write_bytes
from bimcap.optimize.errors import SolverInputError
from bimcap.optimize.options import SolverOptions
from bimcap.optimize.problem import Problem

_T = TypeVar("_T")


class ProblemFileError(SolverInputError):
    """A malformed problem file (names the file and the field)."""


def _core_call(call: Callable[[], _T], path: str | PathLike[str] | None) -> _T:
    """Runs a call into the C++ reader / writer; its errors become ProblemFileError."""
    try:
        return call()
    except (ValueError, TypeError) as exc:
        field = getattr(exc, "field", "") or None
        message = str(exc)
        for prefix in (f"{path}: " if path is not None else None, f"{field}: " if field else None):
            if prefix and message.startswith(prefix):
                message = message[len(prefix):]
        raise ProblemFileError(message, path, field) from None


def problem_to_bytes(problem: Problem, options: SolverOptions | None = None) -> bytes:
    """The file's bytes for ``problem`` and ``options`` (defaults when None)."""
    from bimcap.optimize.core import core

    _core = core()

    flat = (options if options is not None else SolverOptions()).to_flat()
    data: bytes = _core_call(lambda: _core.serialize_problem(problem.arrays(), flat), None)
    return data


def write_problem(
    path: str | PathLike[str], problem: Problem, options: SolverOptions | None = None
) -> None:
    """Write a problem file atomically."""
    atomic_write_bytes(path, problem_to_bytes(problem, options))


def read_problem(path: str | PathLike[str]) -> tuple[Problem, SolverOptions]:
    """Read and validate a problem file with the C++ reader.

    Raises
    ------
    ProblemFileError: naming the file and field, for every malformed input.
    """
    from bimcap.optimize.core import core

    _core = core()

    p = Path(path)
    if p.is_dir():
        raise ProblemFileError("is a directory, not a problem file", p)
    if not p.exists():
        raise ProblemFileError("no such file", p)
    if not p.is_file():
        raise ProblemFileError("not a regular file", p)
    arrays, flat = _core_call(lambda: _core.read_problem_file(str(p)), p)
    return Problem.from_arrays(arrays, p), SolverOptions.from_flat(flat)


def parse_problem_buffer(
    buf: bytes, path: str | PathLike[str] | None = None
) -> tuple[dict[str, NDArray[Any]], SolverOptions]:
    """Parse a problem file's bytes with the C++ reader into arrays and options."""
    from bimcap.optimize.core import core

    _core = core()

    arrays, flat = _core_call(lambda: _core.parse_problem_bytes(bytes(buf)), path)
    return dict(arrays), SolverOptions.from_flat(flat)
