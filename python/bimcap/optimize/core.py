"""Loading the compiled C++ core, ``bimcap._core``, with a clear error when it is missing."""

from __future__ import annotations

from typing import Any

from bimcap.optimize.errors import SolverUnavailableError


def core() -> Any:
    """The compiled module ``bimcap._core``; raises SolverUnavailableError if it is not built."""
    try:
        from bimcap import _core  # compiled; optional at import time
    except ImportError as exc:
        raise SolverUnavailableError(
            f"bimcap._core is not available ({exc}); install bimcap with pip (it builds the C++ "
            "core) or run the developer build (cmake -DBIMCAP_PYTHON=ON)"
        ) from None
    return _core
