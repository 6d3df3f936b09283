"""Exact point-to-segment distances and a robust 2-D (x, y, yaw) point-to-segment ICP.

A 2-D correction acts on world points about a pivot ``c``:
``q = R(yaw) (p - c) + c + t``; :func:`apply_correction` implements it and
:class:`Correction2D` stores it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Correction2D:
    """A planar rigid correction about ``pivot``: ``q = R(yaw)(p - pivot) + pivot + t``.

    Attributes
    ----------
    yaw: radians.
    t: (2,) metres.
    pivot: (2,) metres (world xy).
    """

    yaw: float
    t: F64
    pivot: F64

    def apply(self, p_xy: NDArray[np.float64]) -> F64:
        """Map (M, 2) world points."""
        return apply_correction(p_xy, self.yaw, self.t, self.pivot)

    def matrix(self) -> F64:
        """(3, 3) homogeneous 2-D matrix of the correction (about the world origin)."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        r = np.array([[c, -s], [s, c]])
        m = np.eye(3)
        m[:2, :2] = r
        m[:2, 2] = self.pivot + self.t - r @ self.pivot
        return m


def rot2(yaw: float) -> F64:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])


def apply_correction(p_xy: NDArray[np.float64], yaw: float, t: NDArray[np.float64],
                     pivot: NDArray[np.float64]) -> F64:
    """``R(yaw) (p - pivot) + pivot + t`` for (M, 2) points."""
    return (np.asarray(p_xy) - pivot) @ rot2(yaw).T + pivot + t


def point_segment_distance(p_xy: NDArray[np.float64], segments: NDArray[np.float64],
                           chunk: int = 4096) -> tuple[F64, NDArray[np.int64], F64]:
    """Nearest segment of every point, exactly.

    Parameters
    ----------
    p_xy: (M, 2) metres.
    segments: (S, 4) ``x1 y1 x2 y2`` metres, S >= 1.

    Returns
    -------
    dist: (M,) metres; index: (M,) the nearest segment; closest: (M, 2) the closest point on it.
    """
    p = np.asarray(p_xy, dtype=np.float64).reshape(-1, 2)
    a, b = segments[:, :2], segments[:, 2:]
    ab = b - a
    len2 = np.maximum((ab ** 2).sum(1), 1e-18)
    dist = np.empty(len(p))
    idx = np.empty(len(p), dtype=np.int64)
    closest = np.empty((len(p), 2))
    for s in range(0, len(p), chunk):
        q = p[s:s + chunk]
        ap = q[:, None, :] - a[None]
        u = np.clip((ap * ab[None]).sum(-1) / len2[None], 0.0, 1.0)
        c = a[None] + u[..., None] * ab[None]
        d2 = ((q[:, None, :] - c) ** 2).sum(-1)
        j = d2.argmin(1)
        rows = np.arange(len(q))
        idx[s:s + chunk] = j
        dist[s:s + chunk] = np.sqrt(d2[rows, j])
        closest[s:s + chunk] = c[rows, j]
    return dist, idx, closest


@dataclass(frozen=True)
class IcpResult:
    """Outcome of :func:`icp_2d`: the correction, and the fit at the final radius.

    ``constraint`` is the smaller eigenvalue of the mean outer product ``n nᵀ`` of the inliers'
    residual directions (0 = translation unconstrained along some direction, as in a corridor
    seen without its ends or doors; 0.5 = constrained equally in every direction).
    """

    correction: Correction2D
    inlier_ratio: float
    rms_m: float
    iterations: int
    constraint: float


def _nearest_by_class(q: F64, q_class: NDArray[np.int32], segments: F64,
                      segment_class: NDArray[np.int32]) -> tuple[F64, F64]:
    dist = np.full(len(q), np.inf)
    closest = q.copy()
    for cls in np.unique(q_class):
        m = q_class == cls
        segs = segments[segment_class == cls]
        if len(segs) == 0:
            continue
        d, _, c = point_segment_distance(q[m], segs)
        dist[m], closest[m] = d, c
    return dist, closest


#: ``associate(q (M, 2), q_class (M,), view (M, 2)) -> (dist (M,), closest (M, 2))``: the
#: nearest admissible segment of each point; ``view`` is the ray direction camera → point after
#: the current correction (an associator may use it to skip faces that cannot be seen).
Associator = Callable[[F64, NDArray[np.int32], F64], tuple[F64, F64]]


def exact_associator(segments: NDArray[np.float64], segment_class: NDArray[np.int32]
                     ) -> Associator:
    """Brute-force same-class nearest segment (exact; O(M·S))."""
    seg = np.asarray(segments, dtype=np.float64)
    cls_ = np.asarray(segment_class)
    return lambda q, q_class, view: _nearest_by_class(q, q_class, seg, cls_)


def icp_2d(
    p_xy: NDArray[np.float64],
    p_class: NDArray[np.int32],
    associate: Associator,
    init: Correction2D,
    view_xy: NDArray[np.float64] | None = None,
    radius_start_m: float = 0.3,
    radius_end_m: float = 0.08,
    iterations: int = 10,
    huber_m: float = 0.03,
    inlier_m: float = 0.1,
) -> IcpResult:
    """Robust point-to-segment ICP over (x, y, yaw), same-class association.

    Each point is associated with the nearest segment of its own class; pairs farther than the
    current radius (shrinking geometrically from ``radius_start_m`` to ``radius_end_m``) are
    dropped and the rest weighted with a Huber loss. The residual is the distance to the closest
    point along the unit vector to it, i.e. point-to-line for interior closest points and
    point-to-point at segment ends; the update is a linearised 3-parameter least squares.

    Parameters
    ----------
    p_xy: (M, 2) world points before ``init``; p_class: (M,) their class (1 wall, 4 column).
    associate: nearest same-class segment of points (:func:`exact_associator`, or the raster
        :meth:`bimcap.registration.distance_field.SegmentIndex.nearest`).
    init: the starting correction; its pivot is kept.
    view_xy: (M, 2) ray directions camera → point before the correction (rotated with the
        yaw and passed to ``associate``); None = zeros.

    Returns
    -------
    IcpResult with ``inlier_ratio`` = fraction of points within ``inlier_m`` at the end.
    """
    p = np.asarray(p_xy, dtype=np.float64).reshape(-1, 2)
    yaw, t, pivot = float(init.yaw), np.asarray(init.t, dtype=np.float64).copy(), init.pivot
    view = np.zeros_like(p) if view_xy is None else np.asarray(view_xy, dtype=np.float64)
    radii = np.geomspace(radius_start_m, radius_end_m, max(iterations, 1))
    it = 0
    for it, radius in enumerate(radii, start=1):  # noqa: B007 (the count is reported below)
        q = apply_correction(p, yaw, t, pivot)
        dist, closest = associate(q, p_class, view @ rot2(yaw).T)
        use = dist < radius
        if use.sum() < 3:
            break
        yaw, t, done = _gauss_newton_step(q[use], closest[use], dist[use], huber_m, yaw, t,
                                          pivot)
        if done and radius <= radius_end_m * 1.01:
            break
    q = apply_correction(p, yaw, t, pivot)
    dist, closest = associate(q, p_class, view @ rot2(yaw).T)
    return _icp_result(q, dist, closest, inlier_m, yaw, t, pivot, it)


def _gauss_newton_step(qu: F64, cu: F64, du: F64, huber_m: float, yaw: float, t: F64,
                       pivot: F64) -> tuple[float, F64, bool]:
    """One Huber-weighted Gauss-Newton step of the point-to-line ICP: the points ``qu`` (N, 2),
    their closest plan points ``cu`` (N, 2) and distances ``du`` (N,) metres, N >= 3; returns
    the new yaw (rad) and translation (2,) about ``pivot``, and whether the step was below
    1e-6 rad and 1e-5 m."""
    n = (qu - cu) / np.maximum(du, 1e-9)[:, None]
    m = qu.mean(0)
    v = qu - m
    # d(residual)/d(dyaw) = n · J v with J v = (-v_y, v_x); d/d(t) = n.
    jac = np.c_[n[:, 1] * v[:, 0] - n[:, 0] * v[:, 1], n]
    w = np.where(du <= huber_m, 1.0, huber_m / np.maximum(du, 1e-12))
    h = (jac * w[:, None]).T @ jac + np.diag([1e-6, 1e-9, 1e-9])
    g = (jac * w[:, None]).T @ du
    delta = -np.linalg.solve(h, g)
    dyaw, dt = float(delta[0]), delta[1:]
    # Compose q' = R(dyaw)(q - m) + m + dt with q = R(yaw)(p - pivot) + pivot + t.
    t = rot2(dyaw) @ (pivot + t - m) + m + dt - pivot
    return yaw + dyaw, t, bool(abs(dyaw) < 1e-6 and np.linalg.norm(dt) < 1e-5)


def _icp_result(q: F64, dist: F64, closest: F64, inlier_m: float, yaw: float, t: F64,
                pivot: F64, iterations: int) -> IcpResult:
    """The result of an ICP run ending at ``yaw``, ``t``: ``q`` (M, 2) the points moved there,
    ``dist`` (M,) / ``closest`` (M, 2) their association."""
    ok = dist < inlier_m
    rms = float(np.sqrt(np.mean(dist[ok] ** 2))) if ok.any() else float("nan")
    constraint = 0.0
    if ok.sum() >= 3:
        # Directions from the segment to the point; for points on the line use its normal,
        # which the residual direction approximates well enough at noise level.
        n = (q[ok] - closest[ok]) / np.maximum(dist[ok], 1e-12)[:, None]
        constraint = float(np.linalg.eigvalsh(n.T @ n / len(n))[0])
    yaw = float(np.arctan2(np.sin(yaw), np.cos(yaw)))
    return IcpResult(Correction2D(yaw, t, np.asarray(pivot, dtype=np.float64)),
                     float(ok.mean()) if len(ok) else 0.0, rms, iterations, constraint)


def icp_2d_many(
    p_xy: NDArray[np.float64],
    p_class: NDArray[np.int32],
    associate: Associator,
    inits: list[Correction2D],
    view_xy: NDArray[np.float64] | None = None,
    radius_start_m: float = 0.3,
    radius_end_m: float = 0.08,
    iterations: int = 10,
    huber_m: float = 0.03,
    inlier_m: float = 0.1,
) -> list[IcpResult]:
    """:func:`icp_2d` of the same points from each of ``inits`` (K corrections), the K runs
    in lock-step: each iteration associates the points of every run still going in one call
    of ``associate`` (the per-call overhead once, not K times), the rest per run as
    :func:`icp_2d` does it. ``associate`` must treat each point on its own (the raster
    associators do: a point's nearest segment does not depend on the other points), so each
    result has the bits of ``icp_2d`` from that init.

    Returns
    -------
    K IcpResults, in the order of ``inits``.
    """
    p = np.asarray(p_xy, dtype=np.float64).reshape(-1, 2)
    m_pts = len(p)
    view = np.zeros_like(p) if view_xy is None else np.asarray(view_xy, dtype=np.float64)
    radii = np.geomspace(radius_start_m, radius_end_m, max(iterations, 1))
    k_runs = len(inits)
    yaw = [float(f.yaw) for f in inits]
    t = [np.asarray(f.t, dtype=np.float64).copy() for f in inits]
    pivot = [f.pivot for f in inits]
    its = [0] * k_runs
    going = list(range(k_runs))
    cls_all = np.tile(np.asarray(p_class), max(k_runs, 1))

    def associate_all(runs: list[int]) -> tuple[list[F64], list[F64], list[F64]]:
        qs = [apply_correction(p, yaw[r], t[r], pivot[r]) for r in runs]
        vs = [view @ rot2(yaw[r]).T for r in runs]
        dist, closest = associate(np.concatenate(qs), cls_all[:len(runs) * m_pts],
                                  np.concatenate(vs))
        return (qs, [dist[j * m_pts:(j + 1) * m_pts] for j in range(len(runs))],
                [closest[j * m_pts:(j + 1) * m_pts] for j in range(len(runs))])

    for it, radius in enumerate(radii, start=1):
        if not going:
            break
        for r in going:
            its[r] = it
        qs, dists, closests = associate_all(going)
        still = []
        for j, r in enumerate(going):
            q, dist, closest = qs[j], dists[j], closests[j]
            use = dist < radius
            if use.sum() < 3:
                continue
            yaw[r], t[r], done = _gauss_newton_step(q[use], closest[use], dist[use], huber_m,
                                                    yaw[r], t[r], pivot[r])
            if done and radius <= radius_end_m * 1.01:
                continue
            still.append(r)
        going = still
    out: list[IcpResult] = []
    if k_runs == 0:
        return out
    qs, dists, closests = associate_all(list(range(k_runs)))
    for r in range(k_runs):
        out.append(_icp_result(qs[r], dists[r], closests[r], inlier_m, yaw[r], t[r], pivot[r],
                               its[r]))
    return out
