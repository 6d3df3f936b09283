"""Core geometry shared by every stage: poses, TUM trajectories, the camera model.

Nothing here imports another bimcap stage; every stage may import this.
"""

from __future__ import annotations

from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import (
    compose,
    invert,
    matrix_to_pose,
    pose_to_matrix,
    quat_to_rotmat,
    rotmat_to_quat,
    transform_points,
)
from bimcap.geometry.trajectory import Trajectory, TrajectoryError, read_tum, write_tum

__all__ = [
    "Camera",
    "Trajectory",
    "TrajectoryError",
    "compose",
    "invert",
    "matrix_to_pose",
    "pose_to_matrix",
    "quat_to_rotmat",
    "read_tum",
    "rotmat_to_quat",
    "transform_points",
    "write_tum",
]
