"""Gravity and height: fix pitch, roll and z of a window from its floor and ceiling points.

The floor points of a window, mapped to the world with the window's initial poses, should lie
on ``z = floor_z`` and the ceiling points on ``z = ceiling_z``. A small rotation about the
horizontal axes through the pivot and a vertical shift,
``q = R(ω_x, ω_y) (p - c) + c + (0, 0, dz)``, are fitted by iteratively reweighted (Huber,
gated) least squares with a weak prior on the angles, so that a window that sees only a small
patch of floor keeps its tilt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class LevelResult:
    """A levelling correction ``q = rotation (p - pivot) + pivot + (0, 0, dz)``.

    Attributes
    ----------
    rotation: (3, 3) tilt correction (no yaw component to first order).
    dz: metres.
    pivot: (3,) metres.
    rms_m: RMS height residual of the inliers after the fit (NaN if not fitted).
    inlier_ratio: fraction of floor+ceiling points within the gate after the fit.
    ok: False when there were too few points (the correction is then the identity).
    """

    rotation: F64
    dz: float
    pivot: F64
    rms_m: float
    inlier_ratio: float
    ok: bool

    def matrix(self) -> F64:
        """(4, 4) world-from-world matrix."""
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.pivot - self.rotation @ self.pivot + np.array([0.0, 0.0, self.dz])
        return m

    @classmethod
    def identity(cls, pivot: NDArray[np.float64]) -> LevelResult:
        return cls(np.eye(3), 0.0, np.asarray(pivot, dtype=np.float64), float("nan"), 0.0, False)


def level_window(
    floor_p_in_world: NDArray[np.float64],
    ceiling_p_in_world: NDArray[np.float64],
    floor_z: float | None,
    ceiling_z: float | None,
    pivot: NDArray[np.float64],
    gate_m: float = 0.15,
    huber_m: float = 0.03,
    angle_prior_rad: float = np.deg2rad(5.0),
    iterations: int = 6,
    min_points: int = 30,
) -> LevelResult:
    """Fit tilt and height of a window to the BIM floor and ceiling heights.

    Parameters
    ----------
    floor_p_in_world: (F, 3) floor points mapped with the initial poses, metres.
    ceiling_p_in_world: (C, 3) likewise (may be empty).
    floor_z, ceiling_z: the BIM heights (metres) those points belong to; None = unknown.
    pivot: (3,) the rotation centre (e.g. the window's mean camera position).
    gate_m: points farther than this from their plane after the current estimate are ignored
        (the first estimate of dz is the median offset, so a large z drift is fine).

    Returns
    -------
    LevelResult
    """
    pivot = np.asarray(pivot, dtype=np.float64)
    pts, target = [], []
    if floor_z is not None and len(floor_p_in_world):
        pts.append(np.asarray(floor_p_in_world, dtype=np.float64).reshape(-1, 3))
        target.append(np.full(len(pts[-1]), float(floor_z)))
    if ceiling_z is not None and len(ceiling_p_in_world):
        pts.append(np.asarray(ceiling_p_in_world, dtype=np.float64).reshape(-1, 3))
        target.append(np.full(len(pts[-1]), float(ceiling_z)))
    if not pts or sum(len(p) for p in pts) < min_points:
        return LevelResult.identity(pivot)
    p = np.concatenate(pts)
    h = np.concatenate(target)
    rot = np.eye(3)
    dz = float(np.median(h - p[:, 2]))
    prior = 1.0 / angle_prior_rad ** 2
    use = np.zeros(len(p), dtype=bool)
    for _ in range(iterations):
        q = (p - pivot) @ rot.T + pivot
        r = q[:, 2] + dz - h
        use = np.abs(r) < gate_m
        if use.sum() < min_points:
            return LevelResult.identity(pivot)
        v = q[use] - pivot
        # z of (ω × v) = ω_x v_y - ω_y v_x; the derivative of r by dz is 1.
        jac = np.c_[v[:, 1], -v[:, 0], np.ones(len(v))]
        ru = r[use]
        w = np.where(np.abs(ru) <= huber_m, 1.0, huber_m / np.maximum(np.abs(ru), 1e-12))
        # Data weighted by 1/huber² (the noise scale), so the angle prior only matters when
        # the floor patch is too small to fix the tilt.
        info = 1.0 / huber_m ** 2
        a = (jac * w[:, None]).T @ jac * info
        tilt = Rotation.from_matrix(rot).as_rotvec()
        a[0, 0] += prior
        a[1, 1] += prior
        g = (jac * w[:, None]).T @ ru * info
        g[0] += prior * tilt[0]
        g[1] += prior * tilt[1]
        delta = -np.linalg.solve(a, g)
        rot = Rotation.from_rotvec([delta[0], delta[1], 0.0]).as_matrix() @ rot
        dz += float(delta[2])
        if np.abs(delta).max() < 1e-7:
            break
    q = (p - pivot) @ rot.T + pivot
    r = q[:, 2] + dz - h
    use = np.abs(r) < gate_m
    rms = float(np.sqrt(np.mean(r[use] ** 2))) if use.any() else float("nan")
    return LevelResult(rot, dz, pivot, rms, float(use.mean()), True)
