"""Import a ConSLAM recording (ROS1 bag + ground-truth poses) into a sequence directory.

ConSLAM (Trzeciak et al.) ships ROS1 bags with the topics

- ``pp_rgb/synced2points``: ``sensor_msgs/Image``, rgb8, 2064×1544, raw (distorted);
- ``pp_points/synced2rgb``: ``sensor_msgs/PointCloud2`` from a VLP-16, fields x/y/z/intensity;
- ``pp_rgb/camera_info``: ``sensor_msgs/CameraInfo`` (plumb_bob),

(with or without a leading ``/``) and ground-truth LiDAR poses (``world_from_lidar``) as one
4×4 text file per scan, named by the scan's timestamp in microseconds; the BIM-frame poses of
sessions 2–5 come as TUM files. The bag is read with ``rosbags`` (no ROS install); the
messages are decoded by :mod:`bimcap.dataset.ros` and paired by :mod:`bimcap.dataset.pairing`,
which the generic importers (:mod:`bimcap.dataset.bag`, :mod:`bimcap.dataset.folder`) share.

What the importer does: it is the generic bag importer (:func:`bimcap.dataset.bag.import_bag`'s
passes and :func:`bimcap.dataset.importing.plan_frames`) with ConSLAM's topics and calibration:

1. a first pass reads only the header stamps of images and scans (and the first camera_info);
2. each image is paired with the scan nearest in time, if within ``tolerance_s``; a scan is
   used at most once;
3. with ground truth, each pair gets the ground-truth pose nearest to the *scan's* stamp within
   ``gt_tolerance_s`` (pairs without one are dropped), converted to the camera::

       world_from_cam = world_from_lidar ∘ lidar_from_cam = world_from_lidar ∘ cam_from_lidar⁻¹

   (``gt_frame=GtFrame.CAMERA`` takes the poses as camera poses already);
4. a second pass decodes the chosen messages and writes frames with
   :class:`~bimcap.dataset.SequenceWriter`, timestamped by the image's header stamp.

The camera comes from the first ``camera_info`` message when it has a plumb_bob calibration,
else ConSLAM's published calibration (:data:`CONSLAM_CAMERA`, scaled if the images are smaller by
the same factor in both axes). The LiDAR→camera extrinsic is ConSLAM's
(:data:`CONSLAM_CAM_FROM_LIDAR`) unless another is given.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass, field, fields, replace
from itertools import chain
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.dataset.bag import (
    BagTopics,
    find_topics,
    list_topics,
    open_reader,
    read_stamps,
    reader_errors,
    stream_frames,
)
from bimcap.dataset.calib import Calibration
from bimcap.dataset.importing import (
    DataImportError,
    ImportOptions,
    PoseSensor,
    PoseTime,
    TrajectoryInput,
    plan_frames,
    write_planned_frames,
)
from bimcap.dataset.pairing import pair_nearest  # noqa: F401  (re-exported, tests use it)
from bimcap.dataset.ros import (  # noqa: F401  (decode_pointcloud re-exported)
    camera_from_info_or_reason,
    decode_pointcloud,
    norm_topic,
)
from bimcap.dataset.sequence import MANIFEST, VLP16, Sequence, SequenceError
from bimcap.geometry.camera import Camera
from bimcap.geometry.pose_formats import PoseFile
from bimcap.geometry.poses import matrix_to_pose, pose_to_matrix
from bimcap.geometry.trajectory import Trajectory, TrajectoryError, read_tum
from bimcap.progress import StageProgress

F64 = NDArray[np.float64]
#: A frame of the bag's second pass: (k, rgb (H, W, 3) uint8, cloud (M, 4) float32).
_Frame = tuple[int, NDArray[np.uint8], NDArray[np.float32]]
_log = logging.getLogger(__name__)

TOPIC_IMAGE = "pp_rgb/synced2points"
TOPIC_POINTS = "pp_points/synced2rgb"
TOPIC_CAMERA_INFO = "pp_rgb/camera_info"

#: ConSLAM's RGB camera: 2064×1544, plumb_bob.
CONSLAM_CAMERA = Camera(
    2064,
    1544,
    2351.85909,
    2353.56734,
    1017.24032,
    788.70774,
    (-0.054366, 0.118389, 0.001781, -0.003908, 0.0),
)

#: ConSLAM's LiDAR→camera extrinsic as published, (3, 4) ``[R | t]`` mapping LiDAR points into the
#: RGB optical frame.
CONSLAM_CAM_FROM_LIDAR_MATRIX: F64 = np.array(
    [
        [0.05758374, -0.99833897, -0.00184651, -0.0081025],
        [-0.0017837, 0.0017467, -0.99999688, -0.0631593],
        [0.99833909, 0.05758685, -0.00168015, -0.0215235],
    ]
)

#: The same as a TUM-order pose; the rotation is the nearest orthonormal matrix to the published
#: one (which is orthonormal to ~1e-8).
CONSLAM_CAM_FROM_LIDAR: F64 = matrix_to_pose(CONSLAM_CAM_FROM_LIDAR_MATRIX)


class ConslamError(SequenceError):
    """A ConSLAM bag or ground-truth input that cannot be imported (names file and field)."""


#: Which sensor the ground-truth poses describe: ``LIDAR`` (ConSLAM's per-scan 4×4 files and
#: SLAM2REF TUM output, ``world_from_lidar``) or ``CAMERA`` (``world_from_cam`` already).
GtFrame = PoseSensor


@dataclass
class ConslamImportResult:
    """What an import did.

    Attributes
    ----------
    sequence: the written sequence.
    n_images, n_scans: messages found on the image and point-cloud topics.
    n_pairs: image/scan pairs within the tolerance.
    n_without_gt: pairs dropped for lack of a ground-truth pose.
    n_frames: frames written.
    camera_source: ``"camera_info"`` or ``"conslam_default"``.
    max_pair_dt_s: largest |t_image − t_scan| among the written frames, seconds.
    max_gt_dt_s: largest |t_scan − t_gt| among the written frames, seconds (0 without GT).
    """

    sequence: Sequence
    n_images: int
    n_scans: int
    n_pairs: int
    n_without_gt: int
    n_frames: int
    camera_source: str
    max_pair_dt_s: float
    max_gt_dt_s: float = 0.0
    topics: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "sequence": str(self.sequence.root),
            "n_images": self.n_images,
            "n_scans": self.n_scans,
            "n_pairs": self.n_pairs,
            "n_without_gt": self.n_without_gt,
            "n_frames": self.n_frames,
            "camera_source": self.camera_source,
            "max_pair_dt_s": self.max_pair_dt_s,
            "max_gt_dt_s": self.max_gt_dt_s,
            "topics": dict(self.topics),
        }


# --------------------------------------------------------------------------- ground truth
def _gt_file_stamp(f: Path) -> float | None:
    """Seconds from ``<microseconds>.txt`` (or ``<seconds>.<fraction>.txt``), else None."""
    stem = f.stem
    if stem.isdigit():
        return int(stem) * 1e-6
    whole, dot, frac = stem.partition(".")
    if dot and whole.isdigit() and frac.isdigit():
        return float(stem)
    return None


def read_gt_folder(path: str | PathLike[str]) -> Trajectory:
    """Read ConSLAM ground truth: one text file per scan, ``<microseconds>.txt``, a 4×4 matrix.

    Returns the ``world_from_lidar`` poses, timestamps in seconds, sorted by time. A file may
    hold 16 numbers (4×4) or 12 (the top 3×4); the last row of a 4×4 must be ``0 0 0 1``.
    A name ``<digits>.<digits>.txt`` is read as seconds instead. Other files are ignored. The
    rotation is orthonormalised (nearest rotation) after checking it is one to 1e-3.
    """
    root = Path(path)
    if not root.is_dir():
        raise ConslamError("not a directory", root)
    stamps: list[float] = []
    mats: list[F64] = []
    for f in sorted(root.iterdir()):
        stamp = _gt_file_stamp(f)
        if stamp is None or not f.is_file():
            continue
        try:
            vals = np.array(
                f.read_text(encoding="utf-8").replace(",", " ").split(), dtype=np.float64
            )
        except ValueError as exc:
            raise ConslamError(f"not a matrix of numbers ({exc})", f) from None
        if vals.size not in (12, 16):
            raise ConslamError(f"expected a 4x4 (or 3x4) matrix, got {vals.size} numbers", f)
        m = np.eye(4)
        m[: vals.size // 4] = vals.reshape(-1, 4)
        if not np.isfinite(m).all():
            raise ConslamError("matrix is not finite", f)
        if vals.size == 16 and not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
            raise ConslamError(f"last row must be 0 0 0 1, got {m[3].tolist()}", f)
        r = m[:3, :3]
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-3) or np.linalg.det(r) < 0:
            raise ConslamError("the 3x3 block is not a rotation", f)
        stamps.append(stamp)
        mats.append(m)
    if not mats:
        raise ConslamError("no ground-truth files named <microseconds>.txt", root)
    order = np.argsort(stamps, kind="stable")
    try:
        return Trajectory(np.asarray(stamps)[order], matrix_to_pose(np.asarray(mats)[order]))
    except TrajectoryError as exc:
        raise ConslamError(str(exc), root) from None


def read_gt(path: str | PathLike[str]) -> Trajectory:
    """Ground truth from a folder of 4×4 text files (:func:`read_gt_folder`) or a TUM file."""
    p = Path(path)
    if p.is_dir():
        return read_gt_folder(p)
    try:
        return read_tum(p)
    except TrajectoryError as exc:
        raise ConslamError(str(exc), p, "gt") from None


# --------------------------------------------------------------------------- the importer
@dataclass(frozen=True)
class ConslamImportOptions:
    """Settings of :func:`import_conslam`.

    Attributes
    ----------
    gt_frame: whether the ground truth holds LiDAR poses (ConSLAM's; converted) or camera poses.
    tolerance_s: largest |t_image − t_scan| of a pair, seconds.
    gt_tolerance_s: largest |t_scan − t_gt| for a frame's ground truth, seconds.
    cam_from_lidar: (7,) extrinsic, default :data:`CONSLAM_CAM_FROM_LIDAR`.
    camera: force this camera (else camera_info, else ConSLAM's calibration).
    ifc: IFC path to record in the manifest.
    stride: keep every ``stride``-th frame (after pairing and GT matching).
    max_frames: keep at most this many frames.
    overwrite: allow replacing an existing sequence at the output.
    png_compression: OpenCV PNG level 0-9 of the written images (None = OpenCV's default);
        at 2064×1544, PNG encoding dominates the import time.
    """

    gt_frame: GtFrame = GtFrame.LIDAR
    tolerance_s: float = 0.05
    gt_tolerance_s: float = 0.05
    cam_from_lidar: ArrayLike | None = None
    camera: Camera | None = None
    ifc: str | PathLike[str] | None = None
    stride: int = 1
    max_frames: int | None = None
    overwrite: bool = False
    png_compression: int | None = None


def _import_options(options: ConslamImportOptions | None,
                    overrides: dict[str, Any]) -> ConslamImportOptions:
    """``options`` (default :class:`ConslamImportOptions`) with the keyword arguments given
    to :func:`import_conslam` the old way replacing its fields."""
    names = {f.name for f in fields(ConslamImportOptions)}
    for key in overrides:
        if key not in names:
            raise TypeError(f"import_conslam() got an unexpected keyword argument {key!r}")
    return replace(options or ConslamImportOptions(), **overrides)


def _check_import(bag_path: Path, output: str | PathLike[str],
                  opts: ConslamImportOptions) -> None:
    """Refuse a missing bag, a bad stride or frame limit, or a sequence not to overwrite."""
    if not bag_path.is_file():
        raise ConslamError("no such bag file", bag_path)
    if opts.stride < 1:
        raise ConslamError(f"stride must be >= 1, got {opts.stride}", field="stride")
    if opts.max_frames is not None and opts.max_frames < 1:
        raise ConslamError(f"max_frames must be >= 1, got {opts.max_frames}", field="max_frames")
    if (Path(output) / MANIFEST).exists() and not opts.overwrite:
        raise ConslamError("already a sequence directory (use overwrite / --overwrite)", output)


def _load_gt(
    gt: str | PathLike[str] | Trajectory | None,
) -> tuple[Trajectory | None, str | None]:
    """The ground-truth trajectory (None without) and how the manifest names it."""
    if isinstance(gt, Trajectory):
        return gt, "<in memory>"
    if gt is not None:
        return read_gt(gt), str(gt)
    return None, None


def _provenance(bag_path: Path, gt_label: str | None, has_gt: bool,
                opts: ConslamImportOptions, topics: dict[str, str],
                camera_source: str) -> dict[str, Any]:
    """The manifest's ``source`` record of an import."""
    return {
        "importer": "bimcap.dataset.conslam",
        "bag": str(bag_path.resolve()),
        "gt": gt_label,
        "gt_frame": opts.gt_frame.value if has_gt else None,
        "topics": [topics["image"], topics["cloud"], topics["camera_info"]],
        "tolerance_s": opts.tolerance_s,
        "gt_tolerance_s": opts.gt_tolerance_s,
        "stride": opts.stride,
        "timestamps": "image header stamps (bag time where zero)",
        "camera_source": camera_source,
    }


def _gt_input(gt: Trajectory | None, gt_label: str | None,
              opts: ConslamImportOptions) -> tuple[TrajectoryInput | None, PoseFile | None]:
    """The ground truth as the generic importers' trajectory input: looked up at the *scan's*
    stamp (ConSLAM's poses are per scan), stored as the sequence's ``gt``."""
    if gt is None:
        return None, None
    traj = TrajectoryInput(path=gt_label or "<in memory>", sensor=opts.gt_frame, name="gt",
                           tolerance_s=opts.gt_tolerance_s, at=PoseTime.CLOUD)
    return traj, PoseFile(pose_to_matrix(gt.poses), gt.timestamps)


def _first_then_rest(frames: Iterator[_Frame], n: int,
                     bag: Path) -> tuple[_Frame, Iterator[_Frame]]:
    """The first frame of ``frames`` (to size the camera on) and an iterator over all of them."""
    first = next(frames, None)
    if first is None:
        raise ConslamError(f"only 0 of {n} frames could be assembled", bag)
    return first, chain([first], frames)


def import_conslam(
    bag: str | PathLike[str],
    output: str | PathLike[str],
    gt: str | PathLike[str] | Trajectory | None = None,
    *,
    options: ConslamImportOptions | None = None,
    **legacy_options: Any,
) -> ConslamImportResult:
    """Import a ConSLAM ROS1 bag (and its ground truth) as a sequence directory.

    The generic bag importer (:mod:`bimcap.dataset.bag`) with ConSLAM's topics, its published
    extrinsic and camera, and its ground truth looked up at the scans' stamps.

    Parameters
    ----------
    bag: the ``.bag`` file.
    output: the sequence directory to write.
    gt: ground truth — a folder of ``<microseconds>.txt`` 4×4 files, a TUM file, or a
        :class:`Trajectory`; None for no ground truth.
    options: :class:`ConslamImportOptions` (gt_frame, tolerance_s, gt_tolerance_s,
        cam_from_lidar, camera, ifc, stride, max_frames, overwrite, png_compression).
    legacy_options: the same settings as keyword arguments (``stride=2``), as before the
        options class; they replace the fields of ``options``.

    Raises
    ------
    ConslamError
        If the bag lacks a topic, no pair or no GT match is found, a message cannot be decoded,
        or the camera does not fit the images.
    TypeError
        On a keyword argument that is not a field of :class:`ConslamImportOptions`.
    """
    _require_rosbags()
    opts = _import_options(options, legacy_options)
    bag_path = Path(bag)
    _check_import(bag_path, output, opts)
    gt_traj, gt_label = _load_gt(gt)
    try:
        return _import(bag_path, output, gt_traj, gt_label, opts)
    except ConslamError:
        raise
    except DataImportError as exc:  # the generic importer's errors, as ConSLAM's
        raise ConslamError(exc.message, exc.path, exc.field) from None


def _import(bag_path: Path, output: str | PathLike[str], gt: Trajectory | None,
            gt_label: str | None, opts: ConslamImportOptions) -> ConslamImportResult:
    extrinsic = (CONSLAM_CAM_FROM_LIDAR if opts.cam_from_lidar is None
                 else np.asarray(opts.cam_from_lidar, float))
    traj, poses = _gt_input(gt, gt_label, opts)
    import_opts = ImportOptions(tolerance_s=opts.tolerance_s, trajectory=traj, stride=opts.stride,
                                max_frames=opts.max_frames, lidar_model=VLP16, ifc=opts.ifc,
                                overwrite=opts.overwrite, png_compression=opts.png_compression,
                                progress=StageProgress())
    try:
        with open_reader(bag_path) as reader:
            has_info = any(norm_topic(c.topic) == TOPIC_CAMERA_INFO for c in reader.connections)
            t = find_topics(reader, BagTopics(TOPIC_IMAGE, TOPIC_POINTS,
                                              TOPIC_CAMERA_INFO if has_info else None),
                            need_info=False, need_tf=False, bag=bag_path)
            index = read_stamps(reader, t, import_opts, bag_path)
            try:
                plan = plan_frames(index.t_images, index.t_clouds, import_opts, bag_path,
                                   extrinsic, poses=poses)
            except DataImportError as exc:
                if traj is not None and exc.field == "timestamps" and "pose" in exc.message:
                    raise ConslamError(f"no frame has a ground-truth pose within "
                                       f"{opts.gt_tolerance_s} s", gt_label, "timestamps") from None
                raise
            info_camera = None
            if index.info_msg is not None:
                info_camera, _ = camera_from_info_or_reason(index.info_msg)
            n = len(plan.image_index)
            _log.info(f"writing {n} frames ({plan.n_pairs} image/scan pairs) to {output}")
            first, frames = _first_then_rest(stream_frames(reader, t, plan, bag_path), n,
                                             bag_path)
            cam, cam_source = _choose_camera(opts.camera, info_camera, first[1].shape, bag_path)
            source = _provenance(bag_path, gt_label, gt is not None, opts, t.names, cam_source)
            seq = write_planned_frames(output, Calibration(cam, extrinsic, {}), frames, plan,
                                       index.t_images, import_opts, source, bag_path)
    except reader_errors() as exc:
        raise ConslamError(f"cannot read the bag ({' '.join(str(exc).split())})",
                           bag_path) from None
    return ConslamImportResult(
        sequence=seq,
        n_images=len(index.t_images),
        n_scans=len(index.t_clouds),
        n_pairs=plan.n_pairs,
        n_without_gt=plan.n_without_pose,
        n_frames=len(seq),
        camera_source=cam_source,
        max_pair_dt_s=plan.max_pair_dt_s,
        max_gt_dt_s=plan.max_pose_dt_s,
        topics={"image": t.names["image"], "points": t.names["cloud"],
                "camera_info": t.names["camera_info"]},
    )


def _require_rosbags() -> None:
    """:class:`bimcap.errors.MissingDependencyError` (install ``bimcap[ros]``) unless rosbags
    imports."""
    from bimcap.errors import require

    require("rosbags.highlevel", "rosbags", "ros", "reading ROS1 bags (import-conslam)")


def _choose_camera(
    forced: Camera | None, from_info: Camera | None, shape: tuple[int, ...], bag: Path
) -> tuple[Camera, str]:
    h, w = int(shape[0]), int(shape[1])
    if forced is not None:
        cam, source = forced, "given"
    elif from_info is not None:
        cam, source = from_info, "camera_info"
    else:
        cam, source = CONSLAM_CAMERA, "conslam_default"
        if (w, h) != (cam.width, cam.height):
            fx, fy = w / cam.width, h / cam.height
            if not math.isclose(fx, fy, rel_tol=2e-3):
                raise ConslamError(
                    f"images are {w}x{h}, not a scaled {cam.width}x{cam.height}: give the camera",
                    bag,
                    "camera",
                )
            cam = Camera(
                w,
                h,
                cam.fx * fx,
                cam.fy * fy,
                (cam.cx + 0.5) * fx - 0.5,
                (cam.cy + 0.5) * fy - 0.5,
                cam.dist,
            )
            source = f"conslam_default scaled x{fx:.6g}"
    if (w, h) != (cam.width, cam.height):
        raise ConslamError(
            f"images are {w}x{h} but the camera ({source}) is {cam.width}x{cam.height}",
            bag,
            "camera",
        )
    return cam, source


def iter_topics(bag: str | PathLike[str]) -> Iterator[tuple[str, str, int]]:
    """(topic, message type, count) of every connection in a bag (for ``--list``)."""
    _require_rosbags()
    yield from list_topics(bag)
