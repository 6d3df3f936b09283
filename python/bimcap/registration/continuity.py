"""Trajectory continuity: pick one hypothesis per window so that neighbouring windows agree.

Drift is smooth, so the corrections of consecutive windows must be close. Each window offers
up to K hypotheses (planar corrections with a data score); a Viterbi pass over the chain of
windows minimises

    Σ_w  -score_w / σ_score  +  λ Σ_w min(cap, |ΔT_w(b)|² / σ_t² + Δyaw_w² / σ_yaw²)

where ``ΔT_w(b)`` is the difference of the two windows' corrections evaluated at the point
``b`` between them (the boundary camera position), so the comparison does not depend on
where each correction's pivot is. A symmetric room (two equally good poses) thereby takes the
hypothesis that continues its neighbours'; ``cap`` lets a long run of windows with much better
data overrule one wrong neighbour.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from bimcap.registration.icp import Correction2D

F64 = NDArray[np.float64]


def transition_cost(
    a: list[Correction2D],
    b: list[Correction2D],
    boundary_xy: NDArray[np.float64],
    sigma_t_m: float,
    sigma_yaw_rad: float,
    cap: float,
) -> F64:
    """(Ka, Kb) pairwise costs between the hypotheses of two consecutive windows."""
    pa = np.array([c.apply(boundary_xy[None])[0] for c in a]).reshape(-1, 2)
    pb = np.array([c.apply(boundary_xy[None])[0] for c in b]).reshape(-1, 2)
    ya = np.array([c.yaw for c in a])
    yb = np.array([c.yaw for c in b])
    dt2 = ((pa[:, None, :] - pb[None, :, :]) ** 2).sum(-1)
    dy = np.arctan2(np.sin(ya[:, None] - yb[None, :]), np.cos(ya[:, None] - yb[None, :]))
    return np.minimum(dt2 / sigma_t_m ** 2 + dy ** 2 / sigma_yaw_rad ** 2, cap)


def viterbi_chain(unary: list[F64], pairwise: list[F64]) -> tuple[NDArray[np.int64], float]:
    """Minimum-cost labelling of a chain.

    Parameters
    ----------
    unary: per node w, (K_w,) costs.
    pairwise: per edge w → w+1, (K_w, K_{w+1}) costs (already weighted).

    Returns
    -------
    (labels (W,), total cost).
    """
    if not unary:
        return np.zeros(0, dtype=np.int64), 0.0
    cost = np.asarray(unary[0], dtype=np.float64)
    back: list[NDArray[np.int64]] = []
    for w in range(1, len(unary)):
        tot = cost[:, None] + pairwise[w - 1]
        arg = tot.argmin(0)
        back.append(arg)
        cost = tot[arg, np.arange(tot.shape[1])] + unary[w]
    labels = np.zeros(len(unary), dtype=np.int64)
    labels[-1] = int(cost.argmin())
    total = float(cost[labels[-1]])
    for w in range(len(unary) - 1, 0, -1):
        labels[w - 1] = back[w - 1][labels[w]]
    return labels, total
