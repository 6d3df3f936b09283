"""Pose files of other tools, as ``world_from_cam`` matrices: KITTI, COLMAP ``images.txt``, TUM.

Every reader returns a :class:`PoseFile`: (N, 4, 4) ``world_from_cam`` matrices (camera → world,
OpenCV optical camera frame) and, where the format has them, timestamps and image names.

- **KITTI** (odometry ``poses/XX.txt``): one line per image, the 12 numbers of the top 3×4 of
  ``world_from_cam`` row by row (``r00 r01 r02 tx r10 r11 r12 ty r20 r21 r22 tz``): the pose of
  camera i in the frame of camera 0. No timestamps, no names: line i is image i (KITTI keeps the
  times in a separate ``times.txt``, one per line, which :func:`read_kitti` takes optionally).
- **COLMAP** ``images.txt`` (``colmap model_converter --output_type TXT``): per image two lines,
  ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and its 2-D points. The pose is
  ``cam_from_world`` with the quaternion in w, x, y, z order; it is inverted here. Images are
  returned in ``IMAGE_ID`` order, with their names; no timestamps.
- **TUM** (``timestamp tx ty tz qx qy qz qw``, ``world_from_cam``): read and written by
  :mod:`bimcap.geometry.trajectory`, wrapped here so that every format has the same interface.

Rotations are checked (orthonormal to 1e-3, determinant +1) and replaced by the nearest rotation.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from enum import Enum
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.geometry.poses import matrix_to_pose, pose_to_matrix
from bimcap.geometry.trajectory import Trajectory, TrajectoryError, read_tum, write_tum
from bimcap.io.atomic import atomic_write_text

F64 = NDArray[np.float64]

#: Largest tolerated ‖RᵀR − I‖ (max abs entry) of a rotation read from a file.
ROTATION_TOLERANCE = 1e-3


class PoseFormat(str, Enum):
    """A pose file format."""

    TUM = "tum"
    KITTI = "kitti"
    COLMAP = "colmap"


class PoseFormatError(TrajectoryError):
    """A pose file that cannot be read or written (names the file and the line or field)."""


@dataclass
class PoseFile:
    """Poses read from (or to write to) a pose file.

    Attributes
    ----------
    world_from_cam: (N, 4, 4) float64 homogeneous matrices, camera → world, metres.
    timestamps: (N,) float64 seconds, or None where the format has none (KITTI, COLMAP).
    names: (N,) image names (COLMAP), or None.
    """

    world_from_cam: F64
    timestamps: F64 | None = None
    names: list[str] | None = None

    def __post_init__(self) -> None:
        self.world_from_cam = np.ascontiguousarray(self.world_from_cam, dtype=np.float64)
        m = self.world_from_cam
        if m.ndim != 3 or m.shape[1:] != (4, 4):
            raise PoseFormatError(f"expected shape (N, 4, 4), got {m.shape}",
                                  field="world_from_cam")
        if self.timestamps is not None:
            self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
            if len(self.timestamps) != len(m):
                raise PoseFormatError(f"{len(self.timestamps)} timestamps for {len(m)} poses",
                                      field="timestamps")
        if self.names is not None and len(self.names) != len(m):
            raise PoseFormatError(f"{len(self.names)} names for {len(m)} poses", field="names")

    def __len__(self) -> int:
        return len(self.world_from_cam)

    def poses(self) -> F64:
        """(N, 7) TUM-order ``world_from_cam`` poses."""
        return matrix_to_pose(self.world_from_cam)

    def to_trajectory(self) -> Trajectory:
        """A :class:`Trajectory` (needs timestamps, strictly increasing)."""
        if self.timestamps is None:
            raise PoseFormatError("these poses have no timestamps", field="timestamps")
        return Trajectory(self.timestamps, self.poses())


# --------------------------------------------------------------------------- checks
def _checked_rotations(mats: F64, path: Path, where: list[str]) -> F64:
    """``mats`` (N, 4, 4) with each 3×3 block replaced by its nearest rotation, after checking
    that it is one (``where[i]`` names the line of matrix i)."""
    rot = mats[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    bad = (err > ROTATION_TOLERANCE) | (det <= 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise PoseFormatError(
            f"not a rotation (|RᵀR − I| = {float(err[i]):.3g}, det {float(det[i]):.3g})",
            path, where[i])
    u, _, vt = np.linalg.svd(rot)
    out = mats.copy()
    out[:, :3, :3] = u @ vt
    return out


def _numbers(parts: list[str], path: Path, where: str) -> list[float]:
    try:
        values = [float(x) for x in parts]
    except ValueError as exc:
        raise PoseFormatError(f"not a number ({exc})", path, where) from None
    if not np.isfinite(values).all():
        raise PoseFormatError("not finite", path, where)
    return values


def _as_matrices(world_from_cam: ArrayLike) -> F64:
    m = np.asarray(world_from_cam, dtype=np.float64)
    if m.ndim != 3 or m.shape[1:] != (4, 4) or not np.isfinite(m).all():
        raise PoseFormatError(f"expected finite (N, 4, 4) matrices, got shape {m.shape}",
                              field="world_from_cam")
    return m


def _checked_file(path: str | PathLike[str]) -> Path:
    p = Path(path)
    if not p.is_file():
        raise PoseFormatError("no such file", p)
    return p


# --------------------------------------------------------------------------- KITTI
def read_kitti(path: str | PathLike[str],
               times: str | PathLike[str] | None = None) -> PoseFile:
    """Read a KITTI pose file (12 numbers per line, the top 3×4 of ``world_from_cam``).

    Parameters
    ----------
    path: the pose file; empty lines and lines starting with ``#`` are skipped.
    times: optional KITTI ``times.txt`` (one time in seconds per line, as many as poses).

    Raises
    ------
    PoseFormatError
        Naming the file and line: a line without 12 numbers, a non-finite value, a block that
        is not a rotation, no poses, or a times file of another length.
    """
    p = _checked_file(path)
    rows: list[list[float]] = []
    where: list[str] = []
    for lineno, parts in _data_lines(p):
        if len(parts) != 12:
            raise PoseFormatError(
                f"expected 12 numbers (a 3x4 matrix row by row), got {len(parts)}",
                p, f"line {lineno}")
        rows.append(_numbers(parts, p, f"line {lineno}"))
        where.append(f"line {lineno}")
    if not rows:
        raise PoseFormatError("no poses in file", p)
    mats = np.tile(np.eye(4), (len(rows), 1, 1))
    mats[:, :3, :] = np.asarray(rows).reshape(-1, 3, 4)
    stamps = None if times is None else _read_times(times, len(rows))
    return PoseFile(_checked_rotations(mats, p, where), timestamps=stamps)


def _data_lines(path: Path) -> Iterator[tuple[int, list[str]]]:
    """(line number, whitespace-split fields) of each line of a text file that is neither blank
    nor a ``#`` comment."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if s and not s.startswith("#"):
                yield lineno, s.split()


def _read_times(path: str | PathLike[str], n: int) -> F64:
    """KITTI ``times.txt``: ``n`` times in seconds, one per line."""
    p = _checked_file(path)
    values: list[float] = []
    for lineno, parts in _data_lines(p):
        if len(parts) != 1:
            raise PoseFormatError(f"expected one time per line, got {len(parts)} fields",
                                  p, f"line {lineno}")
        values.extend(_numbers(parts, p, f"line {lineno}"))
    if len(values) != n:
        raise PoseFormatError(f"{len(values)} times for {n} poses", p)
    return np.asarray(values, dtype=np.float64)


def write_kitti(path: str | PathLike[str], world_from_cam: ArrayLike) -> None:
    """Write (N, 4, 4) ``world_from_cam`` as a KITTI pose file, atomically, full precision."""
    m = _as_matrices(world_from_cam)
    lines = [" ".join(repr(float(x)) for x in mat[:3].ravel()) for mat in m]
    atomic_write_text(os.fspath(path), "\n".join(lines) + "\n")


# --------------------------------------------------------------------------- COLMAP
def read_colmap_images(path: str | PathLike[str]) -> PoseFile:
    """Read COLMAP's ``images.txt``: ``world_from_cam`` and names, in ``IMAGE_ID`` order.

    Each image is a line ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` (``cam_from_world``,
    quaternion w first) followed by one line of 2-D points (ignored, may be empty), as COLMAP
    reads it. Lines starting with ``#`` are comments.

    Raises
    ------
    PoseFormatError
        Naming the file and line: too few fields, a value that is not a number, a quaternion
        far from unit norm, a repeated ``IMAGE_ID``, no images.
    """
    p = _checked_file(path)
    lines = p.read_text(encoding="utf-8", errors="replace").splitlines()
    ids: list[int] = []
    names: list[str] = []
    qt: list[list[float]] = []
    where: list[str] = []
    i = 0
    while i < len(lines):
        s = lines[i].strip()
        lineno = i + 1
        i += 1
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        if len(parts) < 10:
            raise PoseFormatError(
                f"expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {len(parts)} fields",
                p, f"line {lineno}")
        try:
            image_id = int(parts[0])
        except ValueError:
            raise PoseFormatError(f"IMAGE_ID {parts[0]!r} is not an integer", p,
                                  f"line {lineno}") from None
        if image_id in ids:
            raise PoseFormatError(f"IMAGE_ID {image_id} repeated", p, f"line {lineno}")
        ids.append(image_id)
        qt.append(_numbers(parts[1:8], p, f"line {lineno}"))
        names.append(" ".join(parts[9:]))
        where.append(f"line {lineno}")
        i += 1  # the POINTS2D line that belongs to this image
    if not ids:
        raise PoseFormatError("no images in file", p)
    arr = np.asarray(qt, dtype=np.float64)
    norms = np.linalg.norm(arr[:, :4], axis=1)
    bad = np.abs(norms - 1.0) > ROTATION_TOLERANCE
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise PoseFormatError(f"quaternion of norm {float(norms[k]):.6g}, expected 1", p,
                              where[k])
    cam_from_world = np.empty((len(arr), 7))
    cam_from_world[:, :3] = arr[:, 4:7]
    cam_from_world[:, 3:6] = arr[:, 1:4]  # qx qy qz
    cam_from_world[:, 6] = arr[:, 0]  # qw
    cam_from_world[:, 3:] /= norms[:, None]
    mats = np.linalg.inv(pose_to_matrix(cam_from_world).reshape(-1, 4, 4)).astype(np.float64)
    mats[:, 3] = [0.0, 0.0, 0.0, 1.0]
    order = np.argsort(ids, kind="stable")
    return PoseFile(mats[order], names=[names[k] for k in order])


def write_colmap_images(path: str | PathLike[str], world_from_cam: ArrayLike,
                        names: list[str], camera_id: int = 1) -> None:
    """Write an ``images.txt`` of N images (``IMAGE_ID`` 1..N, no 2-D points), atomically.

    Parameters
    ----------
    world_from_cam: (N, 4, 4) camera → world; written inverted, as COLMAP's ``cam_from_world``.
    names: (N,) image names, without white space.
    camera_id: the ``CAMERA_ID`` of every image.
    """
    m = _as_matrices(world_from_cam)
    if len(names) != len(m):
        raise PoseFormatError(f"{len(names)} names for {len(m)} poses", field="names")
    for name in names:
        if not name or any(c.isspace() for c in name):
            raise PoseFormatError(f"image name {name!r} is empty or has white space",
                                  field="names")
    cam_from_world = matrix_to_pose(np.linalg.inv(m))
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(m)}, mean observations per image: 0"]
    for k, (pose, name) in enumerate(zip(cam_from_world, names, strict=True), start=1):
        qwxyzt = [pose[6], pose[3], pose[4], pose[5], pose[0], pose[1], pose[2]]
        lines.append(" ".join([str(k), *(repr(float(x)) for x in qwxyzt), str(camera_id), name]))
        lines.append("")
    atomic_write_text(os.fspath(path), "\n".join(lines) + "\n")


# --------------------------------------------------------------------------- TUM and dispatch
def read_tum_poses(path: str | PathLike[str]) -> PoseFile:
    """A TUM file (:func:`bimcap.geometry.trajectory.read_tum`) as a :class:`PoseFile`."""
    traj = read_tum(path)
    return PoseFile(pose_to_matrix(traj.poses).reshape(-1, 4, 4), timestamps=traj.timestamps)


def read_poses(path: str | PathLike[str], fmt: PoseFormat | str,
               times: str | PathLike[str] | None = None) -> PoseFile:
    """Read a pose file of format ``fmt``; ``times`` is KITTI's optional ``times.txt``."""
    kind = PoseFormat(fmt)
    if times is not None and kind is not PoseFormat.KITTI:
        raise PoseFormatError(f"a times file goes with KITTI poses only, not {kind.value}",
                              times)
    if kind is PoseFormat.KITTI:
        return read_kitti(path, times)
    if kind is PoseFormat.COLMAP:
        return read_colmap_images(path)
    return read_tum_poses(path)


def write_poses(path: str | PathLike[str], poses: PoseFile, fmt: PoseFormat | str) -> None:
    """Write ``poses`` as ``fmt`` (TUM needs timestamps, COLMAP names)."""
    kind = PoseFormat(fmt)
    if kind is PoseFormat.KITTI:
        write_kitti(path, poses.world_from_cam)
    elif kind is PoseFormat.COLMAP:
        if poses.names is None:
            raise PoseFormatError("COLMAP images.txt needs image names", path, "names")
        write_colmap_images(path, poses.world_from_cam, poses.names)
    else:
        write_tum(path, poses.to_trajectory(), header="world_from_cam")
