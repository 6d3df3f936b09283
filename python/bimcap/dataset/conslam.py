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

What the importer does:

1. a first pass reads only the header stamps (the first bytes of every ROS1 message with a
   ``std_msgs/Header``) of images and scans;
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
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.dataset.importing import PoseSensor, lidar_to_camera_poses
from bimcap.dataset.pairing import nearest, pair_nearest, unique_increasing
from bimcap.dataset.ros import (
    RosMessageError,
    camera_from_info,
    decode_image,
    decode_pointcloud,
    header_or_record_times,
    header_stamp,
    norm_topic,
)
from bimcap.dataset.sequence import MANIFEST, VLP16, Sequence, SequenceError, SequenceWriter
from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import matrix_to_pose
from bimcap.geometry.trajectory import Trajectory, TrajectoryError, read_tum
from bimcap.progress import progress

F64 = NDArray[np.float64]
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
                opts: ConslamImportOptions) -> dict[str, Any]:
    """The manifest's ``source`` record of an import (without the camera's source)."""
    return {
        "importer": "bimcap.dataset.conslam",
        "bag": str(bag_path.resolve()),
        "gt": gt_label,
        "gt_frame": opts.gt_frame.value if has_gt else None,
        "topics": [TOPIC_IMAGE, TOPIC_POINTS, TOPIC_CAMERA_INFO],
        "tolerance_s": opts.tolerance_s,
        "gt_tolerance_s": opts.gt_tolerance_s,
        "stride": opts.stride,
        "timestamps": "image header stamps (bag time where zero)",
    }


@dataclass(frozen=True)
class _BagIndex:
    """An open bag after pass 1: its reader and type store, the image, points and camera_info
    connections, the image and scan stamps ti (I,), tp (S,) in seconds, and the camera of the
    first camera_info message (None without a usable one)."""

    path: Path
    reader: Any
    typestore: Any
    con_img: Any
    con_pts: Any
    con_info: Any | None
    ti: F64
    tp: F64
    info_camera: Camera | None


def _index_bag(reader: Any, typestore: Any, bag_path: Path) -> _BagIndex:
    """Find the topics (refusing a bag without images or scans) and read their stamps."""
    by_topic = {norm_topic(c.topic): c for c in reader.connections}
    for topic in (TOPIC_IMAGE, TOPIC_POINTS):
        if topic not in by_topic:
            raise ConslamError(
                f"topic {topic!r} not in bag (has {sorted(by_topic)})", bag_path, "topics"
            )
    con_img, con_pts = by_topic[TOPIC_IMAGE], by_topic[TOPIC_POINTS]
    con_info = by_topic.get(TOPIC_CAMERA_INFO)
    ti, tp, info_camera = _read_stamps(reader, typestore, con_img, con_pts, con_info)
    return _BagIndex(path=bag_path, reader=reader, typestore=typestore, con_img=con_img,
                     con_pts=con_pts, con_info=con_info, ti=ti, tp=tp, info_camera=info_camera)


def _camera_poses(plan: _FramePlan, extrinsic: F64, gt_frame: GtFrame) -> F64 | None:
    """(K, 7) ``world_from_cam`` of the planned frames from their ground truth (None without)."""
    if plan.world_from_gt is None:
        return None
    if gt_frame is GtFrame.LIDAR:
        return lidar_to_camera_poses(plan.world_from_gt, extrinsic)
    return plan.world_from_gt


def _write_frames(
    bag: _BagIndex,
    plan: _FramePlan,
    output: str | PathLike[str],
    extrinsic: F64,
    source: dict[str, Any],
    opts: ConslamImportOptions,
) -> tuple[SequenceWriter | None, str]:
    """Pass 2: write the planned frames (the camera chosen at the first image); the writer
    (None when no frame came) and where the camera came from."""
    writer: SequenceWriter | None = None
    cam_source = "given"
    n = len(plan.image_index)
    _log.info(f"writing {n} frames ({plan.n_pairs} image/scan pairs) to {output}")
    frames = _stream_frames(bag.reader, bag.typestore, bag.con_img, bag.con_pts, plan, bag.path)
    for k, image, cloud in progress(frames, total=n, desc="import", unit="frame"):
        if writer is None:
            cam, cam_source = _choose_camera(opts.camera, bag.info_camera, image.shape, bag.path)
            writer = SequenceWriter(
                output,
                cam,
                extrinsic,
                lidar=VLP16,
                ifc=opts.ifc,
                source={**source, "camera_source": cam_source},
                overwrite=opts.overwrite,
                png_compression=opts.png_compression,
            )
        writer.add_frame(float(bag.ti[plan.image_index[k]]), image, cloud)
    return writer, cam_source


def _finish_sequence(writer: SequenceWriter | None, plan: _FramePlan,
                     world_from_cam: F64 | None, bag_path: Path) -> Sequence:
    """Check that every planned frame was written, add the ground truth and close."""
    n_planned = len(plan.image_index)
    if writer is None or len(writer.frames) != n_planned:
        done = 0 if writer is None else len(writer.frames)
        raise ConslamError(f"only {done} of {n_planned} frames could be assembled", bag_path)
    if world_from_cam is not None:
        writer.add_trajectory("gt", world_from_cam)
    return writer.close()


def import_conslam(
    bag: str | PathLike[str],
    output: str | PathLike[str],
    gt: str | PathLike[str] | Trajectory | None = None,
    *,
    options: ConslamImportOptions | None = None,
    **legacy_options: Any,
) -> ConslamImportResult:
    """Import a ConSLAM ROS1 bag (and its ground truth) as a sequence directory.

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
    from rosbags.rosbag1 import Reader, ReaderError
    from rosbags.typesys import Stores, get_typestore

    opts = _import_options(options, legacy_options)
    bag_path = Path(bag)
    _check_import(bag_path, output, opts)
    extrinsic = (CONSLAM_CAM_FROM_LIDAR if opts.cam_from_lidar is None
                 else np.asarray(opts.cam_from_lidar, float))
    typestore = get_typestore(Stores.ROS1_NOETIC)
    gt_traj, gt_label = _load_gt(gt)
    source = _provenance(bag_path, gt_label, gt_traj is not None, opts)
    try:
        with Reader(bag_path) as reader:
            index = _index_bag(reader, typestore, bag_path)
            plan = _plan_frames(index.ti, index.tp, opts.tolerance_s, gt_traj,
                                opts.gt_tolerance_s, opts.stride, opts.max_frames, bag_path,
                                gt_label)
            world_from_cam = _camera_poses(plan, extrinsic, opts.gt_frame)
            writer, cam_source = _write_frames(index, plan, output, extrinsic, source, opts)
    except ReaderError as exc:
        raise ConslamError(f"cannot read the bag ({exc})", bag_path) from None
    seq = _finish_sequence(writer, plan, world_from_cam, bag_path)
    return ConslamImportResult(
        sequence=seq,
        n_images=len(index.ti),
        n_scans=len(index.tp),
        n_pairs=plan.n_pairs,
        n_without_gt=plan.n_without_gt,
        n_frames=len(seq),
        camera_source=cam_source,
        max_pair_dt_s=plan.max_pair_dt_s,
        max_gt_dt_s=plan.max_gt_dt_s,
        topics={
            "image": index.con_img.topic,
            "points": index.con_pts.topic,
            "camera_info": index.con_info.topic if index.con_info is not None else "",
        },
    )


@dataclass(frozen=True)
class _FramePlan:
    """Which messages become frames, in writing order.

    image_index, scan_index: (K,) message indices (per topic, in bag order) of each frame.
    world_from_gt: (K, 7) ground-truth poses at the frames' scans (sensor of the GT), or None.
    """

    image_index: NDArray[np.int64]
    scan_index: NDArray[np.int64]
    world_from_gt: F64 | None
    n_pairs: int
    n_without_gt: int
    max_pair_dt_s: float
    max_gt_dt_s: float


def _require_rosbags() -> None:
    """:class:`bimcap.errors.MissingDependencyError` (install ``bimcap[ros]``) unless rosbags
    imports."""
    from bimcap.errors import require

    require("rosbags.rosbag1", "rosbags", "ros", "reading ROS1 bags (import-conslam)")


def _read_stamps(
    reader: Any, typestore: Any, con_img: Any, con_pts: Any, con_info: Any | None
) -> tuple[F64, F64, Camera | None]:
    """Pass 1: image and scan stamps (header bytes only) and the first camera_info's camera."""
    stamps: dict[int, list[tuple[float, float]]] = {con_img.id: [], con_pts.id: []}
    info_camera: Camera | None = None
    wanted = [con_img, con_pts] + ([con_info] if con_info is not None else [])
    counts = [getattr(c, "msgcount", None) for c in wanted]
    total = None if None in counts else sum(counts)
    _log.info(f"indexing the bag: {'?' if total is None else total} messages on "
              f"{', '.join(c.topic for c in wanted)}")
    for con, bag_ns, raw in progress(reader.messages(connections=wanted), total=total,
                                     desc="index", unit="msg"):
        if con.id in stamps:
            stamps[con.id].append((header_stamp(raw), bag_ns * 1e-9))
        elif info_camera is None:
            info_camera = camera_from_info(typestore.deserialize_ros1(raw, con.msgtype))
    return (header_or_record_times(stamps[con_img.id]),
            header_or_record_times(stamps[con_pts.id]), info_camera)


def _plan_frames(
    ti: F64,
    tp: F64,
    tolerance_s: float,
    gt: Trajectory | None,
    gt_tolerance_s: float,
    stride: int,
    max_frames: int | None,
    bag: Path,
    gt_label: str | None,
) -> _FramePlan:
    """Pair images with scans, attach ground truth, thin out; frames in increasing image time."""
    ia, ib = pair_nearest(ti, tp, tolerance_s)
    order = np.argsort(ti[ia], kind="stable")
    ia, ib = ia[order], ib[order]
    fresh = unique_increasing(ti[ia])
    ia, ib = ia[fresh], ib[fresh]  # equal image stamps: keep the first
    n_pairs = len(ia)
    if n_pairs == 0:
        raise ConslamError(
            f"no image/scan pair within {tolerance_s} s ({len(ti)} images, {len(tp)} scans)",
            bag,
            "timestamps",
        )
    world_from_gt: F64 | None = None
    n_without_gt = 0
    max_gt_dt = 0.0
    if gt is not None:
        gi, gdt = nearest(tp[ib], gt.timestamps)
        keep = gdt <= gt_tolerance_s
        n_without_gt = int((~keep).sum())
        if not keep.any():
            raise ConslamError(
                f"no frame has a ground-truth pose within {gt_tolerance_s} s",
                gt_label,
                "timestamps",
            )
        ia, ib, gi, gdt = ia[keep], ib[keep], gi[keep], gdt[keep]
        world_from_gt = gt.poses[gi]
        max_gt_dt = float(gdt.max())
    sel = np.arange(0, len(ia), stride)[:max_frames]
    ia, ib = ia[sel], ib[sel]
    return _FramePlan(
        image_index=ia,
        scan_index=ib,
        world_from_gt=None if world_from_gt is None else world_from_gt[sel],
        n_pairs=n_pairs,
        n_without_gt=n_without_gt,
        max_pair_dt_s=float(np.abs(ti[ia] - tp[ib]).max()),
        max_gt_dt_s=max_gt_dt,
    )


def _stream_frames(
    reader: Any, typestore: Any, con_img: Any, con_pts: Any, plan: _FramePlan, bag: Path
) -> Iterator[tuple[int, NDArray[np.uint8], NDArray[np.float32]]]:
    """Pass 2: decode only the planned messages; yield ``(k, rgb, scan)`` in frame order k.

    Images and scans arrive interleaved; a frame is yielded as soon as both halves (and every
    earlier frame) are there, so only a few frames are ever held in memory.
    """
    slot = {
        con_img.id: {int(i): k for k, i in enumerate(plan.image_index)},
        con_pts.id: {int(j): k for k, j in enumerate(plan.scan_index)},
    }
    count = {con_img.id: 0, con_pts.id: 0}
    images: dict[int, NDArray[np.uint8]] = {}
    clouds: dict[int, NDArray[np.float32]] = {}
    next_k = 0
    for con, _, raw in reader.messages(connections=[con_img, con_pts]):
        n = count[con.id]
        count[con.id] = n + 1
        k = slot[con.id].get(n)
        if k is None:
            continue
        msg = typestore.deserialize_ros1(raw, con.msgtype)
        try:
            if con.id == con_img.id:
                images[k] = decode_image(msg)
            else:
                clouds[k] = decode_pointcloud(msg)
        except RosMessageError as exc:
            where = f"{con.topic}[{n}]" + (f".{exc.field}" if exc.field else "")
            raise ConslamError(exc.message, bag, where) from None
        while next_k in images and next_k in clouds:
            yield next_k, images.pop(next_k), clouds.pop(next_k)
            next_k += 1


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
    from rosbags.rosbag1 import Reader

    with Reader(Path(bag)) as reader:
        for c in reader.connections:
            yield c.topic, c.msgtype, c.msgcount
