"""ROS message decoding shared by every bag importer (ConSLAM, ``import-bag``); no ROS install.

Messages come deserialised by ``rosbags`` (ROS1 or ROS2 type stores; the field names differ only
in ``sensor_msgs/CameraInfo``: ``K``/``D`` in ROS1, ``k``/``d`` in ROS2, both are read), or as
raw serialised bytes for the fast stamp-only pass (:func:`header_stamp`).

Conventions: timestamps are float seconds; images come out as (H, W, 3) uint8 RGB; clouds as
(M, 4) float32 ``x y z intensity`` in the sensor's frame; cameras as
:class:`~bimcap.geometry.camera.Camera` (plumb_bob, pixel origin at the centre of the top-left
pixel, which is ROS's and OpenCV's convention too).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.dataset.sequence import SequenceError
from bimcap.geometry.camera import Camera

F64 = NDArray[np.float64]

#: ``sensor_msgs/PointField`` datatype codes → numpy type (without byte order).
POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}

#: Message types, as rosbags names them (ROS1 and ROS2 alike).
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"

#: Raw image encodings :func:`decode_image` reads, with their channel counts.
IMAGE_ENCODINGS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}


class RosMessageError(SequenceError):
    """A ROS message that cannot be decoded (names the field; importers add the bag and topic)."""


# --------------------------------------------------------------------------- time
def header_stamp(raw: bytes | memoryview, ros2: bool = False) -> float:
    """Header stamp (s) of a serialised message that starts with ``std_msgs/Header``.

    Reads only the stamp's 8 bytes, so that a pass over a large bag need not deserialise images.
    ROS1: ``uint32 seq`` then ``uint32 sec, uint32 nsec`` (little endian), at byte 4. ROS2 (CDR):
    a 4-byte encapsulation header (its second byte 1 = little endian, 0 = big endian) then
    ``int32 sec, uint32 nanosec``, also at byte 4.
    """
    order = "<"
    if ros2 and bytes(raw[1:2]) == b"\x00":
        order = ">"
    sec, nsec = struct.unpack_from(order + ("iI" if ros2 else "II"), raw, 4)
    return float(sec) + float(nsec) * 1e-9


def header_frame_id(raw: bytes | memoryview, ros2: bool = False) -> str:
    """``header.frame_id`` of a serialised message that starts with ``std_msgs/Header``.

    Both encodings put it at byte 12 (after the stamp) as a ``uint32`` length and the bytes;
    CDR counts a trailing NUL in the length, ROS1 does not.
    """
    order = "<"
    if ros2 and bytes(raw[1:2]) == b"\x00":
        order = ">"
    (n,) = struct.unpack_from(order + "I", raw, 12)
    if n > len(raw) - 16:
        raise RosMessageError(f"frame_id length {n} exceeds the message", field="header")
    return bytes(raw[16 : 16 + n]).rstrip(b"\x00").decode("utf-8", errors="replace")


def message_stamp(msg: Any) -> float:
    """Header stamp (s) of a deserialised message."""
    return float(msg.header.stamp.sec) + float(msg.header.stamp.nanosec) * 1e-9


def header_or_record_times(stamps: Iterable[tuple[float, float]]) -> F64:
    """(N,) times in seconds of one topic from ``(header stamp, bag record time)`` pairs.

    The header stamps, unless any is unset (0): then the topic's bag record times, for all its
    messages (never a mix of two clocks).
    """
    arr = np.asarray(list(stamps), dtype=np.float64).reshape(-1, 2)
    if len(arr) and (arr[:, 0] == 0.0).any():
        return arr[:, 1].copy()
    return arr[:, 0].copy()


# --------------------------------------------------------------------------- tf
def tf_edges(msg: Any) -> list[tuple[str, str, F64]]:
    """``(parent, child, parent_from_child (4, 4))`` of every transform of a
    ``tf2_msgs/TFMessage``: ROS's transform maps points from the child frame into the parent."""
    from scipy.spatial.transform import Rotation

    out = []
    for ts in msg.transforms:
        tr, q = ts.transform.translation, ts.transform.rotation
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        m[:3, 3] = [tr.x, tr.y, tr.z]
        out.append((norm_topic(str(ts.header.frame_id)), norm_topic(str(ts.child_frame_id)), m))
    return out


def tf_chain(edges: Iterable[tuple[str, str, F64]], target: str, source: str) -> F64 | None:
    """(4, 4) ``target_from_source`` composed along the tf tree (either direction of every
    edge; leading ``/`` ignored), or None when the frames are not connected."""
    graph: dict[str, list[tuple[str, F64]]] = {}
    for parent, child, parent_from_child in edges:
        graph.setdefault(parent, []).append((child, parent_from_child))
        graph.setdefault(child, []).append((parent, np.linalg.inv(parent_from_child)))
    start, goal = norm_topic(target), norm_topic(source)
    # Breadth-first from the target, keeping target_from_frame of every frame reached.
    best: dict[str, F64] = {start: np.eye(4)}
    queue = [start]
    while queue:
        frame = queue.pop(0)
        for nxt, frame_from_nxt in graph.get(frame, []):
            if nxt not in best:
                best[nxt] = best[frame] @ frame_from_nxt
                queue.append(nxt)
    return best.get(goal)


# --------------------------------------------------------------------------- topics
def norm_topic(topic: str) -> str:
    """A topic name without its leading ``/`` (bags write either form)."""
    return topic.lstrip("/")


def topic_list(connections: Iterable[Any]) -> str:
    """``"/a (sensor_msgs/msg/Image, 10 msgs), ..."``: every topic of a bag, for error messages."""
    seen: dict[str, tuple[str, int]] = {}
    for c in connections:
        msgtype, count = seen.get(c.topic, (str(c.msgtype), 0))
        seen[c.topic] = (msgtype, count + int(c.msgcount))
    if not seen:
        return "none"
    return ", ".join(f"{t} ({m}, {n} msgs)" for t, (m, n) in sorted(seen.items()))


# --------------------------------------------------------------------------- images
def decode_image(msg: Any) -> NDArray[np.uint8]:
    """A ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8 or mono8) as (H, W, 3) uint8 RGB.

    Row padding (``step`` > width × channels) is removed; alpha is dropped; mono8 is repeated
    into three channels.
    """
    h, w, step, enc = int(msg.height), int(msg.width), int(msg.step), str(msg.encoding)
    channels = IMAGE_ENCODINGS.get(enc)
    if channels is None:
        raise RosMessageError(
            f"unsupported image encoding {enc!r} ({', '.join(IMAGE_ENCODINGS)})", field="encoding"
        )
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * channels or data.size < h * step:
        raise RosMessageError(
            f"image data of {data.size} bytes too small for {w}x{h} {enc} with step {step}",
            field="data",
        )
    img = data[: h * step].reshape(h, step)[:, : w * channels].reshape(h, w, channels)
    if enc.startswith("bgr"):
        img = img[:, :, 2::-1]
    elif enc == "rgba8":
        img = img[:, :, :3]
    elif enc == "mono8":
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img)


def decode_compressed_image(msg: Any) -> NDArray[np.uint8]:
    """A ``sensor_msgs/CompressedImage`` (JPEG or PNG, colour or grey) as (H, W, 3) uint8 RGB."""
    import cv2

    data = np.asarray(msg.data, dtype=np.uint8)
    bgr = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if bgr is None:
        raise RosMessageError(
            f"cannot decode the {data.size}-byte compressed image (format {str(msg.format)!r})",
            field="data",
        )
    if bgr.dtype != np.uint8:
        raise RosMessageError(f"compressed image has {bgr.dtype} pixels, expected 8-bit",
                              field="data")
    return np.ascontiguousarray(bgr[:, :, ::-1])


def decode_any_image(msg: Any, msgtype: str) -> NDArray[np.uint8]:
    """:func:`decode_image` or :func:`decode_compressed_image` by message type."""
    if msgtype == COMPRESSED_IMAGE:
        return decode_compressed_image(msg)
    return decode_image(msg)


# --------------------------------------------------------------------------- clouds
def decode_pointcloud(msg: Any) -> NDArray[np.float32]:
    """A ``sensor_msgs/PointCloud2`` as (M, 4) float32 ``x y z intensity``.

    Fields are read at their declared offsets and types (any numeric type, either endianness),
    honouring ``point_step`` and ``row_step``; intensity is 0 if the cloud has none. Points with
    a non-finite coordinate (no return) are dropped.
    """
    fields = {str(f.name): f for f in msg.fields}
    for name in ("x", "y", "z"):
        if name not in fields:
            raise RosMessageError(f"point cloud has no field {name!r}", field="fields")
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for name in ("x", "y", "z", "intensity"):
        f = fields.get(name)
        if f is None:
            continue
        if int(f.datatype) not in POINTFIELD_DTYPES:
            raise RosMessageError(f"field {name!r} has unknown datatype {f.datatype}",
                                  field="fields")
        names.append(name)
        formats.append(order + POINTFIELD_DTYPES[int(f.datatype)])
        offsets.append(int(f.offset))
    step, h, w = int(msg.point_step), int(msg.height), int(msg.width)
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    if any(o + dtype.fields[n][0].itemsize > step for n, o in zip(names, offsets, strict=True)):
        raise RosMessageError("a field lies outside point_step", field="point_step")
    data = np.asarray(msg.data, dtype=np.uint8)
    row_step = int(msg.row_step)
    if row_step < w * step or data.size < h * row_step:
        raise RosMessageError(
            f"cloud data of {data.size} bytes too small for {h}x{w} points "
            f"(point_step {step}, row_step {row_step})",
            field="data",
        )
    rows = data[: h * row_step].reshape(h, row_step)[:, : w * step]
    pts = np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dtype)
    out = np.zeros((len(pts), 4), dtype=np.float32)
    for k, name in enumerate(("x", "y", "z", "intensity")):
        if name in names:
            out[:, k] = pts[name].astype(np.float32)
    return out[np.isfinite(out[:, :3]).all(axis=1)]


# --------------------------------------------------------------------------- cameras
def _info_field(msg: Any, upper: str) -> NDArray[np.float64]:
    """``K``/``D`` of a ROS1 CameraInfo or ``k``/``d`` of a ROS2 one, flattened."""
    value = getattr(msg, upper, None)
    if value is None:
        value = getattr(msg, upper.lower())
    return np.asarray(value, dtype=np.float64).reshape(-1)


def camera_from_info(msg: Any) -> Camera | None:
    """The camera of a ``sensor_msgs/CameraInfo``, or None if uncalibrated / not plumb_bob.

    ``rational_polynomial`` is accepted when its k4..k6 are zero (it is then plumb_bob).
    """
    return camera_from_info_or_reason(msg)[0]


def camera_from_info_or_reason(msg: Any) -> tuple[Camera | None, str]:
    """:func:`camera_from_info` and, when it gives None, why (for an error message)."""
    k = _info_field(msg, "K")
    d = _info_field(msg, "D")
    model = str(msg.distortion_model)
    if k.size != 9 or k[0] <= 0 or k[4] <= 0 or not np.isfinite(k).all():
        return None, f"K is not a calibrated camera matrix ({k.tolist()})"
    if model == "rational_polynomial" and d.size == 8 and not d[5:].any():
        d = d[:5]
    if model not in ("plumb_bob", "rational_polynomial", "") or d.size > 5:
        return None, (f"distortion_model {model!r} with {d.size} coefficients is not "
                      "plumb_bob (k1 k2 p1 p2 k3)")
    if not np.isfinite(d).all():
        return None, "D is not finite"
    dist = np.zeros(5)
    dist[: d.size] = d
    cam = Camera(int(msg.width), int(msg.height), k[0], k[4], k[2], k[5],
                 (dist[0], dist[1], dist[2], dist[3], dist[4]))
    return cam, ""
