"""Sequence directories: the on-disk format that simulated and imported recordings share.

Layout (``docs/architecture.md`` "Sequence directory")::

    SEQ/manifest.json      versioned manifest (schema below), written last
    SEQ/images/NNNNNN.png  8-bit RGB, raw (distorted) as the camera gives it
    SEQ/lidar/NNNNNN.bin   little-endian float32 (M, 4) x y z intensity, LiDAR frame, metres
    SEQ/labels/NNNNNN.png  uint8 label ids of :class:`bimcap.labels.Label` (optional)
    SEQ/labels_gt/NNNNNN.png  the true labels when labels/ holds noisy ones (optional; simulator)
    SEQ/depth/NNNNNN.npy   float32 (H, W) z-depth in metres of the raw image, 0 = unknown (optional)
    SEQ/poses/NAME.tum     ``world_from_cam`` TUM trajectories, one pose per frame (gt, init, ...)

Manifest (version 1)::

    {"format": "bimcap-sequence", "version": 1,
     "camera": {"model": "plumb_bob", "width": W, "height": H, "K": [fx, fy, cx, cy],
                "dist": [k1, k2, p1, p2, k3]},
     "cam_from_lidar": [tx, ty, tz, qx, qy, qz, qw],
     "lidar": {"model": "VLP-16", "channels": 16, "vertical_fov_deg": [-15, 15],
               "azimuth_step_deg": 0.2, "rate_hz": 10, "max_range_m": 100, ...extra keys kept},
     "ifc": "path/relative/to/SEQ/or/absolute.ifc" | null,
     "frames": [{"timestamp": t, "image": "images/000000.png", "lidar": "lidar/000000.bin",
                 "labels": "labels/000000.png" | null, "depth": "depth/000000.npy" | null,
                 "labels_gt": "labels_gt/000000.png" (only when present)}, ...],
     "poses": {"gt": "poses/gt.tum", "init": "poses/init.tum"},
     "source": {...free-form provenance...}}

Only ``lidar.model`` is required among the LiDAR keys; the others are optional but checked when
present. Every file path in the manifest is relative to ``SEQ`` and may not leave it (the IFC
path excepted). Every trajectory named in ``poses`` must have exactly one pose per frame with the
frame's timestamp.

:func:`read_sequence` validates the whole manifest, the presence of every file, the size of every
LiDAR file and every listed trajectory, and raises :class:`SequenceError` naming the manifest (or
file) and the field. Pixel data are loaded lazily by :meth:`Sequence.load_image` etc., which
check shapes. :class:`SequenceWriter` writes each frame's files atomically as it is added and
the manifest last, so a directory without ``manifest.json`` is an unfinished sequence.
"""

from __future__ import annotations

import io
import itertools
import json
import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path, PurePosixPath
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.errors import InputError
from bimcap.geometry.camera import Camera
from bimcap.geometry.trajectory import Trajectory, TrajectoryError, read_tum, write_tum
from bimcap.io.atomic import atomic_write_bytes, atomic_write_json
from bimcap.io.png import read_png
from bimcap.labels import Label

#: The value of the manifest's ``format`` key.
FORMAT = "bimcap-sequence"
#: The manifest version this module reads and writes.
VERSION = 1
#: File name of the manifest inside a sequence directory.
MANIFEST = "manifest.json"
#: Bytes per LiDAR point on disk: four little-endian float32 (x, y, z, intensity).
LIDAR_POINT_BYTES = 16
#: Largest tolerated difference (s) between a frame's timestamp and its trajectory timestamp.
TIMESTAMP_TOLERANCE_S = 1e-6
#: Largest tolerated deviation of ``cam_from_lidar``'s quaternion norm from 1.
QUATERNION_NORM_TOLERANCE = 1e-6

_LIDAR_DTYPE = np.dtype("<f4")


class SequenceError(InputError):
    """A sequence directory that cannot be read or written (names the file and the field)."""


# --------------------------------------------------------------------------- data classes
@dataclass(frozen=True)
class LidarInfo:
    """The LiDAR model a sequence was recorded with (informational; the points are what count).

    Attributes
    ----------
    model: name, e.g. ``"VLP-16"``.
    channels: number of beams, or None if unknown.
    vertical_fov_deg: (lowest, highest) beam elevation in degrees, or None.
    azimuth_step_deg: horizontal resolution in degrees, or None.
    rate_hz: rotation rate in Hz, or None.
    max_range_m: maximum range in metres, or None.
    extra: further keys of the manifest's ``lidar`` object, kept as they are.
    """

    model: str
    channels: int | None = None
    vertical_fov_deg: tuple[float, float] | None = None
    azimuth_step_deg: float | None = None
    rate_hz: float | None = None
    max_range_m: float | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"model": self.model}
        if self.channels is not None:
            out["channels"] = self.channels
        if self.vertical_fov_deg is not None:
            out["vertical_fov_deg"] = list(self.vertical_fov_deg)
        for key in ("azimuth_step_deg", "rate_hz", "max_range_m"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        out.update(dict(self.extra))
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], path: str | PathLike[str] | None = None) -> LidarInfo:
        """Parse and check the manifest's ``lidar`` object (raises :class:`SequenceError`)."""
        if not isinstance(d, Mapping):
            raise SequenceError("must be an object", path, "lidar")
        model = d.get("model")
        if not isinstance(model, str) or not model:
            raise SequenceError("missing or empty model name", path, "lidar.model")
        channels = d.get("channels")
        if channels is not None and (
            not isinstance(channels, int) or isinstance(channels, bool) or channels <= 0
        ):
            raise SequenceError(
                f"must be a positive integer, got {channels!r}", path, "lidar.channels"
            )
        fov = d.get("vertical_fov_deg")
        fov_t: tuple[float, float] | None = None
        if fov is not None:
            vals = _numbers(fov, 2, path, "lidar.vertical_fov_deg")
            if not -90.0 <= vals[0] <= vals[1] <= 90.0:
                raise SequenceError(
                    f"expected -90 <= lowest <= highest <= 90, got {vals}",
                    path,
                    "lidar.vertical_fov_deg",
                )
            fov_t = (vals[0], vals[1])
        positives: dict[str, float | None] = {}
        for key in ("azimuth_step_deg", "rate_hz", "max_range_m"):
            value = d.get(key)
            if value is not None:
                value = _number(value, path, f"lidar.{key}")
                if value <= 0:
                    raise SequenceError(f"must be positive, got {value}", path, f"lidar.{key}")
            positives[key] = value
        known = {
            "model",
            "channels",
            "vertical_fov_deg",
            "azimuth_step_deg",
            "rate_hz",
            "max_range_m",
        }
        extra = {k: v for k, v in d.items() if k not in known}
        return cls(model, channels, fov_t, extra=extra, **positives)  # type: ignore[arg-type]


#: A Velodyne VLP-16 as ConSLAM used it (and the simulator imitates).
VLP16 = LidarInfo(
    model="VLP-16",
    channels=16,
    vertical_fov_deg=(-15.0, 15.0),
    azimuth_step_deg=0.2,
    rate_hz=10.0,
    max_range_m=100.0,
)


@dataclass(frozen=True)
class FrameInfo:
    """One frame of a sequence: its timestamp and the paths of its files, relative to the root.

    Attributes
    ----------
    index: position of the frame in the manifest's frame list (0-based).
    timestamp: seconds.
    image: path of the RGB image.
    lidar: path of the LiDAR scan.
    labels: path of the label image, or None.
    depth: path of the depth array, or None.
    labels_gt: path of the true label image when ``labels`` holds noisy ones (the simulator's
        label noise), or None.
    """

    index: int
    timestamp: float
    image: str
    lidar: str
    labels: str | None = None
    depth: str | None = None
    labels_gt: str | None = None

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "timestamp": self.timestamp,
            "image": self.image,
            "lidar": self.lidar,
            "labels": self.labels,
            "depth": self.depth,
        }
        if self.labels_gt is not None:
            d["labels_gt"] = self.labels_gt
        return d


# --------------------------------------------------------------------------- the sequence
@dataclass
class Sequence:
    """A validated sequence directory; pixels and points are loaded on demand.

    Attributes
    ----------
    root: the sequence directory.
    camera: the raw (distorted) camera.
    cam_from_lidar: (7,) float64 TUM-order pose mapping LiDAR points into the camera frame.
    lidar: the LiDAR model.
    frames: the frames, in time order (``frames[i].index`` is the manifest position).
    ifc_path: the IFC file (resolved against ``root`` if relative), or None.
    poses: trajectory name → path relative to ``root`` (e.g. ``{"gt": "poses/gt.tum"}``).
    source: free-form provenance from the manifest.
    """

    root: Path
    camera: Camera
    cam_from_lidar: NDArray[np.float64]
    lidar: LidarInfo
    frames: list[FrameInfo]
    ifc_path: Path | None = None
    poses: dict[str, str] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def timestamps(self) -> NDArray[np.float64]:
        """(N,) frame timestamps in seconds."""
        return np.array([f.timestamp for f in self.frames], dtype=np.float64)

    @property
    def has_labels(self) -> bool:
        """True if every frame has a label image."""
        return bool(self.frames) and all(f.labels is not None for f in self.frames)

    @property
    def has_depth(self) -> bool:
        """True if every frame has a ground-truth depth array."""
        return bool(self.frames) and all(f.depth is not None for f in self.frames)

    # ------------------------------------------------------------------ loading
    def load_image(self, i: int) -> NDArray[np.uint8]:
        """The raw RGB image of frame ``i``, shape (H, W, 3) uint8, channels R, G, B."""
        path = self.root / self.frames[i].image
        where = f"frames[{self.frames[i].index}].image"
        image = _read_image(path, rgb=True)
        if image is None:
            raise SequenceError("cannot decode image", path, where)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise SequenceError(
                f"expected an 8-bit 3-channel image, got shape {image.shape} dtype {image.dtype}",
                path,
                where,
            )
        self._check_size(image.shape[:2], path, where)
        return image

    def load_lidar(self, i: int) -> NDArray[np.float32]:
        """The LiDAR scan of frame ``i``: (M, 4) float32 ``x y z intensity`` in the LiDAR frame."""
        path = self.root / self.frames[i].lidar
        data = path.read_bytes()
        if len(data) % LIDAR_POINT_BYTES:
            raise SequenceError(
                f"size {len(data)} bytes is not a multiple of {LIDAR_POINT_BYTES} "
                "(x y z intensity float32)",
                path,
                f"frames[{self.frames[i].index}].lidar",
            )
        return np.frombuffer(data, dtype=_LIDAR_DTYPE).reshape(-1, 4).astype(np.float32)

    def load_labels(self, i: int, truth: bool = False) -> NDArray[np.uint8] | None:
        """The label image of frame ``i`` (H, W) uint8 ids of :class:`Label`, or None.

        With ``truth``, the true labels: ``labels_gt`` when the sequence has them (``labels``
        then holds noisy ones), else ``labels``.
        """
        key = "labels_gt" if truth and self.frames[i].labels_gt is not None else "labels"
        rel = getattr(self.frames[i], key)
        if rel is None:
            return None
        path = self.root / rel
        where = f"frames[{self.frames[i].index}].{key}"
        lab = _read_image(path)
        if lab is None:
            raise SequenceError("cannot decode label image", path, where)
        if lab.dtype != np.uint8 or lab.ndim != 2:
            raise SequenceError(
                f"expected a single-channel uint8 image, got shape {lab.shape} dtype {lab.dtype}",
                path,
                where,
            )
        self._check_size(lab.shape, path, where)
        return lab

    def load_depth(self, i: int) -> NDArray[np.float32] | None:
        """The ground-truth z-depth of frame ``i`` (H, W) float32 metres (0 = unknown), or None."""
        rel = self.frames[i].depth
        if rel is None:
            return None
        path = self.root / rel
        where = f"frames[{self.frames[i].index}].depth"
        try:
            depth = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise SequenceError(f"cannot read depth array ({exc})", path, where) from None
        if depth.dtype != np.float32 or depth.ndim != 2:
            raise SequenceError(
                f"expected a 2-D float32 array, got shape {depth.shape} dtype {depth.dtype}",
                path,
                where,
            )
        self._check_size(depth.shape, path, where)
        return depth

    def _check_size(self, shape: tuple[int, ...], path: Path, where: str) -> None:
        want = (self.camera.height, self.camera.width)
        if tuple(shape[:2]) != want:
            raise SequenceError(
                f"size {shape[1]}x{shape[0]} differs from the camera's "
                f"{self.camera.width}x{self.camera.height}",
                path,
                where,
            )

    # ------------------------------------------------------------------ poses
    def has_trajectory(self, name: str) -> bool:
        """True if the manifest lists trajectory ``name`` or ``poses/NAME.tum`` exists."""
        return name in self.poses or (self.root / "poses" / f"{name}.tum").is_file()

    def trajectory_path(self, name: str) -> Path:
        """The file of trajectory ``name``: the manifest's entry, else ``poses/NAME.tum``."""
        rel = self.poses.get(name, f"poses/{name}.tum")
        return self.root / rel

    def trajectory(self, name: str = "gt") -> Trajectory:
        """Trajectory ``name`` (``world_from_cam``), one pose per frame of this sequence.

        Raises
        ------
        SequenceError
            If the file is missing, malformed, or does not have one pose per frame with the
            frames' timestamps.
        """
        path = self.trajectory_path(name)
        traj = _read_frame_trajectory(path, self._all_timestamps, f"poses.{name}")
        return traj.subset(np.array([f.index for f in self.frames], dtype=np.int64))

    # ------------------------------------------------------------------ views
    def subset(self, frames: Iterable[int] | slice) -> Sequence:
        """A view on some frames (positions into ``self.frames``), in increasing time order.

        Files stay where they are; :meth:`trajectory` returns the matching poses.
        """
        if isinstance(frames, slice):
            picked = self.frames[frames]
        else:
            n = len(self.frames)
            idx = [int(i) for i in frames]
            if any(not -n <= i < n for i in idx):
                raise SequenceError(
                    f"subset index out of range for {n} frames", self.root, "frames"
                )
            idx = [i % n for i in idx]
            if any(b <= a for a, b in itertools.pairwise(idx)):
                raise SequenceError(
                    "subset frame indices must increase strictly", self.root, "frames"
                )
            picked = [self.frames[i] for i in idx]
        view = replace(self, frames=list(picked))
        view._all_timestamps = self._all_timestamps
        return view

    def __post_init__(self) -> None:
        self.cam_from_lidar = np.asarray(self.cam_from_lidar, dtype=np.float64).reshape(7)
        # Timestamps of *all* manifest frames, used to validate trajectory files of subsets.
        self._all_timestamps = self.timestamps


# --------------------------------------------------------------------------- reading
def _read_image(path: Path, rgb: bool = False) -> NDArray[np.uint8] | None:
    """``cv2.imread(path, cv2.IMREAD_UNCHANGED)``, None where it gives None; with ``rgb`` a
    3-channel image's channels are R, G, B (not OpenCV's B, G, R).

    8-bit grey and RGB PNGs (the simulator's images and labels) are read by
    :func:`bimcap.io.png.read_png` (the same pixels, ~2× cheaper than OpenCV's decoder and
    channel swap: docs/speed.md, "Exact cuts in compiled code"); everything else, and a file
    that cannot be opened, by OpenCV.
    """
    import cv2

    try:
        image = read_png(path)
    except OSError:
        image = None
    if image is not None:
        if image.ndim == 3 and not rgb:
            image = np.ascontiguousarray(image[:, :, ::-1])
        return image
    decoded = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if decoded is not None and rgb and decoded.ndim == 3 and decoded.shape[2] == 3:
        # the channels swapped: decoded[:, :, ::-1]'s bytes, ~20× faster than copying that view
        decoded = cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)
    return None if decoded is None else np.asarray(decoded)


def read_sequence(path: str | PathLike[str]) -> Sequence:
    """Open and validate a sequence directory (or its ``manifest.json``).

    Checks: JSON syntax; ``format``/``version``; every required key and its type; the camera;
    ``cam_from_lidar`` (7 finite numbers, unit quaternion); the LiDAR object; frames (at least
    one, strictly increasing finite timestamps, relative paths inside the directory, every file
    present, every LiDAR file a multiple of 16 bytes); every trajectory in ``poses`` (readable,
    one pose per frame, matching timestamps). Images, labels and depth are only decoded when
    loaded (their size is checked then).

    Raises
    ------
    SequenceError
        Naming the manifest (or offending file) and the field.
    """
    p = Path(path)
    root, manifest_path = (p.parent, p) if p.name == MANIFEST and p.is_file() else (p, p / MANIFEST)
    if not root.is_dir():
        raise SequenceError("not a directory", root)
    if not manifest_path.is_file():
        raise SequenceError(
            "no manifest.json: not a sequence directory (or unfinished)", manifest_path
        )
    try:
        doc = json.loads(manifest_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SequenceError(f"not valid JSON ({exc})", manifest_path) from None
    if not isinstance(doc, dict):
        raise SequenceError("the manifest must be a JSON object", manifest_path)
    mp = manifest_path

    for key in ("format", "version", "camera", "cam_from_lidar", "lidar", "frames"):
        if key not in doc:
            raise SequenceError("missing required key", mp, key)
    if doc["format"] != FORMAT:
        raise SequenceError(f"expected {FORMAT!r}, got {doc['format']!r}", mp, "format")
    version = doc["version"]
    if not isinstance(version, int) or isinstance(version, bool) or version != VERSION:
        raise SequenceError(
            f"unsupported version {version!r}; this bimcap reads version {VERSION}", mp, "version"
        )

    camera = _parse_camera(doc["camera"], mp)
    cam_from_lidar = _parse_pose(doc["cam_from_lidar"], mp, "cam_from_lidar")
    lidar = LidarInfo.from_dict(doc["lidar"], mp)

    ifc_path: Path | None = None
    ifc = doc.get("ifc")
    if ifc is not None:
        if not isinstance(ifc, str) or not ifc:
            raise SequenceError(f"must be a path string or null, got {ifc!r}", mp, "ifc")
        ifc_path = Path(ifc) if Path(ifc).is_absolute() else root / ifc

    frames = _parse_frames(doc["frames"], root, mp)

    poses_doc = doc.get("poses", {})
    if not isinstance(poses_doc, dict):
        raise SequenceError("must be an object name -> file", mp, "poses")
    poses: dict[str, str] = {}
    for name, rel in poses_doc.items():
        poses[name] = _relative_file(rel, root, mp, f"poses.{name}")
    source = doc.get("source", {})
    if source is None:
        source = {}
    if not isinstance(source, dict):
        raise SequenceError("must be an object", mp, "source")

    seq = Sequence(root, camera, cam_from_lidar, lidar, frames, ifc_path, poses, dict(source))
    timestamps = seq.timestamps
    for name, rel in poses.items():
        _read_frame_trajectory(root / rel, timestamps, f"poses.{name}", mp)
    return seq


def _read_frame_trajectory(
    path: Path,
    timestamps: NDArray[np.float64],
    field_name: str,
    manifest: Path | None = None,
) -> Trajectory:
    if not path.is_file():
        raise SequenceError(f"trajectory file {path} does not exist", manifest or path, field_name)
    try:
        traj = read_tum(path)
    except TrajectoryError as exc:
        raise SequenceError(str(exc), manifest or path, field_name) from None
    if len(traj) != len(timestamps):
        raise SequenceError(
            f"{path.name} has {len(traj)} poses for {len(timestamps)} frames",
            manifest or path,
            field_name,
        )
    diff = np.abs(traj.timestamps - timestamps)
    if (diff > TIMESTAMP_TOLERANCE_S).any():
        i = int(np.argmax(diff))
        raise SequenceError(
            f"{path.name}: pose {i} has timestamp {float(traj.timestamps[i])!r}, "
            f"frame {i} has {float(timestamps[i])!r}",
            manifest or path,
            field_name,
        )
    return traj


def _number(value: Any, path: Path | str | PathLike[str] | None, field_name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SequenceError(f"expected a number, got {value!r}", path, field_name)
    out = float(value)
    if not math.isfinite(out):
        raise SequenceError(f"must be finite, got {value!r}", path, field_name)
    return out


def _numbers(
    value: Any, n: int, path: Path | str | PathLike[str] | None, field_name: str
) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise SequenceError(f"expected a list of {n} numbers, got {value!r}", path, field_name)
    return [_number(v, path, f"{field_name}[{k}]") for k, v in enumerate(value)]


def _parse_camera(d: Any, mp: Path) -> Camera:
    if not isinstance(d, dict):
        raise SequenceError("must be an object", mp, "camera")
    for key in ("model", "width", "height", "K"):
        if key not in d:
            raise SequenceError("missing required key", mp, f"camera.{key}")
    if d["model"] != "plumb_bob":
        raise SequenceError(
            f"only 'plumb_bob' is supported, got {d['model']!r}", mp, "camera.model"
        )
    for key in ("width", "height"):
        v = d[key]
        if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
            raise SequenceError(f"must be a positive integer, got {v!r}", mp, f"camera.{key}")
    fx, fy, cx, cy = _numbers(d["K"], 4, mp, "camera.K")
    if fx <= 0 or fy <= 0:
        raise SequenceError(f"focal lengths must be positive, got fx={fx}, fy={fy}", mp, "camera.K")
    dist = _numbers(d.get("dist", [0.0] * 5), 5, mp, "camera.dist")
    try:
        return Camera(d["width"], d["height"], fx, fy, cx, cy, tuple(dist))  # type: ignore[arg-type]
    except InputError as exc:
        raise SequenceError(str(exc), mp, "camera") from None


def _parse_pose(value: Any, mp: Path, field_name: str) -> NDArray[np.float64]:
    vals = np.array(_numbers(value, 7, mp, field_name))
    norm = float(np.linalg.norm(vals[3:]))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise SequenceError(
            f"quaternion [qx, qy, qz, qw] has norm {norm:.9g}, expected 1", mp, field_name
        )
    vals[3:] /= norm
    return vals


def _relative_file(rel: Any, root: Path, mp: Path, field_name: str) -> str:
    """Check that ``rel`` is a relative POSIX path inside ``root`` naming an existing file."""
    if not isinstance(rel, str) or not rel:
        raise SequenceError(f"expected a relative file path, got {rel!r}", mp, field_name)
    pp = PurePosixPath(rel)
    if pp.is_absolute() or ".." in pp.parts or "\\" in rel:
        raise SequenceError(
            f"{rel!r} must be a relative path inside the sequence directory", mp, field_name
        )
    if not (root / rel).is_file():
        raise SequenceError(f"file {rel} does not exist", mp, field_name)
    return rel


def _parse_frames(value: Any, root: Path, mp: Path) -> list[FrameInfo]:
    if not isinstance(value, list) or not value:
        raise SequenceError("expected a non-empty list of frames", mp, "frames")
    frames: list[FrameInfo] = []
    previous = -math.inf
    for i, f in enumerate(value):
        where = f"frames[{i}]"
        if not isinstance(f, dict):
            raise SequenceError("must be an object", mp, where)
        for key in ("timestamp", "image", "lidar"):
            if key not in f:
                raise SequenceError("missing required key", mp, f"{where}.{key}")
        t = _number(f["timestamp"], mp, f"{where}.timestamp")
        if t <= previous:
            raise SequenceError(
                f"timestamps must increase strictly: {t!r} follows {previous!r}",
                mp,
                f"{where}.timestamp",
            )
        previous = t
        image = _relative_file(f["image"], root, mp, f"{where}.image")
        lidar = _relative_file(f["lidar"], root, mp, f"{where}.lidar")
        size = (root / lidar).stat().st_size
        if size % LIDAR_POINT_BYTES:
            raise SequenceError(
                f"{lidar} has {size} bytes, not a multiple of {LIDAR_POINT_BYTES} "
                "(x y z intensity float32)",
                mp,
                f"{where}.lidar",
            )
        labels = f.get("labels")
        if labels is not None:
            labels = _relative_file(labels, root, mp, f"{where}.labels")
        depth = f.get("depth")
        if depth is not None:
            depth = _relative_file(depth, root, mp, f"{where}.depth")
        labels_gt = f.get("labels_gt")
        if labels_gt is not None:
            labels_gt = _relative_file(labels_gt, root, mp, f"{where}.labels_gt")
        frames.append(FrameInfo(i, t, image, lidar, labels, depth, labels_gt))
    return frames


def _manifest_dict(
    camera: Camera,
    cam_from_lidar: NDArray[np.float64],
    lidar: LidarInfo,
    ifc: str | None,
    frames: list[FrameInfo],
    poses: Mapping[str, str],
    source: Mapping[str, Any],
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "version": VERSION,
        "camera": camera.to_dict(),
        "cam_from_lidar": [float(x) for x in cam_from_lidar],
        "lidar": lidar.to_dict(),
        "ifc": ifc,
        "frames": [f.to_dict() for f in frames],
        "poses": dict(poses),
        "source": dict(source),
    }


# --------------------------------------------------------------------------- writing
class SequenceWriter:
    """Write a sequence directory frame by frame; the manifest is written last by :meth:`close`.

    Every file is written atomically (:mod:`bimcap.io.atomic`). Use as a context manager: on a
    normal exit the sequence is closed (trajectories and manifest written); on an exception
    nothing more is written and no manifest appears.

    Parameters
    ----------
    root:
        The sequence directory; created if needed.
    camera:
        The raw (distorted) camera; images must be ``camera.height × camera.width``.
    cam_from_lidar:
        (7,) TUM-order pose mapping LiDAR points into the camera frame.
    lidar:
        The LiDAR model (default: :data:`VLP16`).
    ifc:
        The IFC file, stored relative to ``root`` when given relative (as it is) or absolute.
    source:
        Free-form provenance (JSON-serialisable), e.g. simulator settings and seed.
    overwrite:
        Allow writing into a directory that already holds a ``manifest.json``.
    png_compression:
        OpenCV PNG compression level 0-9 for images and labels (None = OpenCV's default).

    Examples
    --------
    >>> with SequenceWriter(out, camera, cam_from_lidar) as w:          # doctest: +SKIP
    ...     for t, rgb, scan in frames:
    ...         w.add_frame(t, rgb, scan)
    ...     w.add_trajectory("gt", world_from_cam)                   # (N, 7)
    """

    def __init__(
        self,
        root: str | PathLike[str],
        camera: Camera,
        cam_from_lidar: ArrayLike,
        lidar: LidarInfo | None = None,
        ifc: str | PathLike[str] | None = None,
        source: Mapping[str, Any] | None = None,
        overwrite: bool = False,
        png_compression: int | None = None,
    ) -> None:
        self.root = Path(root)
        self.png_compression = png_compression
        self.camera = camera
        pose = np.asarray(cam_from_lidar, dtype=np.float64)
        if pose.shape != (7,) or not np.isfinite(pose).all():
            raise SequenceError(f"expected 7 finite numbers, got {pose!r}", field="cam_from_lidar")
        norm = float(np.linalg.norm(pose[3:]))
        if abs(norm - 1.0) > 1e-3:
            raise SequenceError(f"quaternion norm {norm:.6g}, expected 1", field="cam_from_lidar")
        pose[3:] /= norm
        self.cam_from_lidar = pose
        self.lidar = VLP16 if lidar is None else lidar
        self.ifc = None if ifc is None else os.fspath(ifc)
        self.source = dict(source or {})
        if (self.root / MANIFEST).exists() and not overwrite:
            raise SequenceError(
                "already a sequence directory (pass overwrite=True to replace it)",
                self.root / MANIFEST,
            )
        self.root.mkdir(parents=True, exist_ok=True)
        self.frames: list[FrameInfo] = []
        self._trajectories: dict[str, NDArray[np.float64]] = {}
        self._trajectory_times: dict[str, NDArray[np.float64]] = {}
        self._closed = False

    # ------------------------------------------------------------------ frames
    def add_frame(
        self,
        timestamp: float,
        image: NDArray[np.uint8],
        lidar: ArrayLike,
        labels: NDArray[np.uint8] | None = None,
        depth: NDArray[np.floating[Any]] | None = None,
    ) -> FrameInfo:
        """Write one frame's files (see :func:`write_frame`) and remember it for the manifest.

        Parameters
        ----------
        timestamp: seconds, larger than the previous frame's.
        image: (H, W, 3) uint8 RGB raw image.
        lidar: (M, 4) float ``x y z intensity`` in the LiDAR frame (stored as float32); M may be 0.
        labels: (H, W) uint8 label ids (``<= max(Label)``), or None.
        depth: (H, W) float z-depth in metres, finite and >= 0 (0 = unknown), or None.

        Raises
        ------
        SequenceError
            On a timestamp out of order, a wrong shape or dtype, or a closed writer.
        """
        self._check_next(float(timestamp))
        info = write_frame(
            self.root,
            len(self.frames),
            timestamp,
            self.camera,
            image,
            lidar,
            labels,
            depth,
            png_compression=self.png_compression,
        )
        self.frames.append(info)
        return info

    def register_frame(self, info: FrameInfo) -> None:
        """Record a frame whose files were written elsewhere, e.g. by :func:`write_frame` in a
        worker process. Frames must be registered in order: ``info.index == len(frames)``.
        """
        if info.index != len(self.frames):
            raise SequenceError(
                f"frame {info.index} registered, expected frame {len(self.frames)}",
                self.root,
                f"frames[{info.index}]",
            )
        self._check_next(info.timestamp)
        for key in ("image", "lidar", "labels", "depth", "labels_gt"):
            rel = getattr(info, key)
            if rel is not None:
                _relative_file(rel, self.root, self.root, f"frames[{info.index}].{key}")
        self.frames.append(info)

    def _check_next(self, t: float) -> None:
        if self._closed:
            raise SequenceError("the writer is closed", self.root)
        where = f"frames[{len(self.frames)}].timestamp"
        if not math.isfinite(t):
            raise SequenceError(f"timestamp must be finite, got {t!r}", self.root, where)
        if self.frames and t <= self.frames[-1].timestamp:
            raise SequenceError(
                f"timestamp {t!r} does not follow {self.frames[-1].timestamp!r}: frames must be "
                "added in strictly increasing time order",
                self.root,
                where,
            )

    # ------------------------------------------------------------------ poses
    def add_trajectory(self, name: str, world_from_cam: Trajectory | ArrayLike) -> None:
        """Register trajectory ``name`` (written to ``poses/NAME.tum`` on :meth:`close`).

        ``world_from_cam`` is a (N, 7) TUM-order array (the frames' timestamps are used) or a
        :class:`Trajectory` whose timestamps must equal the frames'. N is checked on close.
        """
        if not name or not all(c.isalnum() or c in "_-." for c in name):
            raise SequenceError(f"bad trajectory name {name!r}", self.root, "poses")
        if isinstance(world_from_cam, Trajectory):
            self._trajectories[name] = world_from_cam.poses.copy()
            self._trajectory_times[name] = world_from_cam.timestamps.copy()
            return
        poses = np.array(world_from_cam, dtype=np.float64)
        try:
            Trajectory(np.arange(len(poses), dtype=np.float64), poses)
        except TrajectoryError as exc:
            raise SequenceError(str(exc), self.root, f"poses.{name}") from None
        self._trajectories[name] = poses
        self._trajectory_times.pop(name, None)

    # ------------------------------------------------------------------ finish
    def close(self) -> Sequence:
        """Write the trajectories and then the manifest; return the sequence as read back."""
        if self._closed:
            raise SequenceError("the writer is already closed", self.root)
        if not self.frames:
            raise SequenceError("no frames were added", self.root, "frames")
        timestamps = np.array([f.timestamp for f in self.frames])
        times = self._trajectory_times
        poses_map: dict[str, str] = {}
        for name, poses in self._trajectories.items():
            if len(poses) != len(timestamps):
                raise SequenceError(
                    f"{len(poses)} poses for {len(timestamps)} frames", self.root, f"poses.{name}"
                )
            if name in times and (np.abs(times[name] - timestamps) > TIMESTAMP_TOLERANCE_S).any():
                raise SequenceError(
                    "trajectory timestamps differ from the frames'", self.root, f"poses.{name}"
                )
            rel = f"poses/{name}.tum"
            write_tum(self.root / rel, Trajectory(timestamps, poses), header="world_from_cam")
            poses_map[name] = rel
        doc = _manifest_dict(
            self.camera,
            self.cam_from_lidar,
            self.lidar,
            self.ifc,
            self.frames,
            poses_map,
            self.source,
        )
        atomic_write_json(self.root / MANIFEST, doc)
        self._closed = True
        return read_sequence(self.root)

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None and not self._closed:
            self.close()
        else:
            self._closed = True


def frame_info(
    index: int, timestamp: float, labels: bool = False, depth: bool = False,
    labels_gt: bool = False,
) -> FrameInfo:
    """The standard file names of frame ``index`` (``images/NNNNNN.png`` etc.)."""
    name = f"{index:06d}"
    return FrameInfo(
        index,
        float(timestamp),
        f"images/{name}.png",
        f"lidar/{name}.bin",
        f"labels/{name}.png" if labels else None,
        f"depth/{name}.npy" if depth else None,
        f"labels_gt/{name}.png" if labels_gt else None,
    )


@dataclass(frozen=True)
class _FrameArrays:
    """One frame's checked arrays: image (H, W, 3) uint8 RGB, lidar (M, 4) float, labels and
    labels_gt (H, W) uint8 or None, depth (H, W) float32 metres or None."""

    image: NDArray[np.uint8]
    lidar: NDArray[Any]
    labels: NDArray[np.uint8] | None
    labels_gt: NDArray[np.uint8] | None
    depth: NDArray[np.float32] | None


def _checked_image(image: NDArray[np.uint8], hw: tuple[int, int], out: Path,
                   where: str) -> NDArray[np.uint8]:
    """The (H, W, 3) uint8 RGB image, or a :class:`SequenceError` naming ``where.image``."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.shape != (*hw, 3):
        raise SequenceError(
            f"expected a {(*hw, 3)} uint8 RGB image, got {img.shape} {img.dtype}",
            out,
            f"{where}.image",
        )
    return img


def _checked_lidar(lidar: ArrayLike, out: Path, where: str) -> NDArray[Any]:
    """The (M, 4) float scan, or a :class:`SequenceError` naming ``where.lidar``."""
    pts = np.asarray(lidar)
    if pts.ndim != 2 or pts.shape[1] != 4 or not np.issubdtype(pts.dtype, np.floating):
        raise SequenceError(
            f"expected (M, 4) float x y z intensity, got {pts.shape} {pts.dtype}",
            out,
            f"{where}.lidar",
        )
    return pts


def _checked_labels(value: NDArray[np.uint8] | None, hw: tuple[int, int], out: Path,
                    where: str) -> NDArray[np.uint8] | None:
    """The (H, W) uint8 label ids (None stays None), or a :class:`SequenceError` naming
    ``where`` (e.g. ``frames[3].labels``)."""
    if value is None:
        return None
    lab = np.asarray(value)
    if lab.dtype != np.uint8 or lab.shape != hw:
        raise SequenceError(
            f"expected a {hw} uint8 label image, got {lab.shape} {lab.dtype}", out, where
        )
    if lab.size and int(lab.max()) > max(Label):
        raise SequenceError(f"label id {int(lab.max())} is not a bimcap.labels.Label", out, where)
    return lab


def _checked_depth(depth: NDArray[np.floating[Any]] | None, hw: tuple[int, int], out: Path,
                   where: str) -> NDArray[np.float32] | None:
    """The (H, W) float32 depth in metres (None stays None), or a :class:`SequenceError`
    naming ``where.depth``."""
    if depth is None:
        return None
    dep = np.asarray(depth)
    if not np.issubdtype(dep.dtype, np.floating) or dep.shape != hw:
        raise SequenceError(
            f"expected a {hw} float depth image, got {dep.shape} {dep.dtype}",
            out,
            f"{where}.depth",
        )
    dep = dep.astype(np.float32)
    if not np.isfinite(dep).all() or (dep < 0).any():
        raise SequenceError("depth must be finite and >= 0", out, f"{where}.depth")
    return dep


def _write_frame_files(out: Path, info: FrameInfo, arrays: _FrameArrays,
                       png_compression: int | None) -> None:
    """Write the files ``info`` names (relative to ``out``) atomically."""
    import cv2

    params = [] if png_compression is None else [cv2.IMWRITE_PNG_COMPRESSION, int(png_compression)]
    atomic_write_bytes(out / info.image, _encode_png(cv2, arrays.image[:, :, ::-1], params))
    atomic_write_bytes(out / info.lidar, arrays.lidar.astype(_LIDAR_DTYPE).tobytes())
    if arrays.labels is not None and info.labels is not None:
        atomic_write_bytes(out / info.labels, _encode_png(cv2, arrays.labels, params))
    if arrays.labels_gt is not None and info.labels_gt is not None:
        atomic_write_bytes(out / info.labels_gt, _encode_png(cv2, arrays.labels_gt, params))
    if arrays.depth is not None and info.depth is not None:
        buf = io.BytesIO()
        np.save(buf, arrays.depth, allow_pickle=False)
        atomic_write_bytes(out / info.depth, buf.getvalue())


def write_frame(
    root: str | PathLike[str],
    index: int,
    timestamp: float,
    camera: Camera,
    image: NDArray[np.uint8],
    lidar: ArrayLike,
    labels: NDArray[np.uint8] | None = None,
    depth: NDArray[np.floating[Any]] | None = None,
    png_compression: int | None = None,
    labels_gt: NDArray[np.uint8] | None = None,
) -> FrameInfo:
    """Check and write the files of frame ``index`` atomically; return its :class:`FrameInfo`.

    Stateless (safe in worker processes); :meth:`SequenceWriter.register_frame` then adds the
    returned info in order. Arguments as in :meth:`SequenceWriter.add_frame`; ``png_compression``
    is OpenCV's PNG level 0-9 (None = OpenCV's default); ``labels_gt`` (H, W) uint8 the true
    labels when ``labels`` are noisy (written to ``labels_gt/``; needs ``labels``).

    Raises
    ------
    SequenceError
        On a wrong shape, dtype or value (naming ``frames[index].<file>``).
    """
    out = Path(root)
    where = f"frames[{index}]"
    hw = (camera.height, camera.width)
    img = _checked_image(image, hw, out, where)
    pts = _checked_lidar(lidar, out, where)
    lab = _checked_labels(labels, hw, out, f"{where}.labels")
    lab_gt = _checked_labels(labels_gt, hw, out, f"{where}.labels_gt")
    if lab_gt is not None and lab is None:
        raise SequenceError("true labels given without labels", out, f"{where}.labels_gt")
    dep = _checked_depth(depth, hw, out, where)
    info = frame_info(index, timestamp, lab is not None, dep is not None, lab_gt is not None)
    arrays = _FrameArrays(image=img, lidar=pts, labels=lab, labels_gt=lab_gt, depth=dep)
    _write_frame_files(out, info, arrays, png_compression)
    return info


def _encode_png(cv2: Any, array: NDArray[np.uint8], params: list[int] | None = None) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(array), params or [])
    if not ok:
        raise SequenceError("PNG encoding failed")
    return bytes(buf.tobytes())


# --------------------------------------------------------------------------- editing
def add_trajectory(
    seq: Sequence | str | PathLike[str],
    name: str,
    trajectory: Trajectory,
    header: str | None = None,
    overwrite: bool = False,
) -> Path:
    """Write ``poses/NAME.tum`` into an existing sequence and list it in the manifest.

    The trajectory must have one pose per frame with the frames' timestamps. The TUM file is
    written first, then the manifest is rewritten atomically with the new ``poses`` entry.
    ``gt`` can never be replaced; other names only with ``overwrite=True``.

    Returns
    -------
    The path of the TUM file written.
    """
    s = read_sequence(seq.root if isinstance(seq, Sequence) else seq)
    if not name or not all(c.isalnum() or c in "_-." for c in name):
        raise SequenceError(f"bad trajectory name {name!r}", s.manifest_path, "poses")
    target = s.trajectory_path(name)
    if name == "gt":
        raise SequenceError("refusing to overwrite the ground truth", target, "poses.gt")
    if target.exists() and not overwrite:
        raise SequenceError("already exists (use overwrite / --overwrite)", target, f"poses.{name}")
    if (
        len(trajectory) != len(s.frames)
        or (np.abs(trajectory.timestamps - s.timestamps) > TIMESTAMP_TOLERANCE_S).any()
    ):
        raise SequenceError(
            f"needs one pose per frame with the frames' timestamps ({len(s.frames)} frames, "
            f"{len(trajectory)} poses)",
            target,
            f"poses.{name}",
        )
    write_tum(target, trajectory, header=header)
    doc = json.loads(s.manifest_path.read_text(encoding="utf-8"))
    doc.setdefault("poses", {})[name] = target.relative_to(s.root).as_posix()
    atomic_write_json(s.manifest_path, doc)
    return target
