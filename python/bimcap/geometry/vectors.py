"""Small vector helpers shared by the stages."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def cross_rows(a: F64, b: F64) -> F64:
    """Row-wise cross products of (N, 3) arrays: ``np.cross(a, b)`` bit for bit (each product
    rounded, then the difference, as numpy forms them: a1 b2 − a2 b1, a2 b0 − a0 b2,
    a0 b1 − a1 b0), without its shape handling (~4× cheaper on the RANSACs' 150 rows)."""
    out = np.empty((len(a), 3))
    np.subtract(a[:, 1] * b[:, 2], a[:, 2] * b[:, 1], out=out[:, 0])
    np.subtract(a[:, 2] * b[:, 0], a[:, 0] * b[:, 2], out=out[:, 1])
    np.subtract(a[:, 0] * b[:, 1], a[:, 1] * b[:, 0], out=out[:, 2])
    return out
