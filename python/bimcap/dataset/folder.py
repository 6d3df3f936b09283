"""Import a folder of images and point clouds (or depth images) as a sequence directory.

Layout (sub-folder names are found automatically, or given)::

    DIR/images/   *.png *.jpg *.jpeg     (also image/, rgb/, cam0/; or DIR itself)
    DIR/clouds/   *.pcd *.ply *.bin      (also cloud/, lidar/, velodyne/, points/; or DIR itself)
    DIR/depth/    *.png                  (RGB-D instead of clouds: --depth-dir, --depth-scale)
    DIR/timestamps.txt                   (optional)

Clouds: PCD and PLY through Open3D (``x y z`` and, when present, ``intensity``); KITTI ``.bin``
(little-endian float32 ``x y z intensity``). They are taken as they are, in the LiDAR frame.

Depth images (RGB-D): 16-bit (or 8-bit) PNGs registered to the RGB camera, ``depth_m = value /
depth_scale`` (1000 for millimetres, 5000 for the TUM RGB-D benchmark), 0 = no depth. Each is
back-projected through the (distorted) camera into a cloud in the camera frame
(:func:`depth_to_cloud`), so the extrinsic is the identity.

Times, in this order:

- ``timestamps.txt`` with two columns ``NAME SECONDS`` (NAME the file's path relative to DIR, or
  its name alone), one line per image and cloud;
- ``timestamps.txt`` with one column: the i-th time belongs to the i-th image and the i-th cloud
  (sorted by name; KITTI's ``times.txt``);
- no file: the file names are the times (:func:`bimcap.dataset.importing.stamp_from_name`:
  ``1650000000.25.png``, ``1650000000250000.pcd`` in µs, or ``000042.png`` = 42 s, which pairs
  KITTI's equally numbered images and scans).

Images and clouds are paired by time (:func:`bimcap.dataset.importing.plan_frames`).
"""

from __future__ import annotations

from collections.abc import Iterator
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bimcap.dataset.calib import Calibration, read_calibration
from bimcap.dataset.importing import (
    DataImportError,
    FramePlan,
    ImportOptions,
    ImportResult,
    check_options,
    load_trajectory,
    plan_frames,
    stamp_from_name,
    trajectory_record,
    write_planned_frames,
)
from bimcap.geometry.camera import Camera

F64 = NDArray[np.float64]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
CLOUD_SUFFIXES = (".pcd", ".ply", ".bin")
IMAGE_DIRS = ("images", "image", "rgb", "cam0")
CLOUD_DIRS = ("clouds", "cloud", "lidar", "velodyne", "points")
DEPTH_DIRS = ("depth",)
TIMESTAMPS = "timestamps.txt"


class FolderError(DataImportError):
    """A folder that cannot be imported (names the folder or file and the field)."""


# --------------------------------------------------------------------------- readers
def read_cloud(path: str | PathLike[str]) -> NDArray[np.float32]:
    """A point cloud file as (M, 4) float32 ``x y z intensity`` (intensity 0 where absent).

    ``.bin``: KITTI, little-endian float32 ``x y z intensity``; ``.pcd`` / ``.ply``: Open3D.
    Points with a non-finite coordinate are dropped.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".bin":
        data = p.read_bytes()
        if len(data) % 16:
            raise FolderError(f"{len(data)} bytes is not a multiple of 16 (KITTI .bin: float32 "
                              "x y z intensity)", p)
        out = np.frombuffer(data, dtype="<f4").reshape(-1, 4).astype(np.float32)
    elif suffix in (".pcd", ".ply"):
        import open3d as o3d

        if not p.is_file():
            raise FolderError("no such file", p)
        cloud = o3d.t.io.read_point_cloud(str(p))
        if "positions" not in cloud.point:
            raise FolderError("cannot read a point cloud (no points, or not a PCD/PLY file)", p)
        xyz = cloud.point.positions.numpy().reshape(-1, 3)
        out = np.zeros((len(xyz), 4), np.float32)
        out[:, :3] = xyz
        if "intensity" in cloud.point:
            out[:, 3] = cloud.point["intensity"].numpy().reshape(-1)[: len(xyz)]
    else:
        raise FolderError(f"unknown point cloud type {p.suffix!r} ({', '.join(CLOUD_SUFFIXES)})",
                          p)
    return out[np.isfinite(out[:, :3]).all(axis=1)]


def read_image(path: str | PathLike[str]) -> NDArray[np.uint8]:
    """An image file as (H, W, 3) uint8 RGB (grey images repeated into three channels)."""
    import cv2

    p = Path(path)
    bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FolderError("cannot read the image", p)
    return np.ascontiguousarray(bgr[:, :, ::-1])


def depth_to_cloud(depth: NDArray[np.generic], camera: Camera,
                   depth_scale: float) -> NDArray[np.float32]:
    """Back-project a depth image into a cloud in the camera frame.

    Parameters
    ----------
    depth: (H, W) raw depth values (uint16, uint8 or float), registered to ``camera``'s raw
        (distorted) image; 0 = no depth.
    camera: the camera (size must match).
    depth_scale: raw units per metre: ``z = depth / depth_scale`` (z-depth along the optical
        axis, as RGB-D sensors give it).

    Returns
    -------
    (M, 4) float32 ``x y z 0`` in metres, camera frame, one point per pixel with depth.
    """
    if depth.shape != (camera.height, camera.width):
        raise FolderError(f"depth image is {depth.shape[1]}x{depth.shape[0]} but the camera is "
                          f"{camera.width}x{camera.height}", field="depth")
    z = depth.astype(np.float64).reshape(-1) / depth_scale
    ok = np.isfinite(z) & (z > 0)
    uv = camera.pixel_grid()[ok]
    out = np.zeros((int(ok.sum()), 4), np.float32)
    out[:, :3] = camera.backproject(uv, z[ok])
    return out


def read_depth(path: str | PathLike[str]) -> NDArray[np.generic]:
    """A single-channel depth PNG, unchanged (uint16 or uint8)."""
    import cv2

    p = Path(path)
    depth = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise FolderError("cannot read the depth image", p)
    if depth.ndim != 2:
        raise FolderError(f"expected a single-channel depth image, got shape {depth.shape}", p)
    return depth


# --------------------------------------------------------------------------- finding files
def _files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    return sorted(f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in suffixes)


def _sub(root: Path, given: str | PathLike[str] | None, candidates: tuple[str, ...],
         suffixes: tuple[str, ...], what: str) -> Path:
    """The folder holding the ``what`` files: ``given`` (relative to root), else the first
    candidate sub-folder with such files, else root itself."""
    if given is not None:
        p = Path(given)
        p = p if p.is_absolute() else root / p
        if not p.is_dir():
            raise FolderError("no such directory", p, what)
        return p
    for name in candidates:
        if (root / name).is_dir() and _files(root / name, suffixes):
            return root / name
    return root


def _read_timestamps(path: Path) -> dict[str, float] | list[float]:
    """``timestamps.txt``: ``{name: seconds}`` (two columns) or ``[seconds]`` (one column)."""
    named: dict[str, float] = {}
    plain: list[float] = []
    for lineno, line in enumerate(path.read_text(encoding="utf-8", errors="replace")
                                  .splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        if len(parts) not in (1, 2) or (plain and len(parts) == 2) or (named and len(parts) == 1):
            raise FolderError("expected 'NAME SECONDS' on every line, or 'SECONDS' on every "
                              f"line; got {len(parts)} fields", path, f"line {lineno}")
        try:
            t = float(parts[-1])
        except ValueError:
            raise FolderError(f"{parts[-1]!r} is not a number of seconds", path,
                              f"line {lineno}") from None
        if len(parts) == 2:
            named[parts[0]] = t
        else:
            plain.append(t)
    if not named and not plain:
        raise FolderError("no timestamps in file", path)
    return named if named else plain


def _times(files: Seq[Path], root: Path, stamps: dict[str, float] | list[float] | None,
           stamps_path: Path, what: str) -> F64:
    """(N,) seconds of ``files`` from the timestamps file or their names."""
    if isinstance(stamps, list):
        if len(stamps) != len(files):
            raise FolderError(f"{len(stamps)} times for {len(files)} {what}", stamps_path)
        return np.asarray(stamps, dtype=np.float64)
    out = np.empty(len(files))
    for i, f in enumerate(files):
        if stamps is not None:
            rel = f.relative_to(root).as_posix() if f.is_relative_to(root) else f.name
            t = stamps.get(rel, stamps.get(f.name))
            if t is None:
                raise FolderError(f"no line for {rel}", stamps_path)
        else:
            t = stamp_from_name(f.name)
            if t is None:
                raise FolderError(f"the name is not a time, and there is no {TIMESTAMPS}", f)
        out[i] = t
    return out


@dataclass(frozen=True)
class _Inputs:
    """The image and cloud (or depth) files of a folder, sorted by name, and their times (s)."""

    image_dir: Path
    cloud_dir: Path
    images: list[Path]
    clouds: list[Path]
    t_images: F64
    t_clouds: F64
    times_from: str


def _find_inputs(root: Path, images: str | PathLike[str] | None,
                 clouds: str | PathLike[str] | None, depth: str | PathLike[str] | None,
                 timestamps: str | PathLike[str] | None) -> _Inputs:
    """Find the files (refusing a folder without images or clouds) and read their times."""
    rgbd = depth is not None
    img_dir = _sub(root, images, IMAGE_DIRS, IMAGE_SUFFIXES, "images")
    cloud_dir = (_sub(root, depth, DEPTH_DIRS, (".png",), "depth") if rgbd
                 else _sub(root, clouds, CLOUD_DIRS, CLOUD_SUFFIXES, "clouds"))
    if img_dir == cloud_dir and rgbd:
        raise FolderError("the depth images must be in their own folder", cloud_dir, "depth")
    img_files = _files(img_dir, IMAGE_SUFFIXES)
    cloud_files = _files(cloud_dir, (".png",) if rgbd else CLOUD_SUFFIXES)
    if not img_files:
        raise FolderError(f"no images ({', '.join(IMAGE_SUFFIXES)})", img_dir, "images")
    if not cloud_files:
        kind = "depth images (.png)" if rgbd else f"point clouds ({', '.join(CLOUD_SUFFIXES)})"
        raise FolderError(f"no {kind}", cloud_dir, "depth" if rgbd else "clouds")
    stamps_path = Path(timestamps) if timestamps is not None else root / TIMESTAMPS
    if timestamps is not None and not stamps_path.is_file():
        raise FolderError("no such file", stamps_path, "timestamps")
    stamps = _read_timestamps(stamps_path) if stamps_path.is_file() else None
    ti = _times(img_files, root, stamps, stamps_path, "images")
    tc = _times(cloud_files, root, stamps, stamps_path, "depth images" if rgbd else "clouds")
    return _Inputs(img_dir, cloud_dir, img_files, cloud_files, ti, tc,
                   str(stamps_path) if stamps is not None else "file names")


# --------------------------------------------------------------------------- the importer
def import_folder(
    folder: str | PathLike[str],
    output: str | PathLike[str],
    calib: str | PathLike[str],
    *,
    calib_camera: str = "cam0",
    lidar_extrinsic: str | PathLike[str] | None = None,
    images: str | PathLike[str] | None = None,
    clouds: str | PathLike[str] | None = None,
    depth: str | PathLike[str] | None = None,
    depth_scale: float = 1000.0,
    timestamps: str | PathLike[str] | None = None,
    options: ImportOptions | None = None,
) -> ImportResult:
    """Import a folder of images and clouds (or depth images) as a sequence (module docstring).

    Parameters
    ----------
    folder: the folder.
    output: the sequence directory to write.
    calib: the camera calibration (ROS camera_info YAML or Kalibr camchain).
    calib_camera: which camera of a Kalibr camchain.
    lidar_extrinsic: an extrinsic YAML or ``"identity"``; needed with clouds unless ``calib``
        carries one; with ``depth`` it must be None or ``"identity"``.
    images, clouds, depth: sub-folders (relative to ``folder``, or absolute); None finds them.
        ``depth`` turns on RGB-D: depth images instead of clouds.
    depth_scale: raw depth units per metre (1000: millimetres).
    timestamps: a timestamps file (default ``folder/timestamps.txt`` when present).
    options: :class:`~bimcap.dataset.importing.ImportOptions`.

    Raises
    ------
    FolderError
        No images or clouds, an unreadable file, times missing, no pair within the tolerance.
    bimcap.dataset.calib.CalibrationError, bimcap.geometry.pose_formats.PoseFormatError
        A bad calibration or trajectory file (naming the file and the field).
    """
    opts = options or ImportOptions()
    root = Path(folder)
    if not root.is_dir():
        raise FolderError("no such directory", root)
    check_options(opts, output)
    rgbd = depth is not None
    if rgbd and not depth_scale > 0:
        raise FolderError(f"must be > 0, got {depth_scale}", field="depth_scale")
    if rgbd and lidar_extrinsic not in (None, "identity"):
        raise FolderError("depth clouds are in the camera frame: no extrinsic to give",
                          lidar_extrinsic, "lidar_extrinsic")
    poses = load_trajectory(opts)
    cal = read_calibration(calib, camera=calib_camera,
                           lidar_extrinsic="identity" if rgbd else lidar_extrinsic)
    if cal.cam_from_lidar is None:
        raise FolderError("no LiDAR extrinsic: give lidar_extrinsic / --lidar-extrinsic (a YAML "
                          "with T_cam_lidar, or 'identity' when the clouds are in the camera "
                          "frame)", calib, "lidar_extrinsic")
    found = _find_inputs(root, images, clouds, depth, timestamps)
    img_files, cloud_files, ti, tc = found.images, found.clouds, found.t_images, found.t_clouds
    img_dir, cloud_dir = found.image_dir, found.cloud_dir
    plan = plan_frames(ti, tc, opts, root, cal.cam_from_lidar,
                       image_names=[f.name for f in img_files], poses=poses)
    record = {
        "importer": "bimcap.dataset.folder",
        "folder": str(root.resolve()),
        "images": str(img_dir.resolve()),
        "clouds" if not rgbd else "depth": str(cloud_dir.resolve()),
        "depth_scale": depth_scale if rgbd else None,
        "calibration": cal.source,
        "timestamps": found.times_from,
        "tolerance_s": opts.tolerance_s,
        "stride": opts.stride,
        "trajectory": trajectory_record(opts.trajectory),
    }
    frames = _frames(img_files, cloud_files, plan, cal, depth_scale if rgbd else None)
    seq = write_planned_frames(output, cal, frames, plan, ti, opts, record, root)
    return ImportResult(
        sequence=seq,
        n_images=len(img_files),
        n_clouds=len(cloud_files),
        n_pairs=plan.n_pairs,
        n_without_pose=plan.n_without_pose,
        n_frames=len(seq),
        max_pair_dt_s=plan.max_pair_dt_s,
        max_pose_dt_s=plan.max_pose_dt_s,
        pose_match=plan.pose_match,
        camera_source=f"{cal.source.get('format')} file {calib}",
        extra={"images": str(img_dir), "clouds": str(cloud_dir), "rgbd": rgbd},
    )


def _frames(img_files: Seq[Path], cloud_files: Seq[Path], plan: FramePlan, cal: Calibration,
            depth_scale: float | None) -> Iterator[tuple[int, NDArray[np.uint8],
                                                          NDArray[np.float32]]]:
    """The planned frames ``(k, rgb, cloud)``, read one at a time."""
    for k, (i, j) in enumerate(zip(plan.image_index, plan.cloud_index, strict=True)):
        image = read_image(img_files[i])
        if depth_scale is None:
            cloud = read_cloud(cloud_files[j])
        else:
            try:
                cloud = depth_to_cloud(read_depth(cloud_files[j]), cal.camera, depth_scale)
            except FolderError as exc:
                raise FolderError(exc.message, cloud_files[j], exc.field) from None
        yield k, image, cloud
