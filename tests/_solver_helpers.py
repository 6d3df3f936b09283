"""Helpers shared by the optimize tests (not collected: no test_ prefix)."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def core():
    """bimcap._core, or skip with a clear message when the C++ core is not built."""
    return pytest.importorskip(
        "bimcap._core",
        reason="bimcap._core is not built (pip install . or cmake -DBIMCAP_PYTHON=ON)",
    )


def bimcap_solve_binary() -> Path:
    """The bimcap_solve executable: $BIMCAP_SOLVE, next to the interpreter, on PATH, or a dev
    build."""
    candidates = [os.environ.get("BIMCAP_SOLVE"), str(Path(sys.executable).parent / "bimcap_solve"),
                  shutil.which("bimcap_solve")]
    # Developer builds, the most recent first (it matches the freshly built python/bimcap/_core).
    builds = sorted(REPO.glob("build/*/cpp/bimcap_solve"), key=lambda p: p.stat().st_mtime,
                    reverse=True)
    candidates += [str(p) for p in builds]
    for c in candidates:
        if c and Path(c).is_file() and os.access(c, os.X_OK):
            return Path(c)
    pytest.skip("bimcap_solve not found (set BIMCAP_SOLVE, pip install ., or build build/dev)")
