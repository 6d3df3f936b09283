"""The solver problem: every input of one solve as named dense arrays.

See ``docs/architecture.md`` ("Solver problem") for the table. Poses are ``world_from_cam`` in TUM
order ``[tx, ty, tz, qx, qy, qz, qw]``; the camera frame is OpenCV optical; pixels are
undistorted pinhole ``(u, v) = (column, row)``; metres throughout.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from os import PathLike
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.labels import Label
from bimcap.optimize.errors import SolverInputError

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]

#: name → (dtype, number of columns or 0 for 1-D, required)
FIELDS: dict[str, tuple[type, int, bool]] = {
    "poses": (np.float64, 7, True),
    "timestamps": (np.float64, 0, True),
    "pose_fixed": (np.int32, 0, True),
    "cameras": (np.float64, 4, True),
    "frame_camera": (np.int32, 0, True),
    "match_frames": (np.int32, 2, False),
    "match_uv": (np.float64, 4, False),
    "match_depth": (np.float64, 2, False),
    "track_obs_frame": (np.int32, 0, False),
    "track_obs_point": (np.int32, 0, False),
    "track_obs_uv": (np.float64, 2, False),
    "track_obs_depth": (np.float64, 0, False),
    "track_points": (np.float64, 3, False),
    "floor_frame": (np.int32, 0, False),
    "floor_p_in_cam": (np.float64, 3, False),
    "floor_plane": (np.int32, 0, False),
    "ceiling_frame": (np.int32, 0, False),
    "ceiling_p_in_cam": (np.float64, 3, False),
    "ceiling_plane": (np.int32, 0, False),
    "planes": (np.float64, 4, False),
    "wall_frame": (np.int32, 0, False),
    "wall_p_in_cam": (np.float64, 3, False),
    "column_frame": (np.int32, 0, False),
    "column_p_in_cam": (np.float64, 3, False),
    "segments": (np.float64, 4, False),
    "segment_class": (np.int32, 0, False),
    "segment_z": (np.float64, 2, False),
    "segment_normal": (np.float64, 2, False),
}


def _empty(name: str) -> NDArray[Any]:
    dtype, cols, _ = FIELDS[name]
    return np.zeros((0, cols) if cols else (0,), dtype=dtype)


def _f(name: str) -> Any:
    return field(default_factory=lambda: _empty(name))


@dataclass
class Problem:
    """All arrays of one solve; validated and normalised (C-contiguous float64 / int32) on creation.

    Attributes
    ----------
    poses: (N, 7) initial world_from_cam, TUM order. timestamps: (N,) seconds.
    pose_fixed: (N,) int32, 1 = held constant. cameras: (C, 4) pinhole fx fy cx cy (pixels).
    frame_camera: (N,) int32 camera of each frame.
    match_frames (M, 2) i32, match_uv (M, 4) [ua va ub vb] px, match_depth (M, 2) m (<= 0 unknown):
        G as point consistency / reprojection.
    track_obs_frame (K,) i32, track_obs_point (K,) i32, track_obs_uv (K, 2) px,
    track_obs_depth (K,) m (<= 0 none), track_points (P, 3) m world: G as landmark BA.
    floor_frame (F,) i32, floor_p_in_cam (F, 3) m, floor_plane (F,) i32: F; ceiling_* likewise: Ce.
    planes: (Q, 4) [nx ny nz d], unit n, signed distance n·p + d.
    wall_frame (W,) i32, wall_p_in_cam (W, 3): W; column_* likewise: Co.
    segments (S, 4) [x1 y1 x2 y2] m, segment_class (S,) i32 (1 wall, 4 column),
    segment_z (S, 2) [zmin zmax] m: the floor plan.
    segment_normal (S, 2) or (0, 2): optional free-side unit normal of each segment ((0, 0) =
        visible from both sides); when given, a wall/column point is associated only with
        segments whose free side faces its camera (no far-face / wall-thickness aliases).
    """

    poses: F64
    timestamps: F64 = _f("timestamps")
    pose_fixed: I32 = _f("pose_fixed")
    cameras: F64 = _f("cameras")
    frame_camera: I32 = _f("frame_camera")
    match_frames: I32 = _f("match_frames")
    match_uv: F64 = _f("match_uv")
    match_depth: F64 = _f("match_depth")
    track_obs_frame: I32 = _f("track_obs_frame")
    track_obs_point: I32 = _f("track_obs_point")
    track_obs_uv: F64 = _f("track_obs_uv")
    track_obs_depth: F64 = _f("track_obs_depth")
    track_points: F64 = _f("track_points")
    floor_frame: I32 = _f("floor_frame")
    floor_p_in_cam: F64 = _f("floor_p_in_cam")
    floor_plane: I32 = _f("floor_plane")
    ceiling_frame: I32 = _f("ceiling_frame")
    ceiling_p_in_cam: F64 = _f("ceiling_p_in_cam")
    ceiling_plane: I32 = _f("ceiling_plane")
    planes: F64 = _f("planes")
    wall_frame: I32 = _f("wall_frame")
    wall_p_in_cam: F64 = _f("wall_p_in_cam")
    column_frame: I32 = _f("column_frame")
    column_p_in_cam: F64 = _f("column_p_in_cam")
    segments: F64 = _f("segments")
    segment_class: I32 = _f("segment_class")
    segment_z: F64 = _f("segment_z")
    segment_normal: F64 = _f("segment_normal")

    def __post_init__(self) -> None:
        n = len(np.asarray(self.poses)) if np.ndim(self.poses) == 2 else 0
        # Defaults that depend on N: timestamps 0..N-1, nothing fixed, one camera for all.
        if np.size(self.timestamps) == 0 and n:
            self.timestamps = np.arange(n, dtype=np.float64)
        if np.size(self.pose_fixed) == 0 and n:
            self.pose_fixed = np.zeros(n, dtype=np.int32)
        if np.size(self.frame_camera) == 0 and n:
            self.frame_camera = np.zeros(n, dtype=np.int32)
        for name in FIELDS:
            setattr(self, name, _normalise(name, getattr(self, name)))
        validate_arrays(self.arrays())

    @property
    def num_poses(self) -> int:
        return int(self.poses.shape[0])

    def arrays(self) -> dict[str, NDArray[Any]]:
        """Every array by name (what ``bimcap._core.solve`` and problem files take)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_arrays(
        cls, arrays: Mapping[str, ArrayLike], path: str | PathLike[str] | None = None
    ) -> Problem:
        """Build from a dict of arrays; unknown names raise SolverInputError."""
        unknown = set(arrays) - set(FIELDS)
        if unknown:
            raise SolverInputError(f"unknown problem array(s) {sorted(unknown)}", path)
        if "poses" not in arrays:
            raise SolverInputError("required array missing", path, "poses")
        try:
            return cls(**arrays)  # type: ignore[arg-type]
        except SolverInputError as exc:
            if path is None:
                raise
            raise SolverInputError(str(exc), path) from None


def _normalise(name: str, value: ArrayLike) -> NDArray[Any]:
    dtype, cols, _ = FIELDS[name]
    arr = np.asarray(value)
    if arr.size == 0 and arr.ndim <= 2:
        return _empty(name)
    if dtype is np.int32:
        if not np.issubdtype(arr.dtype, np.integer):
            raise SolverInputError(f"expected an integer array, got dtype {arr.dtype}", field=name)
        if arr.size and (arr.min() < np.iinfo(np.int32).min or arr.max() > np.iinfo(np.int32).max):
            raise SolverInputError("values do not fit in int32", field=name)
    elif not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise SolverInputError(f"expected a real array, got dtype {arr.dtype}", field=name)
    want_ndim = 2 if cols else 1
    if arr.ndim != want_ndim or (cols and arr.shape[1] != cols):
        want = f"(n, {cols})" if cols else "(n,)"
        raise SolverInputError(f"expected shape {want}, got {arr.shape}", field=name)
    return np.ascontiguousarray(arr, dtype=dtype)


def validate_arrays(
    a: dict[str, NDArray[Any]],
    path: str | PathLike[str] | None = None,
    error: type[SolverInputError] = SolverInputError,
) -> None:
    """The checks of the C++ ``ValidateProblem``, in Python, naming the field.

    ``a`` must hold every name of :data:`FIELDS` with the right dtype and column count; the
    first problem raises ``error(message, path, field)``.
    """
    with np.errstate(all="ignore"):  # huge values from a corrupt file must not warn
        _validate(a, path, error)


def _validate(a: dict[str, NDArray[Any]], path: str | PathLike[str] | None, error: type[SolverInputError]) -> None:
    def fail(name: str, message: str) -> None:
        raise error(message, path, name)

    def rows(name: str, expected: int) -> None:
        if a[name].shape[0] != expected:
            fail(name, f"expected {expected} rows, got {a[name].shape[0]}")

    def finite(name: str) -> None:
        bad = ~np.isfinite(a[name])
        if bad.any():
            row = int(np.flatnonzero(bad.reshape(len(a[name]), -1).any(axis=1))[0])
            fail(name, f"row {row} is not finite")

    def index(name: str, upper: int) -> None:
        v = a[name]
        if v.size and (v.min() < 0 or v.max() >= upper):
            bad = (v < 0) | (v >= upper)
            row = int(np.flatnonzero(bad.reshape(len(v), -1).any(axis=1))[0])
            fail(name, f"row {row}: index {v.reshape(len(v), -1)[row].tolist()} out of range [0, {upper})")

    n = a["poses"].shape[0]
    if n < 1:
        fail("poses", "need at least one pose")
    finite("poses")
    norms = np.linalg.norm(a["poses"][:, 3:7], axis=1)
    bad = np.abs(norms - 1.0) > 1e-3
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        fail("poses", f"pose {i} has a quaternion of norm {norms[i]:.6g}, expected 1")
    for name in ("timestamps", "pose_fixed", "frame_camera"):
        rows(name, n)
    finite("timestamps")
    index("pose_fixed", 2)
    c = a["cameras"].shape[0]
    if c < 1:
        fail("cameras", "need at least one camera")
    finite("cameras")
    if (a["cameras"][:, :2] <= 0).any():
        fail("cameras", "focal lengths must be positive")
    index("frame_camera", c)

    m = a["match_frames"].shape[0]
    rows("match_uv", m)
    rows("match_depth", m)
    index("match_frames", n)
    finite("match_uv")
    finite("match_depth")
    if m and (a["match_frames"][:, 0] == a["match_frames"][:, 1]).any():
        row = int(np.flatnonzero(a["match_frames"][:, 0] == a["match_frames"][:, 1])[0])
        fail("match_frames", f"row {row} matches a frame with itself")

    k = a["track_obs_frame"].shape[0]
    for name in ("track_obs_point", "track_obs_uv", "track_obs_depth"):
        rows(name, k)
    index("track_obs_frame", n)
    index("track_obs_point", a["track_points"].shape[0])
    for name in ("track_obs_uv", "track_obs_depth", "track_points"):
        finite(name)

    q = a["planes"].shape[0]
    finite("planes")
    if q:
        pn = np.linalg.norm(a["planes"][:, :3], axis=1)
        if (np.abs(pn - 1.0) > 1e-6).any():
            i = int(np.flatnonzero(np.abs(pn - 1.0) > 1e-6)[0])
            fail("planes", f"plane {i} has a normal of norm {pn[i]:.6g}, expected 1")
    for kind in ("floor", "ceiling", "wall", "column"):
        f = a[f"{kind}_frame"].shape[0]
        rows(f"{kind}_p_in_cam", f)
        index(f"{kind}_frame", n)
        finite(f"{kind}_p_in_cam")
        if kind in ("floor", "ceiling"):
            rows(f"{kind}_plane", f)
            index(f"{kind}_plane", q)

    s = a["segments"].shape[0]
    rows("segment_class", s)
    rows("segment_z", s)
    finite("segments")
    finite("segment_z")
    ok = np.isin(a["segment_class"], [int(Label.WALL), int(Label.COLUMN)])
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        fail("segment_class", f"row {i}: class {int(a['segment_class'][i])} is neither 1 (wall) nor 4 (column)")
    if s and (a["segment_z"][:, 0] > a["segment_z"][:, 1]).any():
        i = int(np.flatnonzero(a["segment_z"][:, 0] > a["segment_z"][:, 1])[0])
        fail("segment_z", f"row {i}: zmin > zmax")
    if a["segment_normal"].shape[0]:
        rows("segment_normal", s)
        finite("segment_normal")
        norm = np.hypot(a["segment_normal"][:, 0], a["segment_normal"][:, 1])
        bad = (norm != 0.0) & (np.abs(norm - 1.0) > 1e-6)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            fail("segment_normal", f"row {i} has norm {norm[i]:.6g}, expected 1 or 0")
