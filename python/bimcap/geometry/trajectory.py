"""Trajectories and TUM files.

A TUM trajectory file has one pose per line, ``timestamp tx ty tz qx qy qz qw``: the camera's pose
in the world (``world_from_cam``), timestamps in float seconds. Lines starting with ``#`` are
comments. evo reads these files as they are.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.io.atomic import atomic_write_text


class TrajectoryError(InputError):
    """A trajectory file or array that cannot be used (bad line, NaN, non-unit quaternion ...)."""


@dataclass
class Trajectory:
    """Timestamped ``world_from_cam`` poses.

    Attributes
    ----------
    timestamps: (N,) float64 seconds, strictly increasing.
    poses: (N, 7) float64, TUM order ``[tx, ty, tz, qx, qy, qz, qw]``, unit quaternions.
    """

    timestamps: NDArray[np.float64]
    poses: NDArray[np.float64]

    def __post_init__(self) -> None:
        self.timestamps = np.ascontiguousarray(self.timestamps, dtype=np.float64).reshape(-1)
        self.poses = np.ascontiguousarray(self.poses, dtype=np.float64)
        validate_poses(self.poses, self.timestamps)

    def __len__(self) -> int:
        return len(self.timestamps)

    def subset(self, index: NDArray[np.int64] | slice) -> Trajectory:
        """The poses at ``index`` (integer array, mask or slice)."""
        return Trajectory(self.timestamps[index], self.poses[index])


def validate_poses(
    poses: NDArray[np.float64],
    timestamps: NDArray[np.float64] | None = None,
    path: str | PathLike[str] | None = None,
    field: str = "poses",
) -> None:
    """Raise :class:`TrajectoryError` unless ``poses`` is a finite (N, 7) array of unit
    quaternions."""
    if poses.ndim != 2 or poses.shape[1] != 7:
        raise TrajectoryError(f"expected shape (N, 7), got {poses.shape}", path, field)
    bad = ~np.isfinite(poses).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise TrajectoryError(f"pose {i} is not finite: {poses[i].tolist()}", path, field)
    norms = np.linalg.norm(poses[:, 3:7], axis=1)
    bad = np.abs(norms - 1.0) > 1e-3
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise TrajectoryError(
            f"pose {i} has a quaternion of norm {norms[i]:.6g}, expected 1", path, field
        )
    if timestamps is not None:
        if len(timestamps) != len(poses):
            raise TrajectoryError(
                f"{len(timestamps)} timestamps for {len(poses)} poses", path, "timestamps"
            )
        if not np.isfinite(timestamps).all():
            raise TrajectoryError("timestamps must be finite", path, "timestamps")
        steps = np.diff(timestamps)
        if (steps <= 0).any():
            i = int(np.flatnonzero(steps <= 0)[0]) + 1
            raise TrajectoryError(
                f"timestamps must increase strictly; entry {i} ({float(timestamps[i])!r}) does not",
                path,
                "timestamps",
            )


def read_tum(path: str | PathLike[str]) -> Trajectory:
    """Read a TUM trajectory file; quaternions are renormalised if within 1e-3 of unit norm.

    Raises
    ------
    TrajectoryError
        Naming the file and line when a line has the wrong number of fields, a value is not a
        number, a pose is NaN/Inf, a quaternion is far from unit norm, or timestamps do not
        increase.
    """
    p = Path(path)
    if not p.is_file():
        raise TrajectoryError("no such file", p)
    rows: list[list[float]] = []
    with open(p, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = s.replace(",", " ").split()
            if len(parts) != 8:
                raise TrajectoryError(
                    f"expected 8 fields 'timestamp tx ty tz qx qy qz qw', got {len(parts)}",
                    p,
                    f"line {lineno}",
                )
            try:
                rows.append([float(x) for x in parts])
            except ValueError as exc:
                raise TrajectoryError(f"not a number ({exc})", p, f"line {lineno}") from None
    if not rows:
        raise TrajectoryError("no poses in file", p)
    arr = np.asarray(rows, dtype=np.float64)
    validate_poses(arr[:, 1:], arr[:, 0], p)
    poses = arr[:, 1:].copy()
    poses[:, 3:] /= np.linalg.norm(poses[:, 3:], axis=1, keepdims=True)
    return Trajectory(arr[:, 0], poses)


def write_tum(path: str | PathLike[str], traj: Trajectory, header: str | None = None) -> None:
    """Write a TUM file atomically (full float precision); ``header`` lines become ``#``
    comments."""
    lines = []
    if header:
        lines += [f"# {h}" for h in header.splitlines()]
    for t, p in zip(traj.timestamps, traj.poses, strict=True):
        lines.append(" ".join([repr(float(t))] + [repr(float(x)) for x in p]))
    atomic_write_text(os.fspath(path), "\n".join(lines) + "\n")
