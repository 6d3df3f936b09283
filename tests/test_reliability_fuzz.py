"""Issue 12, item 7: a sweep of mutated problem files through both readers and ``bimcap_solve``.

Mutations of the committed seed corpus (``cpp/fuzz/corpus/``, valid files written by
``write_problem``): truncations, bit flips, huge sizes and counts in the header and directory,
non-finite and overflowing values in the float arrays, bytes in the options text. Every file
goes through the numpy reader (``read_problem``), the C++ reader (``_core.parse_problem_bytes``)
and ``bimcap_solve`` as a subprocess, asserting: no signal, no hang (timeouts), and either a
clear error (an ``InputError`` / exit 2 with one ``error:`` line, or a failed solve with exit 3)
or a successful solve with a finite cost and finite poses. The libFuzzer target
(``scripts/fuzz.sh``) explores the reader much further when clang is present.
"""

from __future__ import annotations

import json
import math
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from _solver_helpers import REPO, bimcap_solve_binary, core
from bimcap.errors import InputError
from bimcap.optimize.problem_file import parse_problem_buffer

CORPUS = REPO / "cpp" / "fuzz" / "corpus"
SOLVE_TIMEOUT_S = 30


def _seeds() -> list[bytes]:
    files = sorted(CORPUS.glob("*.bcp"))
    if not files:
        pytest.skip(f"no seed corpus in {CORPUS} (python cpp/fuzz/make_corpus.py)")
    return [f.read_bytes() for f in files]


def _directory(data: bytes) -> list[tuple[int, str, int, int, int, int]]:
    """(entry offset, name, dtype, rows, cols, data offset) of each array."""
    n = struct.unpack_from("<I", data, 16)[0]
    out = []
    for i in range(n):
        at = 64 + 64 * i
        name = data[at : at + 32].split(b"\0")[0].decode()
        dtype, _ndim, rows, cols, offset = struct.unpack_from("<IIQQQ", data, at + 32)
        out.append((at, name, dtype, rows, cols, offset))
    return out


def mutations(seed: bytes, rng: np.random.Generator) -> list[tuple[str, bytes]]:
    """Named mutations of one valid file."""
    out: list[tuple[str, bytes]] = []
    size = len(seed)
    for cut in sorted({0, 7, 63, 64, 65, 200, size // 2, size - 64, size - 1}):
        out.append((f"truncated to {cut}", seed[:cut]))
    for _ in range(6):
        b = bytearray(seed)
        for _ in range(int(rng.integers(1, 6))):
            b[int(rng.integers(0, size))] ^= 1 << int(rng.integers(0, 8))
        out.append(("bit flips", bytes(b)))
    for field_at, what in ((16, "num_arrays"), (24, "file_size")):
        for value in (2**31, 2**63 - 1, 2**64 - 1):
            b = bytearray(seed)
            struct.pack_into("<I" if what == "num_arrays" else "<Q", b, field_at,
                             value & (0xFFFFFFFF if what == "num_arrays" else 2**64 - 1))
            out.append((f"header {what} {value}", bytes(b)))
    entries = _directory(seed)
    for at, name, _dtype, _rows, _cols, _offset in entries[:: max(1, len(entries) // 6)]:
        for rel, value in ((40, 2**62), (40, 2**31 - 1), (48, 2**40), (56, 2**63)):
            b = bytearray(seed)
            struct.pack_into("<Q", b, at + rel, value)
            out.append((f"{name} directory +{rel} = {value}", bytes(b)))
    for _at, name, dtype, rows, cols, offset in entries:
        if dtype != 1 or rows == 0:
            continue
        for value in (math.nan, math.inf, -math.inf, 1e308, -1e300, 1e-300):
            b = bytearray(seed)
            k = int(rng.integers(0, rows * cols))
            struct.pack_into("<d", b, offset + 8 * k, value)
            out.append((f"{name}[{k}] = {value}", bytes(b)))
    options = next((e for e in entries if e[1] == "options"), None)
    if options is not None and options[3] > 2:
        for raw in (b"\xff", b"\x00", b"\r", b"="):
            b = bytearray(seed)
            b[options[5] + int(rng.integers(0, options[3]))] = raw[0]
            out.append((f"options byte {raw!r}", bytes(b)))
    return out


@pytest.fixture(scope="module")
def corpus() -> list[tuple[str, bytes]]:
    rng = np.random.default_rng(12)
    out = []
    for k, seed in enumerate(_seeds()):
        out += [(f"seed {k}: {name}", data) for name, data in mutations(seed, rng)]
    return out


def test_both_readers_parse_or_raise_input_errors(corpus: list[tuple[str, bytes]]) -> None:
    _core = core()
    rejected = 0
    for name, data in corpus:
        try:
            parse_problem_buffer(data)
            py_ok = True
        except InputError:
            py_ok = False
        cpp_error = ""
        try:
            _core.parse_problem_bytes(data)
            cpp_ok = True
        except _core.InputError as exc:
            cpp_error = str(exc)
            cpp_ok = False
        assert cpp_ok or cpp_error, name
        assert py_ok == cpp_ok, f"{name}: the numpy and C++ readers disagree"
        rejected += not py_ok
    assert rejected > len(corpus) // 2


def test_bimcap_solve_never_crashes_or_hangs(corpus: list[tuple[str, bytes]],
                                             tmp_path: Path) -> None:
    exe = bimcap_solve_binary()
    rng = np.random.default_rng(3)
    # Every file the readers accept (they go on to a solve), and a sample of the rejected ones.
    accepted, rejected = [], []
    for name, data in corpus:
        try:
            parse_problem_buffer(data)
            accepted.append((name, data))
        except InputError:
            rejected.append((name, data))
    picked = accepted + [rejected[i] for i in rng.choice(len(rejected), min(25, len(rejected)),
                                                         replace=False)]
    outcomes = {0: 0, 2: 0, 3: 0}
    for k, (name, data) in enumerate(picked):
        path = tmp_path / f"m{k}.bcp"
        path.write_bytes(data)
        out = tmp_path / f"out{k}"
        r = subprocess.run([str(exe), str(path), "-o", str(out), "--quiet"], capture_output=True,
                           text=True, timeout=SOLVE_TIMEOUT_S, errors="replace")
        assert r.returncode >= 0, f"{name}: killed by signal {-r.returncode}\n{r.stderr}"
        assert r.returncode in outcomes, f"{name}: exit {r.returncode}\n{r.stderr}"
        outcomes[r.returncode] += 1
        if r.returncode == 0:
            summary = json.loads((out / "summary.json").read_text())
            assert summary["success"] is True, name
            assert summary["final_cost"] is not None and math.isfinite(summary["final_cost"]), name
            poses = np.loadtxt(out / "refined.tum", ndmin=2)
            assert np.isfinite(poses).all(), name
        else:
            lines = [ln for ln in r.stderr.splitlines() if ln.startswith("bimcap_solve:")]
            assert lines, f"{name}: exit {r.returncode} without a message\n{r.stderr}"
            assert ("error:" in lines[-1]) or ("solve failed" in lines[-1]), lines
            assert "Traceback" not in r.stderr and "terminate called" not in r.stderr, name
    assert outcomes[0] > 0 and outcomes[2] > 0, outcomes
