"""Import any ROS1 or ROS2 bag (camera images + LiDAR clouds) as a sequence directory.

The bag is read with ``rosbags.highlevel.AnyReader`` (no ROS install): a ROS1 ``.bag`` file, or
a ROS2 bag (its directory with ``metadata.yaml``, or one ``.db3`` / ``.mcap`` storage file). The
importer takes

- an image topic (``sensor_msgs/Image``: rgb8, bgr8, rgba8, bgra8, mono8; or
  ``sensor_msgs/CompressedImage``: JPEG / PNG),
- a cloud topic (``sensor_msgs/PointCloud2`` with x, y, z and optionally intensity),
- the camera: a ``sensor_msgs/CameraInfo`` topic (by default the ``camera_info`` beside the
  image topic, or the bag's only CameraInfo topic) or a calibration file
  (:mod:`bimcap.dataset.calib`: ROS camera_info YAML or Kalibr camchain),
- the LiDAR → camera extrinsic: an extrinsic YAML (or ``identity``), unless the calibration file
  carries one; or ``tf``: composed along the bag's ``/tf_static`` tree from the cloud's
  ``header.frame_id`` to the image's (which must be the camera's optical frame, REP 103),
- optionally a trajectory (TUM / KITTI / COLMAP, camera or LiDAR poses;
  :class:`~bimcap.dataset.importing.TrajectoryInput`).

Two passes over the bag: the first reads only the header stamps of the images and clouds (the
8 bytes after the ROS1 ``seq`` or the CDR encapsulation header; a topic with an unset stamp uses
the bag's record times) and the first CameraInfo; :func:`~bimcap.dataset.importing.plan_frames`
pairs them; the second decodes only the planned messages and writes them, a few frames in
memory at a time. ``options.progress`` hears about both passes.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.dataset.calib import Calibration, read_calibration, read_extrinsic_argument
from bimcap.dataset.importing import (
    DataImportError,
    FramePlan,
    ImportOptions,
    ImportResult,
    check_options,
    load_trajectory,
    plan_frames,
    trajectory_record,
    write_planned_frames,
)
from bimcap.dataset.ros import (
    CAMERA_INFO,
    COMPRESSED_IMAGE,
    IMAGE,
    POINTCLOUD2,
    RosMessageError,
    camera_from_info_or_reason,
    decode_any_image,
    decode_pointcloud,
    header_frame_id,
    header_or_record_times,
    header_stamp,
    norm_topic,
    tf_chain,
    tf_edges,
    topic_list,
)
from bimcap.errors import require
from bimcap.geometry.poses import matrix_to_pose

F64 = NDArray[np.float64]

#: How often (messages) pass 1 reports progress.
PROGRESS_EVERY = 200
#: The ``lidar_extrinsic`` value that takes the extrinsic from the bag's ``/tf_static``.
FROM_TF = "tf"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"


class BagError(DataImportError):
    """A bag that cannot be imported: unreadable, a topic missing or of the wrong type, no pairs
    (names the bag and the topic or field)."""


@dataclass(frozen=True)
class BagTopics:
    """The topics to import (with or without the leading ``/``).

    Attributes
    ----------
    image: ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage``.
    cloud: ``sensor_msgs/PointCloud2``.
    camera_info: ``sensor_msgs/CameraInfo``, or None (then a calibration file, or the
        ``camera_info`` beside the image topic, or the bag's only CameraInfo topic).
    """

    image: str
    cloud: str
    camera_info: str | None = None


def is_ros2(path: Path) -> bool:
    """True for a ROS2 bag (a directory, ``.db3`` or ``.mcap``), False for a ROS1 ``.bag``."""
    return path.suffix != ".bag"


def _check_bag_path(path: Path) -> None:
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise BagError("a directory without metadata.yaml is not a ROS2 bag", path)
    elif not path.is_file():
        raise BagError("no such bag file or directory", path)
    elif path.suffix not in (".bag", ".db3", ".mcap"):
        raise BagError(f"unknown bag type {path.suffix!r} (.bag, .db3, .mcap or a ROS2 bag "
                       "directory)", path)


def open_reader(path: Path) -> Any:
    """An unopened ``AnyReader`` with a default type store for bags without definitions."""
    require("rosbags.highlevel", "rosbags", "ros", "reading ROS bags (import-bag)")
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    store = Stores.ROS2_HUMBLE if is_ros2(path) else Stores.ROS1_NOETIC
    return AnyReader([path], default_typestore=get_typestore(store))


def reader_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as ReaderError1
    from rosbags.rosbag2 import ReaderError as ReaderError2
    from rosbags.serde import SerdeError

    return AnyReaderError, ReaderError1, ReaderError2, SerdeError


def list_topics(bag: str | PathLike[str]) -> list[tuple[str, str, int]]:
    """(topic, message type, count) of every topic of a bag, sorted by topic."""
    path = Path(bag)
    _check_bag_path(path)
    try:
        with open_reader(path) as reader:
            return sorted((name, str(info.msgtype), int(info.msgcount))
                          for name, info in reader.topics.items())
    except reader_errors() as exc:
        raise BagError(f"cannot read the bag ({exc})", path) from None


# --------------------------------------------------------------------------- topics
@dataclass(frozen=True)
class BagConnections:
    """The connections of the image, cloud and camera_info topics (lists: a ROS1 bag may hold
    several connections per topic) and their names as the bag spells them."""

    image: list[Any]
    cloud: list[Any]
    info: list[Any]
    tf: list[Any]
    names: dict[str, str]

    @property
    def all(self) -> list[Any]:
        """Every connection both passes read (the same set, so that the order is the same)."""
        return self.image + self.cloud + self.info + self.tf


def _find(connections: list[Any], topic: str, types: tuple[str, ...], what: str,
          bag: Path) -> list[Any]:
    found = [c for c in connections if norm_topic(c.topic) == norm_topic(topic)]
    if not found:
        raise BagError(f"{what} topic {topic!r} is not in the bag; its topics: "
                       f"{topic_list(connections)}", bag, "topics")
    bad = [c.msgtype for c in found if c.msgtype not in types]
    if bad:
        raise BagError(f"{what} topic {topic!r} carries {bad[0]}, expected "
                       f"{' or '.join(types)}", bag, "topics")
    return found


def _auto_camera_info(connections: list[Any], image_topic: str, bag: Path) -> list[Any]:
    """The CameraInfo beside the image topic (``ns/image_raw`` → ``ns/camera_info``), else the
    bag's only CameraInfo topic."""
    infos = [c for c in connections if c.msgtype == CAMERA_INFO]
    parent = norm_topic(image_topic).rsplit("/", 1)[0]
    sibling = [c for c in infos if norm_topic(c.topic) == f"{parent}/camera_info"]
    if sibling:
        return sibling
    if len({c.topic for c in infos}) == 1:
        return infos
    raise BagError(
        "no camera: give a camera_info topic or a calibration file (CameraInfo topics in the "
        f"bag: {', '.join(sorted({c.topic for c in infos})) or 'none'})", bag, "camera_info")


def find_topics(reader: Any, topics: BagTopics, need_info: bool, need_tf: bool,
                bag: Path) -> BagConnections:
    cons = list(reader.connections)
    img = _find(cons, topics.image, (IMAGE, COMPRESSED_IMAGE), "image", bag)
    cloud = _find(cons, topics.cloud, (POINTCLOUD2,), "cloud", bag)
    info: list[Any] = []
    if topics.camera_info is not None:
        info = _find(cons, topics.camera_info, (CAMERA_INFO,), "camera_info", bag)
    elif need_info:
        info = _auto_camera_info(cons, topics.image, bag)
    tf: list[Any] = []
    if need_tf:
        tf = [c for c in cons if norm_topic(c.topic) == "tf_static" and c.msgtype == TF_MESSAGE]
        if not tf:
            raise BagError("no /tf_static (tf2_msgs/msg/TFMessage) to take the LiDAR extrinsic "
                           f"from; its topics: {topic_list(cons)}", bag, "lidar_extrinsic")
    names = {"image": img[0].topic, "cloud": cloud[0].topic,
             "camera_info": info[0].topic if info else ""}
    return BagConnections(img, cloud, info, tf, names)


# --------------------------------------------------------------------------- passes
@dataclass(frozen=True)
class BagIndex:
    """What pass 1 found: image and cloud times (I,), (C,) in seconds, the first CameraInfo
    message (or None), the frame ids of the first image and cloud, the /tf_static edges."""

    t_images: F64
    t_clouds: F64
    info_msg: Any | None
    image_frame: str
    cloud_frame: str
    tf: list[tuple[str, str, F64]]


def read_stamps(reader: Any, t: BagConnections, opts: ImportOptions, bag: Path) -> BagIndex:
    """Pass 1: image and cloud times (header bytes only), the first CameraInfo message, the
    frame ids of the first image and cloud, and the /tf_static transforms."""
    ros2 = bool(reader.is2)
    key_of = {id(c): "image" for c in t.image} | {id(c): "cloud" for c in t.cloud}
    tf_ids = {id(c) for c in t.tf}
    stamps: dict[str, list[tuple[float, float]]] = {"image": [], "cloud": []}
    frames = {"image": "", "cloud": ""}
    info_msg: Any | None = None
    edges: list[tuple[str, str, F64]] = []
    total = sum(int(c.msgcount) for c in t.all)
    for n, (con, bag_ns, raw) in enumerate(reader.messages(connections=t.all), start=1):
        key = key_of.get(id(con))
        if key is not None:
            try:
                stamp = header_stamp(raw, ros2)
                if not stamps[key]:
                    frames[key] = norm_topic(header_frame_id(raw, ros2))
            except (struct.error, RosMessageError):  # a truncated message
                raise BagError(f"message {len(stamps[key])} is too short for a header",
                               bag, con.topic) from None
            stamps[key].append((stamp, bag_ns * 1e-9))
        elif id(con) in tf_ids:
            edges += tf_edges(reader.deserialize(raw, con.msgtype))
        elif info_msg is None:
            info_msg = reader.deserialize(raw, con.msgtype)
        if opts.progress is not None and (n % PROGRESS_EVERY == 0 or n == total):
            opts.progress("index", n, total)
    return BagIndex(header_or_record_times(stamps["image"]),
                    header_or_record_times(stamps["cloud"]), info_msg, frames["image"],
                    frames["cloud"], edges)


def _extrinsic_from_tf(index: BagIndex, t: BagConnections, bag: Path) -> F64:
    """(7,) ``cam_from_lidar`` along /tf_static from the cloud's frame to the image's."""
    cam, lidar = index.image_frame, index.cloud_frame
    if not cam or not lidar:
        raise BagError(f"the {'image' if not cam else 'cloud'} messages have no frame_id to "
                       "look up in /tf_static", bag, t.names["image" if not cam else "cloud"])
    m = tf_chain(index.tf, cam, lidar)
    if m is None:
        known = sorted({f for e in index.tf for f in e[:2]})
        raise BagError(f"no chain of /tf_static transforms from the cloud's frame {lidar!r} to "
                       f"the image's frame {cam!r} (frames: {', '.join(known) or 'none'})",
                       bag, "lidar_extrinsic")
    return matrix_to_pose(m)


def stream_frames(reader: Any, t: BagConnections, plan: FramePlan,
                   bag: Path) -> Iterator[tuple[int, NDArray[np.uint8], NDArray[np.float32]]]:
    """Pass 2: decode only the planned messages; yield ``(k, rgb, cloud)`` in frame order k,
    as soon as both halves of frame k (and every earlier frame) are there."""
    img_ids = {id(c) for c in t.image}
    slot = {
        "image": {int(i): k for k, i in enumerate(plan.image_index)},
        "cloud": {int(j): k for k, j in enumerate(plan.cloud_index)},
    }
    count = {"image": 0, "cloud": 0}
    images: dict[int, NDArray[np.uint8]] = {}
    clouds: dict[int, NDArray[np.float32]] = {}
    next_k = 0
    skip = {id(c) for c in t.info + t.tf}
    for con, _, raw in reader.messages(connections=t.all):  # as pass 1: the same order
        if id(con) in skip:
            continue
        key = "image" if id(con) in img_ids else "cloud"
        n = count[key]
        count[key] = n + 1
        k = slot[key].get(n)
        if k is None:
            continue
        try:
            msg = reader.deserialize(raw, con.msgtype)
            if key == "image":
                images[k] = decode_any_image(msg, con.msgtype)
            else:
                clouds[k] = decode_pointcloud(msg)
        except RosMessageError as exc:
            where = f"{con.topic}[{n}]" + (f".{exc.field}" if exc.field else "")
            raise BagError(exc.message, bag, where) from None
        while next_k in images and next_k in clouds:
            yield next_k, images.pop(next_k), clouds.pop(next_k)
            next_k += 1


def _calibration(calib: str | PathLike[str] | None, calib_camera: str,
                 lidar_extrinsic: str | PathLike[str] | None) -> Calibration | None:
    """The calibration file's camera and extrinsic (None without a file)."""
    if calib is None:
        return None
    return read_calibration(calib, camera=calib_camera, lidar_extrinsic=lidar_extrinsic)


def _missing_extrinsic(where: str | PathLike[str] | None) -> BagError:
    return BagError("no LiDAR extrinsic: give lidar_extrinsic / --lidar-extrinsic (a YAML with "
                    "T_cam_lidar, 'tf' to take it from the bag's /tf_static, or 'identity' when "
                    "the clouds are in the camera frame)", where, "lidar_extrinsic")


def _final_calibration(cal: Calibration | None, extrinsic: tuple[F64, str] | None,
                       index: BagIndex, t: BagConnections, bag: Path) -> Calibration:
    """The calibration after pass 1: the file's camera or the first camera_info's; the given
    extrinsic, the file's, or (``extrinsic`` None and no file extrinsic) the one of /tf_static.
    """
    if t.tf:
        label = f"/tf_static: {index.cloud_frame} -> {index.image_frame}"
        extrinsic = (_extrinsic_from_tf(index, t, bag), label)
        if cal is not None:
            return Calibration(cal.camera, extrinsic[0], {**cal.source, "extrinsic": label})
    if cal is not None:
        return cal
    topic = t.names["camera_info"]
    if index.info_msg is None:
        raise BagError("no message on the camera_info topic", bag, topic)
    camera, reason = camera_from_info_or_reason(index.info_msg)
    if camera is None:
        raise BagError(f"unusable camera_info: {reason}", bag, topic)
    assert extrinsic is not None
    return Calibration(camera, extrinsic[0],
                       {"camera_info_topic": topic, "extrinsic": extrinsic[1]})


def _provenance(bag: Path, ros2: bool, t: BagConnections, cal: Calibration,
                opts: ImportOptions) -> dict[str, Any]:
    """The manifest's ``source`` record of an import."""
    return {
        "importer": "bimcap.dataset.bag",
        "bag": str(bag.resolve()),
        "ros_version": 2 if ros2 else 1,
        "topics": dict(t.names),
        "calibration": cal.source,
        "tolerance_s": opts.tolerance_s,
        "stride": opts.stride,
        "trajectory": trajectory_record(opts.trajectory),
        "timestamps": "image header stamps (bag record times where unset)",
    }


# --------------------------------------------------------------------------- the importer
def import_bag(
    bag: str | PathLike[str],
    output: str | PathLike[str],
    topics: BagTopics,
    *,
    calib: str | PathLike[str] | None = None,
    calib_camera: str = "cam0",
    lidar_extrinsic: str | PathLike[str] | None = None,
    options: ImportOptions | None = None,
) -> ImportResult:
    """Import a ROS1 or ROS2 bag as a sequence directory (module docstring).

    Parameters
    ----------
    bag: a ROS1 ``.bag``, a ROS2 bag directory, or a ROS2 ``.db3`` / ``.mcap`` file.
    output: the sequence directory to write.
    topics: the image, cloud and (optional) camera_info topics.
    calib: a camera calibration file (ROS camera_info YAML or Kalibr camchain) instead of a
        camera_info topic.
    calib_camera: which camera of a Kalibr camchain.
    lidar_extrinsic: an extrinsic YAML, ``"identity"``, or ``"tf"`` (from ``/tf_static``);
        needed unless ``calib`` has one.
    options: :class:`~bimcap.dataset.importing.ImportOptions`.

    Raises
    ------
    BagError
        An unreadable bag; a topic that is missing (the message lists the bag's topics) or of
        the wrong type; no camera or extrinsic; a message that cannot be decoded.
    bimcap.dataset.importing.DataImportError
        (BagError's base) No image/cloud pair within the tolerance (the message gives both
        topics' time ranges), no frame with a pose, an image of another size than the camera.
    bimcap.dataset.calib.CalibrationError, bimcap.geometry.pose_formats.PoseFormatError
        A bad calibration or trajectory file (naming the file and the field).
    """
    require("rosbags.highlevel", "rosbags", "ros", "reading ROS bags (import-bag)")
    opts = options or ImportOptions()
    path = Path(bag)
    _check_bag_path(path)
    check_options(opts, output)
    if calib is not None and topics.camera_info is not None:
        raise BagError("give a camera_info topic or a calibration file, not both", path,
                       "camera_info")
    from_tf = lidar_extrinsic is not None and str(lidar_extrinsic) == FROM_TF
    cal = _calibration(calib, calib_camera, None if from_tf else lidar_extrinsic)
    if cal is not None and cal.cam_from_lidar is None and not from_tf:
        raise _missing_extrinsic(calib)
    poses = load_trajectory(opts)
    extrinsic: tuple[F64, str] | None = None
    if cal is None and not from_tf:
        if lidar_extrinsic is None:
            raise _missing_extrinsic(None)
        extrinsic = read_extrinsic_argument(lidar_extrinsic)
    try:
        with open_reader(path) as reader:
            t = find_topics(reader, topics, cal is None, from_tf, path)
            index = read_stamps(reader, t, opts, path)
            ti = index.t_images
            cal = _final_calibration(cal, extrinsic, index, t, path)
            assert cal.cam_from_lidar is not None
            plan = plan_frames(ti, index.t_clouds, opts, path, cal.cam_from_lidar, poses=poses)
            record = _provenance(path, bool(reader.is2), t, cal, opts)
            seq = write_planned_frames(output, cal, stream_frames(reader, t, plan, path), plan,
                                       ti, opts, record, path)
    except reader_errors() as exc:
        raise BagError(f"cannot read the bag ({' '.join(str(exc).split())})", path) from None
    camera_source = (f"camera_info topic {t.names['camera_info']}" if calib is None
                     else f"{cal.source.get('format')} file {calib}")
    return ImportResult(
        sequence=seq,
        n_images=len(ti),
        n_clouds=len(index.t_clouds),
        n_pairs=plan.n_pairs,
        n_without_pose=plan.n_without_pose,
        n_frames=len(seq),
        max_pair_dt_s=plan.max_pair_dt_s,
        max_pose_dt_s=plan.max_pose_dt_s,
        pose_match=plan.pose_match,
        camera_source=camera_source,
        extra={"topics": dict(t.names)},
    )
