"""Umeyama least-squares alignment of two point sets (SE(3) or Sim(3)).

Reproduces evo's ``evo.core.geometry.umeyama_alignment`` operation for operation (population
covariance ``1/n``, reflection fix via ``det(U) det(V)``, scale ``trace(D S) / sigma_x``), and
evo's way of applying a Sim(3) to a trajectory: positions are scaled first, then rotated and
translated, ``t' = R (s t) + t_align`` and ``R' = R R_est``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.evaluation.errors import EvaluationError
from bimcap.geometry.poses import matrix_to_pose, pose_to_matrix

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Similarity:
    """``y = scale * rotation @ x + translation`` (``gt_from_est`` when aligning an estimate).

    Attributes
    ----------
    rotation: (3, 3) rotation matrix.
    translation: (3,) metres.
    scale: dimensionless, 1.0 for SE(3).
    """

    rotation: F64
    translation: F64
    scale: float = 1.0

    def apply_points(self, p: ArrayLike) -> F64:
        """Map points (N, 3) → (N, 3)."""
        pts = np.asarray(p, dtype=np.float64)
        return (self.rotation @ (self.scale * pts).T).T + self.translation

    def apply_poses(self, world_from_cam: ArrayLike) -> F64:
        """Map TUM poses (N, 7) like evo's ``scale`` then ``transform``: positions scaled, then the
        rigid part applied from the left. Returns (N, 7) TUM-order poses."""
        mats = pose_to_matrix(np.atleast_2d(np.asarray(world_from_cam, dtype=np.float64)))
        mats[:, :3, 3] *= self.scale
        rigid = np.eye(4)
        rigid[:3, :3] = self.rotation
        rigid[:3, 3] = self.translation
        return matrix_to_pose(rigid[None] @ mats)

    def to_dict(self) -> dict[str, object]:
        return {
            "rotation": self.rotation.tolist(),
            "translation_m": self.translation.tolist(),
            "scale": float(self.scale),
        }


def umeyama_alignment(x: ArrayLike, y: ArrayLike, with_scale: bool = False) -> Similarity:
    """Least-squares ``y ≈ s R x + t`` (Umeyama 1991), exactly as evo computes it.

    Parameters
    ----------
    x: (N, 3) source points (e.g. estimated positions), metres.
    y: (N, 3) target points (e.g. ground-truth positions), metres.
    with_scale: estimate the scale (Sim(3)); otherwise s = 1 (SE(3)).

    Raises
    ------
    EvaluationError
        If the shapes differ or the cross-covariance is degenerate (fewer than 2 non-zero
        singular values, e.g. all points identical or collinear).
    """
    xs = np.asarray(x, dtype=np.float64)
    ys = np.asarray(y, dtype=np.float64)
    if xs.shape != ys.shape or xs.ndim != 2 or xs.shape[1] != 3:
        raise EvaluationError(f"alignment needs two (N, 3) arrays, got {xs.shape} and {ys.shape}")
    xt, yt = xs.T, ys.T  # (3, N), evo's layout
    m, n = xt.shape
    mean_x = xt.mean(axis=1)
    mean_y = yt.mean(axis=1)
    sigma_x = 1.0 / n * (np.linalg.norm(xt - mean_x[:, None]) ** 2)
    cov_xy = np.multiply(1.0 / n, (yt - mean_y[:, None]) @ (xt - mean_x[:, None]).T)
    u, d, v = np.linalg.svd(cov_xy)
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < m - 1:
        raise EvaluationError(
            "degenerate covariance rank: Umeyama alignment needs at least 3 non-collinear positions"
        )
    s = np.eye(m)
    if np.linalg.det(u) * np.linalg.det(v) < 0.0:
        s[m - 1, m - 1] = -1
    r = u @ s @ v
    c = float(1.0 / sigma_x * np.trace(np.diag(d) @ s)) if with_scale else 1.0
    t = mean_y - np.multiply(c, r @ mean_x)
    return Similarity(rotation=r, translation=t, scale=c)
