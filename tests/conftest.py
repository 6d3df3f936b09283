"""Shared pytest fixtures. Tests that need ``../shared`` skip with a clear message when it is
absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("BIMCAP_SHARED", REPO.parent / "shared"))

# Tests never write into the user's shared cache (~/.cache/bimcap); the tests of the shared cache
# point it at a temporary directory themselves (subprocesses inherit this).
os.environ["BIMCAP_CACHE_DIR"] = "off"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The project's ``../shared`` folder (override with $BIMCAP_SHARED)."""
    if not SHARED.is_dir():
        pytest.skip(f"../shared not found at {SHARED}: set BIMCAP_SHARED to run this test")
    return SHARED


@pytest.fixture(scope="session")
def ifc_dir(shared_dir: Path) -> Path:
    d = shared_dir / "data" / "ifc"
    if not d.is_dir():
        pytest.skip(f"real IFC models not found in {d}")
    return d


@pytest.fixture(scope="session")
def oracles_dir(shared_dir: Path) -> Path:
    d = shared_dir / "oracles"
    if not d.is_dir():
        pytest.skip(f"oracle numbers not found in {d}")
    return d
