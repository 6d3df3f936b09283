"""Problem files from numpy: the same versioned binary format as ``cpp/bimcap/problem_file.h``.

Layout (little-endian, every offset a multiple of 64 so that arrays map without copying)::

    header 64 B   magic "BIMCAPPF", u32 version, u32 header_size=64, u32 num_arrays,
                  u32 entry_size=64, u64 file_size, 32 reserved bytes
    directory     num_arrays × 64 B: char[32] name, u32 dtype (1 f64, 2 i32, 3 u8), u32 ndim,
                  u64 rows, u64 cols, u64 offset
    data          each array C-contiguous at its offset

The ``options`` array (uint8) holds the solver options as ``key=value`` lines.
"""

from __future__ import annotations

import os
import struct
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.io.atomic import atomic_write_bytes
from bimcap.optimize.errors import SolverInputError
from bimcap.optimize.options import SolverOptions
from bimcap.optimize.problem import FIELDS, Problem, validate_arrays

MAGIC = b"BIMCAPPF"
VERSION = 1
HEADER_SIZE = 64
ENTRY_SIZE = 64
ALIGNMENT = 64
MAX_ARRAYS = 256
_HEADER = struct.Struct("<8sIIIIQ32x")
_ENTRY = struct.Struct("<32sIIQQQ")
_DTYPES: dict[int, np.dtype[Any]] = {
    1: np.dtype("<f8"),
    2: np.dtype("<i4"),
    3: np.dtype("u1"),
}
_CODES = {np.dtype(np.float64): 1, np.dtype(np.int32): 2, np.dtype(np.uint8): 3}


class ProblemFileError(SolverInputError):
    """A malformed problem file (names the file and the field)."""


def _options_text(raw: bytes, fail: Any) -> str:
    """The options text; any byte other than printable ASCII and the line feed is an error naming
    its line and column, as in the C++ reader."""
    line, column = 1, 0
    for c in raw:
        column += 1
        if c == 0x0A:
            line, column = line + 1, 0
        elif c < 0x20 or c > 0x7E:
            fail("options", f"line {line}, column {column}: byte 0x{c:02x} is not printable ASCII "
                            "(options are key=value text)")
    return raw.decode("ascii")


def _align(n: int) -> int:
    return (n + ALIGNMENT - 1) // ALIGNMENT * ALIGNMENT


def problem_to_bytes(problem: Problem, options: SolverOptions | None = None) -> bytes:
    """The file's bytes for ``problem`` and ``options`` (defaults when None)."""
    opts = options if options is not None else SolverOptions()
    text = "".join(f"{k}={v}\n" for k, v in sorted(opts.to_flat().items())).encode("ascii")
    arrays: list[tuple[str, NDArray[Any]]] = list(problem.arrays().items())
    arrays.append(("options", np.frombuffer(text, dtype=np.uint8)))
    offset = _align(HEADER_SIZE + len(arrays) * ENTRY_SIZE)
    entries, placed = [], []
    for name, arr in arrays:
        rows = arr.shape[0]
        cols = arr.shape[1] if arr.ndim == 2 else 1
        entries.append(_ENTRY.pack(name.encode("ascii"), _CODES[arr.dtype], arr.ndim, rows, cols, offset))
        placed.append((offset, arr))
        offset = _align(offset + arr.nbytes)
    buf = bytearray(offset)
    buf[:HEADER_SIZE] = _HEADER.pack(MAGIC, VERSION, HEADER_SIZE, len(arrays), ENTRY_SIZE, offset)
    for i, e in enumerate(entries):
        buf[HEADER_SIZE + i * ENTRY_SIZE : HEADER_SIZE + (i + 1) * ENTRY_SIZE] = e
    for off, arr in placed:
        data = np.ascontiguousarray(arr).astype(arr.dtype.newbyteorder("<"), copy=False).tobytes()
        buf[off : off + len(data)] = data
    return bytes(buf)


def write_problem(
    path: str | PathLike[str], problem: Problem, options: SolverOptions | None = None
) -> None:
    """Write a problem file atomically."""
    atomic_write_bytes(path, problem_to_bytes(problem, options))


def read_problem(
    path: str | PathLike[str], *, mmap: bool = True
) -> tuple[Problem, SolverOptions]:
    """Read and validate a problem file.

    With ``mmap`` the arrays are read-only views of the mapped file (no copy) until
    :class:`Problem` normalises them (it keeps float64 / int32 C-contiguous arrays as they are).

    Raises
    ------
    ProblemFileError: naming the file and field, for every malformed input.
    """
    p = Path(path)
    if p.is_dir():
        raise ProblemFileError("is a directory, not a problem file", p)
    if not p.exists():
        raise ProblemFileError("no such file", p)
    if not p.is_file():
        raise ProblemFileError("not a regular file", p)
    size = os.path.getsize(p)
    if size < HEADER_SIZE:
        raise ProblemFileError(f"file too short for a header ({size} bytes)", p, "header")
    buf: Any = np.memmap(p, dtype=np.uint8, mode="r") if mmap else np.fromfile(p, dtype=np.uint8)
    arrays, options = parse_problem_buffer(buf, p)
    return Problem.from_arrays(arrays, p), options


def parse_problem_buffer(
    buf: NDArray[np.uint8] | bytes, path: str | PathLike[str] | None = None
) -> tuple[dict[str, NDArray[Any]], SolverOptions]:
    """Parse the bytes of a problem file into arrays (views of ``buf``) and options."""
    data = np.frombuffer(buf, dtype=np.uint8) if isinstance(buf, (bytes, bytearray)) else buf
    size = len(data)

    def fail(field: str, message: str) -> None:
        raise ProblemFileError(message, path, field)

    if size < HEADER_SIZE:
        fail("header", f"file too short for a header ({size} bytes, need 64)")
    magic, version, header_size, num_arrays, entry_size, file_size = _HEADER.unpack(
        bytes(data[:HEADER_SIZE])
    )
    if magic != MAGIC:
        fail("header.magic", "not a bimcap problem file (bad magic)")
    if version != VERSION:
        fail("header.version", f"unsupported version {version} (this build reads version {VERSION})")
    if header_size != HEADER_SIZE:
        fail("header.header_size", "must be 64")
    if entry_size != ENTRY_SIZE:
        fail("header.entry_size", "must be 64")
    if num_arrays > MAX_ARRAYS:
        fail("header.num_arrays", f"{num_arrays} arrays (at most {MAX_ARRAYS})")
    if file_size != size:
        fail("header.file_size", f"header says {file_size} bytes, the file has {size} (truncated or padded?)")
    directory_end = HEADER_SIZE + num_arrays * ENTRY_SIZE
    if directory_end > size:
        fail("header.num_arrays", "directory runs past the end of the file")

    arrays: dict[str, NDArray[Any]] = {}
    options_text: str | None = None
    extents: list[tuple[int, int]] = []
    for i in range(num_arrays):
        start = HEADER_SIZE + i * ENTRY_SIZE
        raw_name, code, ndim, rows, cols, offset = _ENTRY.unpack(bytes(data[start : start + ENTRY_SIZE]))
        where = f"array {i}"
        if b"\0" not in raw_name:
            fail(where, "name is not NUL-terminated")
        name_bytes = raw_name.split(b"\0", 1)[0]
        if not name_bytes or not all(c in b"abcdefghijklmnopqrstuvwxyz0123456789_" for c in name_bytes):
            fail(where, "bad name")
        name = name_bytes.decode("ascii")
        if name in arrays or (name == "options" and options_text is not None):
            fail(name, "array given twice")
        if code not in _DTYPES:
            fail(name, f"unknown dtype code {code}")
        if ndim not in (1, 2):
            fail(name, "ndim must be 1 or 2")
        if ndim == 1 and cols != 1:
            fail(name, "a 1-D array must have cols = 1")
        if cols == 0 or cols > 64:
            fail(name, "bad column count")
        dtype = _DTYPES[code]
        nbytes = rows * cols * dtype.itemsize
        if offset % ALIGNMENT:
            fail(name, "offset is not 64-byte aligned")
        if offset < directory_end:
            fail(name, "data overlaps the header or directory")
        if offset > size or nbytes > size - offset:
            fail(name, f"data runs past the end of the file (offset {offset}, {nbytes} bytes, file {size})")
        if rows > 2**31 - 1:
            fail(name, "too many rows")
        if nbytes:
            extents.append((offset, offset + nbytes))
        view = data[offset : offset + nbytes].view(dtype)
        if name == "options":
            if code != 3 or ndim != 1:
                fail(name, "must be a 1-D uint8 array")
            options_text = _options_text(bytes(view), fail)
            continue
        if name not in FIELDS:
            fail(name, "unknown array")
        want_dtype, want_cols, _ = FIELDS[name]
        if dtype != np.dtype(want_dtype):
            fail(name, f"dtype {dtype.name}, expected {np.dtype(want_dtype).name}")
        if ndim != (2 if want_cols else 1) or cols != (want_cols or 1):
            fail(name, f"expected {'a 2-D array with %d columns' % want_cols if want_cols else 'a 1-D array'}")
        arrays[name] = view.reshape((rows, cols) if ndim == 2 else (rows,))
    extents.sort()
    for (_, end0), (start1, _) in zip(extents, extents[1:]):
        if start1 < end0:
            fail("directory", "arrays overlap")
    for name, (_, _, required) in FIELDS.items():
        if required and name not in arrays:
            fail(name, "required array missing")
    full = {name: arrays.get(name, np.zeros((0, c) if c else (0,), dtype=d)) for name, (d, c, _) in FIELDS.items()}
    validate_arrays(full, path, ProblemFileError)
    options = SolverOptions()
    if options_text is not None:
        flat: dict[str, str] = {}
        for lineno, line in enumerate(options_text.splitlines(), start=1):
            if not line or line.startswith("#"):
                continue
            key, sep, value = line.partition("=")
            if not sep or not key:
                fail("options", f"line {lineno} is not key=value")
            if key in flat:
                fail(key, "given twice")
            flat[key] = value
        try:
            options = SolverOptions.from_flat(flat)
        except SolverInputError as exc:
            raise ProblemFileError(str(exc), path) from None
    return arrays, options
