"""Camera and LiDAR calibration files: ROS ``camera_info`` YAML, Kalibr camchains, extrinsics.

:func:`read_calibration` reads either camera format (told apart by their keys) and an optional
LiDAR extrinsic into a :class:`Calibration`: the raw :class:`~bimcap.geometry.camera.Camera`
and ``cam_from_lidar`` (maps LiDAR points into the camera's OpenCV optical frame).

**ROS camera_info YAML** (what ``camera_calibration`` / ``camera_info_manager`` write)::

    image_width: 640
    image_height: 480
    camera_name: cam
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob                   # or rational_polynomial with k4..k6 = 0
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}

**Kalibr camchain** (``kalibr_calibrate_cameras`` / ``kalibr_calibrate_imu_camera``), one block
per camera ``cam0``, ``cam1`` ...; only ``camera_model: pinhole`` with ``distortion_model:
radtan`` (``k1 k2 p1 p2``, which is plumb_bob with k3 = 0) is supported::

    cam0:
      camera_model: pinhole
      intrinsics: [fu, fv, pu, pv]
      distortion_model: radtan
      distortion_coeffs: [k1, k2, p1, p2]
      resolution: [width, height]
      T_cam_imu: [[...], [...], [...], [0, 0, 0, 1]]    # IMU → cam0 (imu-camera calibration)
    cam1:
      T_cn_cnm1: [[...], ...]                          # cam0 → cam1
      ...

``T_cn_cnm1`` chains the cameras: ``cam_n_from_cam0 = T_cn_cnm1(n) · … · T_cn_cnm1(1)``; a
camera without its own ``T_cam_imu`` gets ``cam_n_from_cam0 · T_cam_imu(cam0)``.

**LiDAR extrinsic** (bimcap's small YAML; the keys may also sit at the top level of the camera
file, or inside a Kalibr camera block). Exactly one of::

    T_cam_lidar: [[r00, r01, r02, tx], [r10, r11, r12, ty], [r20, r21, r22, tz], [0, 0, 0, 1]]
    T_lidar_cam: [...]     # the inverse (camera → LiDAR)
    T_imu_lidar: [...]     # LiDAR → IMU; composed with the camchain's T_cam_imu
    camera: cam0           # optional: the camchain camera T_cam_lidar / T_lidar_cam refer to

A matrix is 4×4 or 3×4 (nested lists, or 12 / 16 numbers row by row), metres; its rotation
must be one to 1e-3 and is replaced by the nearest rotation. Pixel conventions need no
conversion: ROS, Kalibr and OpenCV all put pixel (0, 0) at the centre of the top-left pixel.
Every error names the file and the field.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.dataset.sequence import SequenceError
from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import matrix_to_pose

F64 = NDArray[np.float64]

#: Keys of a LiDAR extrinsic, in the order they are looked for.
EXTRINSIC_KEYS = ("T_cam_lidar", "T_lidar_cam", "T_imu_lidar")
#: The value of ``--lidar-extrinsic`` that says the clouds are in the camera frame already.
IDENTITY = "identity"

_CAM_KEY = re.compile(r"cam\d+$")


class CalibrationError(SequenceError):
    """A calibration file that cannot be used (names the file and the field)."""


class CalibFormat(str, Enum):
    """Which kind of camera calibration file."""

    CAMERA_INFO = "camera_info"
    KALIBR = "kalibr"


@dataclass(frozen=True)
class Calibration:
    """A camera and, when given, the LiDAR → camera extrinsic.

    Attributes
    ----------
    camera: the raw (distorted) camera.
    cam_from_lidar: (7,) TUM-order pose mapping LiDAR points into the camera frame, or None.
    source: provenance (file, format, camera name, where the extrinsic came from); JSON-ready.
    """

    camera: Camera
    cam_from_lidar: F64 | None = None
    source: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "camera": self.camera.to_dict(),
            "cam_from_lidar": None if self.cam_from_lidar is None
            else [float(x) for x in self.cam_from_lidar],
            "source": dict(self.source),
        }


# --------------------------------------------------------------------------- YAML basics
def load_yaml(path: str | PathLike[str]) -> dict[str, Any]:
    """A YAML file whose top level is a mapping (raises :class:`CalibrationError`)."""
    import yaml

    p = Path(path)
    if not p.is_file():
        raise CalibrationError("no such file", p)
    text = p.read_text(encoding="utf-8", errors="replace")
    if text.startswith("%YAML:1."):  # OpenCV FileStorage header, not YAML 1.1/1.2
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CalibrationError(f"not valid YAML ({' '.join(str(exc).split())})", p) from None
    if not isinstance(doc, dict):
        raise CalibrationError(f"expected a YAML mapping, got {type(doc).__name__}", p)
    return doc


def _require(d: Mapping[str, Any], key: str, path: Path, prefix: str = "") -> Any:
    if key not in d:
        raise CalibrationError("missing", path, prefix + key)
    return d[key]


def _numbers(value: Any, path: Path, name: str, sizes: tuple[int, ...]) -> F64:
    """A flat float array of one of ``sizes`` finite numbers (nested lists are flattened)."""
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f"expected numbers, got {value!r}", path, name) from None
    if arr.size not in sizes:
        want = " or ".join(str(s) for s in sizes)
        raise CalibrationError(f"expected {want} numbers, got {arr.size}", path, name)
    if not np.isfinite(arr).all():
        raise CalibrationError("not finite", path, name)
    return arr


def _positive_int(value: Any, path: Path, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or value <= 0 \
            or int(value) != value:
        raise CalibrationError(f"expected a positive integer, got {value!r}", path, name)
    return int(value)


def _camera(w: int, h: int, k: F64, dist: F64, path: Path, name: str) -> Camera:
    d = np.zeros(5)
    d[: dist.size] = dist
    if k[0] <= 0 or k[1] <= 0:
        raise CalibrationError(f"focal lengths must be positive, got {k[:2].tolist()}", path, name)
    return Camera(w, h, float(k[0]), float(k[1]), float(k[2]), float(k[3]),
                  (float(d[0]), float(d[1]), float(d[2]), float(d[3]), float(d[4])))


def matrix_from_yaml(value: Any, path: Path, name: str) -> F64:
    """A (4, 4) rigid transform from a 4×4 or 3×4 matrix (nested or flat), rotation checked and
    orthonormalised."""
    arr = _numbers(value, path, name, (12, 16))
    m = np.eye(4)
    m[: arr.size // 4] = arr.reshape(-1, 4)
    if arr.size == 16 and not np.allclose(m[3], [0, 0, 0, 1], atol=1e-9):
        raise CalibrationError(f"last row must be 0 0 0 1, got {m[3].tolist()}", path, name)
    r = m[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-3) or np.linalg.det(r) <= 0:
        raise CalibrationError("the 3x3 block is not a rotation", path, name)
    u, _, vt = np.linalg.svd(r)
    m[:3, :3] = u @ vt
    return m


# --------------------------------------------------------------------------- camera_info
def camera_from_camera_info_yaml(doc: Mapping[str, Any], path: Path) -> Camera:
    """The camera of a ROS ``camera_info`` YAML document (see the module docstring)."""
    w = _positive_int(_require(doc, "image_width", path), path, "image_width")
    h = _positive_int(_require(doc, "image_height", path), path, "image_height")
    km = _require(doc, "camera_matrix", path)
    kdata = km.get("data") if isinstance(km, Mapping) else km
    k = _numbers(kdata, path, "camera_matrix.data", (9,))
    model = str(doc.get("distortion_model", "plumb_bob") or "plumb_bob")
    dm = doc.get("distortion_coefficients", {"data": []})
    ddata = dm.get("data", []) if isinstance(dm, Mapping) else dm
    dist = _numbers(ddata if ddata is not None else [], path, "distortion_coefficients.data",
                    (0, 4, 5, 8))
    if model == "rational_polynomial" and dist.size == 8:
        if dist[5:].any():
            raise CalibrationError(
                f"rational_polynomial with k4..k6 = {dist[5:].tolist()} is not supported "
                "(plumb_bob only)", path, "distortion_coefficients.data")
        dist = dist[:5]
    elif model not in ("plumb_bob", "rational_polynomial"):
        raise CalibrationError(f"distortion model {model!r} is not supported (plumb_bob only)",
                               path, "distortion_model")
    if dist.size == 8:
        raise CalibrationError("8 coefficients need distortion_model rational_polynomial",
                               path, "distortion_coefficients.data")
    return _camera(w, h, k[[0, 4, 2, 5]], dist, path, "camera_matrix.data")


# --------------------------------------------------------------------------- Kalibr
def _kalibr_cameras(doc: Mapping[str, Any]) -> list[str]:
    return sorted((k for k in doc if _CAM_KEY.match(str(k))), key=lambda k: int(k[3:]))


def camera_from_kalibr(doc: Mapping[str, Any], path: Path, camera: str = "cam0") -> Camera:
    """The camera ``camera`` of a Kalibr camchain document (pinhole-radtan)."""
    names = _kalibr_cameras(doc)
    if camera not in doc:
        raise CalibrationError(f"no camera {camera!r} (has {', '.join(names) or 'none'})",
                               path, camera)
    block = doc[camera]
    if not isinstance(block, Mapping):
        raise CalibrationError("expected a mapping", path, camera)
    p = f"{camera}."
    model = _require(block, "camera_model", path, p)
    if model != "pinhole":
        raise CalibrationError(f"camera model {model!r} is not supported (pinhole only)",
                               path, p + "camera_model")
    dmodel = _require(block, "distortion_model", path, p)
    if dmodel not in ("radtan", "none"):
        raise CalibrationError(
            f"distortion model {dmodel!r} is not supported (radtan only: k1 k2 p1 p2)",
            path, p + "distortion_model")
    k = _numbers(_require(block, "intrinsics", path, p), path, p + "intrinsics", (4,))
    dist = _numbers(block.get("distortion_coeffs", []), path, p + "distortion_coeffs",
                    (0, 4) if dmodel == "radtan" else (0,))
    res = _numbers(_require(block, "resolution", path, p), path, p + "resolution", (2,))
    w = _positive_int(float(res[0]), path, p + "resolution")
    h = _positive_int(float(res[1]), path, p + "resolution")
    return _camera(w, h, k, dist, path, p + "intrinsics")


def kalibr_cam_from_cam0(doc: Mapping[str, Any], path: Path, camera: str) -> F64:
    """(4, 4) ``camN_from_cam0`` from the chain of ``T_cn_cnm1`` (identity for cam0)."""
    n = int(camera[3:])
    out = np.eye(4)
    for i in range(1, n + 1):
        name = f"cam{i}"
        block = doc.get(name)
        if not isinstance(block, Mapping):
            raise CalibrationError("missing (needed for the chain of T_cn_cnm1)", path, name)
        t = matrix_from_yaml(_require(block, "T_cn_cnm1", path, f"{name}."), path,
                             f"{name}.T_cn_cnm1")
        out = t @ out
    return out


# --------------------------------------------------------------------------- extrinsics
def _extrinsic_in(d: Mapping[str, Any]) -> list[str]:
    return [k for k in EXTRINSIC_KEYS if k in d]


def extrinsic_from_mapping(
    d: Mapping[str, Any],
    path: Path,
    prefix: str = "",
    cam_from_imu: F64 | None = None,
    cam_from_named: Any = None,
) -> F64:
    """(4, 4) ``cam_from_lidar`` from a mapping holding one of :data:`EXTRINSIC_KEYS`.

    Parameters
    ----------
    d: the mapping (a whole extrinsic YAML, or a block of one).
    path, prefix: where it came from, for errors.
    cam_from_imu: (4, 4) the camera's ``T_cam_imu``, for ``T_imu_lidar``; None if unknown.
    cam_from_named: a function ``name -> (4, 4) cam_from_<name>`` for the ``camera`` key (a
        camchain); None when the file has one camera only.
    """
    keys = _extrinsic_in(d)
    if len(keys) != 1:
        raise CalibrationError(
            f"expected exactly one of {', '.join(EXTRINSIC_KEYS)}, found {len(keys)}",
            path, prefix.rstrip(".") or None)
    key = keys[0]
    m = matrix_from_yaml(d[key], path, prefix + key)
    if key == "T_imu_lidar":
        if cam_from_imu is None:
            raise CalibrationError("T_imu_lidar needs the camera's T_cam_imu (a Kalibr "
                                   "camera-IMU camchain), which is missing", path, prefix + key)
        return cam_from_imu @ m
    cam_from_lidar: F64 = m if key == "T_cam_lidar" else np.linalg.inv(m).astype(np.float64)
    named = d.get("camera")
    if named is not None:
        if cam_from_named is None:
            raise CalibrationError("a camera name needs a Kalibr camchain", path,
                                   prefix + "camera")
        cam_from_lidar = cam_from_named(str(named)) @ cam_from_lidar
    return cam_from_lidar


def read_lidar_extrinsic(path: str | PathLike[str]) -> F64:
    """``cam_from_lidar`` (7,) TUM order from an extrinsic YAML of ``T_cam_lidar`` or
    ``T_lidar_cam`` alone (``T_imu_lidar`` and ``camera`` need :func:`read_calibration`)."""
    p = Path(path)
    return matrix_to_pose(extrinsic_from_mapping(load_yaml(p), p))


# --------------------------------------------------------------------------- the reader
def detect_format(doc: Mapping[str, Any], path: Path) -> CalibFormat:
    """Which camera format ``doc`` is, by its keys."""
    if "camera_matrix" in doc or "image_width" in doc:
        return CalibFormat.CAMERA_INFO
    if _kalibr_cameras(doc):
        return CalibFormat.KALIBR
    raise CalibrationError(
        "neither a ROS camera_info YAML (image_width, camera_matrix, ...) nor a Kalibr "
        f"camchain (cam0: intrinsics, ...); top-level keys: {sorted(map(str, doc))}", path)


def read_calibration(
    path: str | PathLike[str],
    *,
    camera: str = "cam0",
    lidar_extrinsic: str | PathLike[str] | None = None,
) -> Calibration:
    """Read a camera calibration (ROS camera_info YAML or Kalibr camchain) and an extrinsic.

    Parameters
    ----------
    path: the camera file.
    camera: which camera of a Kalibr camchain (``cam0``, ``cam1``, ...).
    lidar_extrinsic: an extrinsic YAML (module docstring), or :data:`IDENTITY` (the clouds are
        in the camera frame already), or None: then the extrinsic keys are looked for in the
        camera file (its top level, then the Kalibr camera's block); ``cam_from_lidar`` is None
        when there are none.

    Raises
    ------
    CalibrationError
        Naming the file and the field: a missing or malformed field, an unsupported camera or
        distortion model, a matrix that is not a rigid transform.
    """
    p = Path(path)
    doc = load_yaml(p)
    fmt = detect_format(doc, p)
    source: dict[str, Any] = {"file": str(p), "format": fmt.value}
    cam_from_imu: F64 | None = None
    cam_from_named: Any = None
    block: Mapping[str, Any] = {}
    if fmt is CalibFormat.CAMERA_INFO:
        cam = camera_from_camera_info_yaml(doc, p)
    else:
        cam = camera_from_kalibr(doc, p, camera)
        source["camera"] = camera
        block = doc[camera]
        this_from_cam0 = kalibr_cam_from_cam0(doc, p, camera)
        if "T_cam_imu" in block:
            cam_from_imu = matrix_from_yaml(block["T_cam_imu"], p, f"{camera}.T_cam_imu")
        elif isinstance(doc.get("cam0"), Mapping) and "T_cam_imu" in doc["cam0"]:
            cam_from_imu = this_from_cam0 @ matrix_from_yaml(doc["cam0"]["T_cam_imu"], p,
                                                             "cam0.T_cam_imu")

        def this_from_named(name: str) -> F64:
            if not _CAM_KEY.match(name) or name not in doc:
                raise CalibrationError(f"no camera {name!r} in {p}", lidar_extrinsic or p,
                                       "camera")
            return this_from_cam0 @ np.linalg.inv(kalibr_cam_from_cam0(doc, p, name))

        cam_from_named = this_from_named

    extrinsic: F64 | None = None
    if lidar_extrinsic is not None and str(lidar_extrinsic) == IDENTITY:
        extrinsic = np.eye(4)
        source["extrinsic"] = IDENTITY
    elif lidar_extrinsic is not None:
        e = Path(lidar_extrinsic)
        extrinsic = extrinsic_from_mapping(load_yaml(e), e, "", cam_from_imu, cam_from_named)
        source["extrinsic"] = str(e)
    elif _extrinsic_in(doc):
        extrinsic = extrinsic_from_mapping(doc, p, "", cam_from_imu, cam_from_named)
        source["extrinsic"] = str(p)
    elif _extrinsic_in(block):
        extrinsic = extrinsic_from_mapping(block, p, f"{camera}.", cam_from_imu, cam_from_named)
        source["extrinsic"] = f"{p}:{camera}"
    pose = None if extrinsic is None else matrix_to_pose(extrinsic)
    return Calibration(cam, pose, source)


def read_extrinsic_argument(value: str | PathLike[str]) -> tuple[F64, str]:
    """``cam_from_lidar`` (7,) of an extrinsic YAML or :data:`IDENTITY`, and its label for the
    manifest (the path, or ``identity``)."""
    if str(value) == IDENTITY:
        return matrix_to_pose(np.eye(4)), IDENTITY
    return read_lidar_extrinsic(value), str(value)
