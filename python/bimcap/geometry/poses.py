"""Rigid poses as dense arrays.

A pose is 7 numbers in **TUM order** ``[tx, ty, tz, qx, qy, qz, qw]`` (translation, then a unit
quaternion in Eigen/COLMAP x, y, z, w order). An array of poses has shape (N, 7). The name of a
pose variable says which frame it maps from and to: ``world_from_cam`` maps a point in camera
coordinates into the world, ``p_in_world = R @ p_in_cam + t``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

F64 = NDArray[np.float64]


def _as_poses(poses: ArrayLike) -> tuple[F64, bool]:
    arr = np.asarray(poses, dtype=np.float64)
    single = arr.ndim == 1
    arr = np.atleast_2d(arr)
    if arr.ndim != 2 or arr.shape[1] != 7:
        raise ValueError(f"poses must have shape (7,) or (N, 7), got {np.shape(poses)}")
    return arr, single


def quat_to_rotmat(q_xyzw: ArrayLike) -> F64:
    """Rotation matrices from quaternions.

    Parameters
    ----------
    q_xyzw: (..., 4) quaternions, x, y, z, w order; normalised before use.

    Returns
    -------
    (..., 3, 3) rotation matrices.
    """
    q = np.asarray(q_xyzw, dtype=np.float64)
    flat = q.reshape(-1, 4)
    mats: F64 = Rotation.from_quat(flat).as_matrix()
    return mats.reshape((*q.shape[:-1], 3, 3))


def rotmat_to_quat(rotmats: ArrayLike) -> F64:
    """Quaternions (x, y, z, w) with w >= 0 from rotation matrices of shape (..., 3, 3)."""
    r = np.asarray(rotmats, dtype=np.float64)
    q: F64 = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat()
    q[q[:, 3] < 0] *= -1.0
    return q.reshape((*r.shape[:-2], 4))


def pose_to_matrix(poses: ArrayLike) -> F64:
    """(N, 7) or (7,) TUM-order poses to (N, 4, 4) or (4, 4) homogeneous matrices."""
    arr, single = _as_poses(poses)
    mats = np.tile(np.eye(4), (arr.shape[0], 1, 1))
    mats[:, :3, :3] = quat_to_rotmat(arr[:, 3:7])
    mats[:, :3, 3] = arr[:, :3]
    return mats[0] if single else mats


def matrix_to_pose(mats: ArrayLike) -> F64:
    """(N, 4, 4) or (4, 4) homogeneous matrices (or (.., 3, 4)) to TUM-order poses."""
    m = np.asarray(mats, dtype=np.float64)
    single = m.ndim == 2
    m = m.reshape(-1, m.shape[-2], m.shape[-1])
    out = np.empty((m.shape[0], 7))
    out[:, :3] = m[:, :3, 3]
    out[:, 3:] = rotmat_to_quat(m[:, :3, :3])
    return out[0] if single else out


def invert(poses: ArrayLike) -> F64:
    """Inverse poses: ``cam_from_world`` from ``world_from_cam``; shape preserved."""
    arr, single = _as_poses(poses)
    rot = Rotation.from_quat(arr[:, 3:7]).inv()
    out = np.empty_like(arr)
    out[:, 3:] = rot.as_quat()
    out[:, :3] = -rot.apply(arr[:, :3])
    return out[0] if single else out


def compose(a_from_b: ArrayLike, b_from_c: ArrayLike) -> F64:
    """``a_from_c = a_from_b ∘ b_from_c``; broadcasts (7,) against (N, 7)."""
    ab, s1 = _as_poses(a_from_b)
    bc, s2 = _as_poses(b_from_c)
    r_ab = Rotation.from_quat(ab[:, 3:7])
    r_bc = Rotation.from_quat(bc[:, 3:7])
    n = max(len(ab), len(bc))
    out = np.empty((n, 7))
    out[:, 3:] = (r_ab * r_bc).as_quat()
    out[:, :3] = r_ab.apply(bc[:, :3]) + ab[:, :3]
    out[out[:, 6] < 0, 3:] *= -1.0
    return out[0] if (s1 and s2) else out


def transform_points(a_from_b: ArrayLike, p_in_b: ArrayLike) -> F64:
    """Map points (M, 3) from frame b to frame a with one pose (7,) or one pose per point (M, 7)."""
    pose, single = _as_poses(a_from_b)
    p = np.asarray(p_in_b, dtype=np.float64)
    if p.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 3), got {p.shape}")
    if single:
        flat = p.reshape(-1, 3)
        moved: F64 = Rotation.from_quat(pose[0, 3:7]).apply(flat) + pose[0, :3]
        return moved.reshape(p.shape)
    if p.shape != (len(pose), 3):
        raise ValueError(f"{len(pose)} poses need points of shape ({len(pose)}, 3), got {p.shape}")
    out: F64 = Rotation.from_quat(pose[:, 3:7]).apply(p) + pose[:, :3]
    return out
