"""What every generic importer shares (ROS bags, folders): options, the frame plan, trajectories.

An importer finds the images and clouds and their times, then calls :func:`plan_frames`:

1. each image is paired with the cloud nearest in time within ``tolerance_s``, each cloud used at
   most once (:func:`bimcap.dataset.pairing.pair_nearest`); frames are in image-time order;
2. with a trajectory (:class:`TrajectoryInput`: TUM, KITTI or COLMAP, camera or LiDAR poses),
   each frame gets its pose (:func:`match_poses`); frames without one are dropped;
3. every ``stride``-th frame is kept, at most ``max_frames``.

It then decodes only the planned images and clouds and writes them with
:func:`write_planned_frames`. A frame's timestamp is its image's; LiDAR-frame poses become
``world_from_cam = world_from_lidar ∘ cam_from_lidar⁻¹``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from collections.abc import Sequence as Seq
from dataclasses import dataclass, field
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.dataset.calib import Calibration
from bimcap.dataset.pairing import nearest, pair_nearest, unique_increasing
from bimcap.dataset.sequence import MANIFEST, LidarInfo, Sequence, SequenceError, SequenceWriter
from bimcap.geometry.pose_formats import PoseFile, PoseFormat, read_poses
from bimcap.geometry.poses import compose, invert

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

#: ``progress(stage, done, total)``: called while an import reads its input.
Progress = Callable[[str, int, int], None]


class DataImportError(SequenceError):
    """Input that an importer cannot turn into a sequence (names the file and the field)."""


class PoseSensor(str, Enum):
    """Which sensor a trajectory's poses describe."""

    LIDAR = "lidar"  # world_from_lidar (LiDAR SLAM: LIO-SAM, FAST-LIO ...; ConSLAM's GT)
    CAMERA = "camera"  # world_from_cam already (visual SLAM, COLMAP)


class PoseTime(str, Enum):
    """Which stamp of a frame its pose is looked up at: the image's (camera poses, most rigs) or
    the cloud's (LiDAR poses written per scan, e.g. ConSLAM's ground truth)."""

    IMAGE = "image"
    CLOUD = "cloud"


def lidar_to_camera_poses(world_from_lidar: ArrayLike, cam_from_lidar: ArrayLike) -> F64:
    """``world_from_cam = world_from_lidar ∘ cam_from_lidar⁻¹`` for (N, 7) or (7,) poses."""
    return compose(world_from_lidar, invert(cam_from_lidar))


@dataclass(frozen=True)
class TrajectoryInput:
    """A trajectory to attach to the imported frames.

    Attributes
    ----------
    path: the pose file.
    fmt: its format (TUM, KITTI, COLMAP ``images.txt``).
    times: KITTI ``times.txt`` (one time per pose), optional.
    sensor: whether the poses are the camera's or the LiDAR's.
    name: the sequence trajectory it becomes (``init``: poses to refine; ``gt``: ground truth).
    tolerance_s: largest |t_frame − t_pose| when matching by time, seconds.
    at: whether a frame's pose is looked up at its image's stamp or its cloud's.
    """

    path: str | PathLike[str]
    fmt: PoseFormat = PoseFormat.TUM
    times: str | PathLike[str] | None = None
    sensor: PoseSensor = PoseSensor.CAMERA
    name: str = "init"
    tolerance_s: float = 0.05
    at: PoseTime = PoseTime.IMAGE


@dataclass(frozen=True)
class ImportOptions:
    """Settings every generic importer takes.

    Attributes
    ----------
    tolerance_s: largest |t_image − t_cloud| of a pair, seconds.
    trajectory: poses to attach, or None.
    stride: keep every N-th frame.
    max_frames: keep at most this many frames.
    lidar_model: the LiDAR's name in the manifest, or its full :class:`LidarInfo`.
    ifc: IFC path to record in the manifest.
    overwrite: allow replacing an existing sequence at the output.
    png_compression: OpenCV PNG level 0-9 of the written images (None = OpenCV's default).
    progress: called as ``progress(stage, done, total)`` while reading (large bags).
    """

    tolerance_s: float = 0.05
    trajectory: TrajectoryInput | None = None
    stride: int = 1
    max_frames: int | None = None
    lidar_model: str | LidarInfo = "unknown"
    ifc: str | PathLike[str] | None = None
    overwrite: bool = False
    png_compression: int | None = None
    progress: Progress | None = None


def check_options(opts: ImportOptions, output: str | PathLike[str]) -> None:
    """Refuse bad settings, an unreadable trajectory path, or a sequence not to overwrite."""
    if not opts.tolerance_s >= 0:
        raise DataImportError(f"must be >= 0 s, got {opts.tolerance_s}", field="tolerance_s")
    if opts.stride < 1:
        raise DataImportError(f"must be >= 1, got {opts.stride}", field="stride")
    if opts.max_frames is not None and opts.max_frames < 1:
        raise DataImportError(f"must be >= 1, got {opts.max_frames}", field="max_frames")
    if not opts.lidar_model:
        raise DataImportError("must not be empty", field="lidar_model")
    if (Path(output) / MANIFEST).exists() and not opts.overwrite:
        raise DataImportError("already a sequence directory (use overwrite / --overwrite)", output)
    traj = opts.trajectory
    if traj is not None:
        if not Path(traj.path).is_file():
            raise DataImportError("no such file", traj.path, "trajectory")
        if not traj.name or not all(c.isalnum() or c in "_-." for c in traj.name):
            raise DataImportError(f"bad trajectory name {traj.name!r} (letters, digits, _ - .)",
                                  field="trajectory.name")
        if not traj.tolerance_s >= 0:
            raise DataImportError(f"must be >= 0 s, got {traj.tolerance_s}",
                               field="trajectory.tolerance_s")


@dataclass
class ImportResult:
    """What an import did.

    Attributes
    ----------
    sequence: the written sequence.
    n_images, n_clouds: images and clouds found.
    n_pairs: image/cloud pairs within the tolerance.
    n_without_pose: pairs dropped for lack of a pose in the trajectory (0 without one).
    n_frames: frames written.
    max_pair_dt_s: largest |t_image − t_cloud| among the written frames, seconds.
    max_pose_dt_s: largest |t_frame − t_pose| among the written frames (0 when matched by name
        or order), seconds.
    pose_match: how poses were matched (``timestamp``, ``name``, ``order``), or None.
    camera_source: where the camera came from.
    """

    sequence: Sequence
    n_images: int
    n_clouds: int
    n_pairs: int
    n_without_pose: int
    n_frames: int
    max_pair_dt_s: float
    max_pose_dt_s: float = 0.0
    pose_match: str | None = None
    camera_source: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "sequence": str(self.sequence.root),
            "n_images": self.n_images,
            "n_clouds": self.n_clouds,
            "n_pairs": self.n_pairs,
            "n_without_pose": self.n_without_pose,
            "n_frames": self.n_frames,
            "max_pair_dt_s": self.max_pair_dt_s,
            "max_pose_dt_s": self.max_pose_dt_s,
            "pose_match": self.pose_match,
            "camera_source": self.camera_source,
            **self.extra,
        }

    def summary_lines(self) -> list[str]:
        """Two lines for the command line."""
        seq = self.sequence
        first = (f"{seq.root}: {self.n_frames} frames from {self.n_images} images / "
                 f"{self.n_clouds} clouds ({self.n_pairs} pairs, max |dt| "
                 f"{self.max_pair_dt_s * 1e3:.1f} ms")
        if self.pose_match is not None:
            first += f"; {self.n_without_pose} without a pose, matched by {self.pose_match}"
        second = (f"  camera {seq.camera.width}x{seq.camera.height} from {self.camera_source}; "
                  f"trajectories: {', '.join(seq.poses) or 'none'}")
        return [first + ")", second]


# --------------------------------------------------------------------------- names and times
def stamp_from_name(name: str) -> float | None:
    """Seconds from a file name's stem: ``1650000000.25.png`` → 1650000000.25; an integer of
    13, 16 or 19 digits is read as ms, µs or ns (``1650000000250000.png``); else None."""
    stem = Path(name).name
    stem = stem[: -len(Path(stem).suffix)] if Path(stem).suffix[1:].isalpha() else stem
    if stem.isdigit():
        scale = {13: 1e-3, 16: 1e-6, 19: 1e-9}.get(len(stem), 1.0)
        return int(stem) * scale
    whole, dot, frac = stem.partition(".")
    if dot and whole.isdigit() and frac.isdigit():
        return float(stem)
    return None


def _format_range(t: F64) -> str:
    return f"{t.min():.6f}..{t.max():.6f} s" if len(t) else "none"


# --------------------------------------------------------------------------- poses
@dataclass(frozen=True)
class PoseMatch:
    """Poses matched to K frames: ``keep`` (K,) bool, the (K', 7) TUM-order poses of the kept
    frames (sensor of the trajectory), how they were matched and the largest time gap."""

    keep: NDArray[np.bool_]
    poses: F64
    how: str
    max_dt_s: float


def match_poses(
    poses: PoseFile,
    frame_times: F64,
    image_index: I64,
    image_names: Seq[str] | None,
    n_images: int,
    tolerance_s: float,
    path: str | PathLike[str],
) -> PoseMatch:
    """Match the poses of a pose file to K frames.

    Parameters
    ----------
    poses: the poses read.
    frame_times: (K,) the frames' times, seconds.
    image_index: (K,) each frame's index among all images (in time order).
    image_names: (I,) the names of all images (folder import), or None (bags).
    n_images: I, the number of images.
    tolerance_s: largest |t_frame − t_pose| when matching by time.
    path: the pose file, for errors.

    Matching, in this order: by timestamp (TUM, KITTI with ``times.txt``) to the nearest pose
    within ``tolerance_s``; by image name (COLMAP, when the images have names), else by the
    numbers in the names read as times (:func:`stamp_from_name`); by order (KITTI without
    times: pose i is image i, so there must be one pose per image).
    """
    k = len(frame_times)
    stamps = poses.timestamps
    how = "timestamp"
    if stamps is None and poses.names is not None:
        if image_names is not None:
            by_name = {Path(n).name: i for i, n in enumerate(poses.names)}
            pick = np.array([by_name.get(Path(image_names[i]).name, -1) for i in image_index],
                            dtype=np.int64)
            keep = pick >= 0
            if not keep.any():
                raise DataImportError(
                    f"no image name matches a name in the file (files e.g. "
                    f"{Path(image_names[0]).name!r}, poses e.g. {poses.names[0]!r})", path,
                    "names")
            return PoseMatch(keep, poses.poses()[pick[keep]], "name", 0.0)
        named = [stamp_from_name(n) for n in poses.names]
        if any(t is None for t in named):
            bad = poses.names[[t is None for t in named].index(True)]
            raise DataImportError(
                f"image name {bad!r} is not a timestamp, and bag frames have no names to match",
                path, "names")
        stamps = np.asarray(named, dtype=np.float64)
        how = "timestamp in name"
    if stamps is None:
        if len(poses) != n_images:
            raise DataImportError(
                f"{len(poses)} poses for {n_images} images: a pose file without timestamps "
                "needs one pose per image (or give its times)", path)
        return PoseMatch(np.ones(k, bool), poses.poses()[image_index], "order", 0.0)
    order = np.argsort(stamps, kind="stable")
    gi, gdt = nearest(frame_times, stamps[order])
    keep = gdt <= tolerance_s
    if not keep.any():
        raise DataImportError(
            f"no frame has a pose within {tolerance_s} s (frames {_format_range(frame_times)}, "
            f"poses {_format_range(stamps)})", path, "timestamps")
    return PoseMatch(keep, poses.poses()[order[gi[keep]]], how, float(gdt[keep].max()))


# --------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class FramePlan:
    """Which images and clouds become frames, in writing (time) order.

    image_index, cloud_index: (K,) indices into the image and cloud lists of each frame.
    world_from_cam: (K, 7) the frames' camera poses, or None without a trajectory.
    """

    image_index: I64
    cloud_index: I64
    world_from_cam: F64 | None
    n_pairs: int
    n_without_pose: int
    max_pair_dt_s: float
    max_pose_dt_s: float
    pose_match: str | None


def load_trajectory(opts: ImportOptions) -> PoseFile | None:
    """The poses of ``opts.trajectory`` (None without one): read before any expensive work,
    so that a malformed pose file fails at once."""
    traj = opts.trajectory
    return None if traj is None else read_poses(traj.path, traj.fmt, traj.times)


def plan_frames(
    t_images: F64,
    t_clouds: F64,
    opts: ImportOptions,
    source: str | PathLike[str],
    cam_from_lidar: F64,
    image_names: Seq[str] | None = None,
    poses: PoseFile | None = None,
) -> FramePlan:
    """Pair images and clouds, attach the trajectory of ``opts``, thin out (module docstring).

    Parameters
    ----------
    t_images: (I,) image times, seconds, in the order of the input.
    t_clouds: (C,) cloud times, seconds.
    opts: the settings.
    source: the bag or folder, for errors.
    cam_from_lidar: (7,) the extrinsic (to turn LiDAR poses into camera poses).
    image_names: (I,) image file names (folders), or None.
    poses: the trajectory's poses (:func:`load_trajectory`); read here when None.
    """
    ia, ib = pair_nearest(t_images, t_clouds, opts.tolerance_s)
    order = np.argsort(t_images[ia], kind="stable")
    ia, ib = ia[order], ib[order]
    fresh = unique_increasing(t_images[ia])  # equal image stamps: keep the first
    ia, ib = ia[fresh], ib[fresh]
    n_pairs = len(ia)
    if n_pairs == 0:
        raise DataImportError(
            f"no image/cloud pair within {opts.tolerance_s} s ({len(t_images)} images at "
            f"{_format_range(t_images)}, {len(t_clouds)} clouds at {_format_range(t_clouds)})",
            source, "timestamps")
    world_from_cam: F64 | None = None
    n_without = 0
    max_pose_dt = 0.0
    how: str | None = None
    traj = opts.trajectory
    if traj is not None:
        pose_file = poses if poses is not None else read_poses(traj.path, traj.fmt, traj.times)
        rank = np.empty(len(t_images), np.int64)  # image index → position in time order
        rank[np.argsort(t_images, kind="stable")] = np.arange(len(t_images))
        names_in_time = None
        if image_names is not None:
            names_in_time = [image_names[i] for i in np.argsort(t_images, kind="stable")]
        t_frames = t_clouds[ib] if traj.at is PoseTime.CLOUD else t_images[ia]
        match = match_poses(pose_file, t_frames, rank[ia], names_in_time, len(t_images),
                            traj.tolerance_s, traj.path)
        n_without = int((~match.keep).sum())
        ia, ib = ia[match.keep], ib[match.keep]
        world_from_cam = match.poses
        if traj.sensor is PoseSensor.LIDAR:
            world_from_cam = lidar_to_camera_poses(world_from_cam, cam_from_lidar)
        max_pose_dt, how = match.max_dt_s, match.how
    sel = np.arange(0, len(ia), opts.stride)[: opts.max_frames]
    ia, ib = ia[sel], ib[sel]
    return FramePlan(
        image_index=ia,
        cloud_index=ib,
        world_from_cam=None if world_from_cam is None else world_from_cam[sel],
        n_pairs=n_pairs,
        n_without_pose=n_without,
        max_pair_dt_s=float(np.abs(t_images[ia] - t_clouds[ib]).max()),
        max_pose_dt_s=max_pose_dt,
        pose_match=how,
    )


# --------------------------------------------------------------------------- writing
def write_planned_frames(
    output: str | PathLike[str],
    calib: Calibration,
    frames: Iterator[tuple[int, NDArray[np.uint8], NDArray[np.float32]]],
    plan: FramePlan,
    t_images: F64,
    opts: ImportOptions,
    source_record: dict[str, Any],
    source: str | PathLike[str],
) -> Sequence:
    """Write the frames ``frames`` yields as ``(k, rgb (H, W, 3) uint8, cloud (M, 4) float32)``
    in plan order k, then the trajectory, and close the sequence.

    Raises
    ------
    DataImportError
        When an image's size differs from the camera's, or a planned frame never came.
    """
    if calib.cam_from_lidar is None:
        raise DataImportError("no LiDAR extrinsic (cam_from_lidar)", source, "calibration")
    cam = calib.camera
    writer = SequenceWriter(output, cam, calib.cam_from_lidar,
                            lidar=(opts.lidar_model if isinstance(opts.lidar_model, LidarInfo)
                                   else LidarInfo(model=opts.lidar_model)), ifc=opts.ifc,
                            source=source_record, overwrite=opts.overwrite,
                            png_compression=opts.png_compression)
    n = len(plan.image_index)
    for k, image, cloud in frames:
        h, w = image.shape[:2]
        if (w, h) != (cam.width, cam.height):
            raise DataImportError(
                f"image {int(plan.image_index[k])} is {w}x{h} but the camera is "
                f"{cam.width}x{cam.height}", source, "camera")
        writer.add_frame(float(t_images[plan.image_index[k]]), image, cloud)
        if opts.progress is not None:
            opts.progress("write", len(writer.frames), n)
    if len(writer.frames) != n:
        raise DataImportError(f"only {len(writer.frames)} of {n} frames could be assembled", source)
    if plan.world_from_cam is not None and opts.trajectory is not None:
        writer.add_trajectory(opts.trajectory.name, plan.world_from_cam)
    return writer.close()


def trajectory_record(traj: TrajectoryInput | None) -> dict[str, Any] | None:
    """The manifest's record of a trajectory input."""
    if traj is None:
        return None
    return {"path": str(traj.path), "format": PoseFormat(traj.fmt).value,
            "times": None if traj.times is None else str(traj.times),
            "sensor": PoseSensor(traj.sensor).value, "name": traj.name,
            "tolerance_s": traj.tolerance_s, "at": PoseTime(traj.at).value}
