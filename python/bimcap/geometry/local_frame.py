"""A local origin for float32 geometry far from the world's origin.

Open3D's ray casting (and any float32 array) steps by 0.5 m at 5·10⁶ m, a georeferenced model's
northing. Code that hands world coordinates to float32 holds them relative to
:func:`local_origin` and adds it back in float64.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

#: :func:`local_origin` keeps points that all lie within this of the origin (metres) at the
#: origin; further out it rounds their centre to a multiple of it.
LOCAL_ORIGIN_STEP_M = 1000.0


def local_origin(points: NDArray[np.floating]) -> F64:
    """(3,) float64 metres: the zero to hold ``points`` (N, 3) world metres relative to in float32.

    The origin itself when every point is within :data:`LOCAL_ORIGIN_STEP_M` of it (so that
    models near the origin compute bit for bit as in world coordinates), else the centre of their
    bounding box rounded to a multiple of :data:`LOCAL_ORIGIN_STEP_M`.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0 or float(np.abs(p).max()) <= LOCAL_ORIGIN_STEP_M:
        return np.zeros(3)
    centre = 0.5 * (p.min(axis=0) + p.max(axis=0))
    out: F64 = np.round(centre / LOCAL_ORIGIN_STEP_M) * LOCAL_ORIGIN_STEP_M
    return out
