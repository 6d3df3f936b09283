"""Pairing by time: each image with the nearest LiDAR scan, each frame with the nearest pose.

Shared by every importer (ConSLAM, ROS bags, folders). Timestamps are float seconds.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


def pair_nearest(
    t_a: ArrayLike, t_b: ArrayLike, tolerance_s: float
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Pair each ``t_a`` with the nearest ``t_b`` within ``tolerance_s``, each b used once.

    Pairs are accepted greedily by increasing |Δt|, so a b closer to another a goes there.

    Returns
    -------
    (K,) indices into ``t_a`` (increasing) and (K,) indices into ``t_b``.
    """
    a = np.asarray(t_a, dtype=np.float64)
    b = np.asarray(t_b, dtype=np.float64)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    order_b = np.argsort(b, kind="stable")
    bs = b[order_b]
    pos = np.searchsorted(bs, a)
    cands: list[tuple[float, int, int]] = []
    for i, p in enumerate(pos):
        for j in (p - 1, p):
            if 0 <= j < len(bs):
                dt = abs(a[i] - bs[j])
                if dt <= tolerance_s:
                    cands.append((dt, i, int(order_b[j])))
    cands.sort()
    used_a: set[int] = set()
    used_b: set[int] = set()
    pairs: list[tuple[int, int]] = []
    for _, i, j in cands:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    pairs.sort()
    ia = np.array([p[0] for p in pairs], dtype=np.int64)
    ib = np.array([p[1] for p in pairs], dtype=np.int64)
    return ia, ib


def nearest(t_query: ArrayLike, t_ref: ArrayLike) -> tuple[NDArray[np.int64], F64]:
    """Index of the nearest ``t_ref`` (sorted, non-empty) for each query (Q,), and |Δt| (Q,)."""
    q = np.asarray(t_query, dtype=np.float64)
    ref = np.asarray(t_ref, dtype=np.float64)
    pos = np.clip(np.searchsorted(ref, q), 1, max(len(ref) - 1, 1))
    lo = np.maximum(pos - 1, 0)
    hi = np.minimum(pos, len(ref) - 1)
    pick = np.where(np.abs(q - ref[lo]) <= np.abs(q - ref[hi]), lo, hi)
    return pick.astype(np.int64), np.abs(q - ref[pick])


def unique_increasing(t: ArrayLike) -> NDArray[np.bool_]:
    """(N,) mask keeping the first of equal consecutive values of a sorted time array."""
    arr = np.asarray(t, dtype=np.float64)
    return np.concatenate([np.ones(min(len(arr), 1), bool), np.diff(arr) > 0])
