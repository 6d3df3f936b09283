"""The solver problem: every input of one solve as named dense arrays.

See ``docs/architecture.md`` ("Solver problem") for the table. Poses are ``world_from_cam`` in TUM
order ``[tx, ty, tz, qx, qy, qz, qw]``; the camera frame is OpenCV optical; pixels are
undistorted pinhole ``(u, v) = (column, row)``; metres throughout.

One implementation: the arrays are those of the C++ core's field table (five core arrays, then
each registered term's, ``bimcap._core.problem_fields()``), and the checks are the core's
``ValidateProblem``. This module normalises dtypes and fills the defaults that depend on N.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from os import PathLike
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.optimize.errors import SolverInputError

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


@dataclass(frozen=True)
class FieldInfo:
    """One problem array of the C++ field table."""

    name: str
    dtype: type  #: np.float64 or np.int32
    cols: int  #: number of columns, 0 for a 1-D array
    required: bool
    term: str  #: the key of the term that declared it ("" for the five core arrays)


@cache
def problem_fields() -> dict[str, FieldInfo]:
    """Every problem array by name, in the core's order."""
    from bimcap.optimize.core import core

    _core = core()

    return {
        name: FieldInfo(name, np.float64 if dtype == "float64" else np.int32, int(cols),
                        bool(required), str(term))
        for name, dtype, cols, required, term in _core.problem_fields()
    }


def _empty(info: FieldInfo) -> NDArray[Any]:
    return np.zeros((0, info.cols) if info.cols else (0,), dtype=info.dtype)


class Problem:
    """All arrays of one solve; normalised (C-contiguous float64 / int32) and validated by the
    C++ core on creation. Each array reads as an attribute (``problem.floor_p_in_cam``); an
    array not given is empty.

    Core arrays: poses (N, 7) initial world_from_cam, TUM order; timestamps (N,) seconds
    (default 0..N-1); pose_fixed (N,) int32, 1 = held constant (default 0); cameras (C, 4)
    pinhole fx fy cx cy (pixels); frame_camera (N,) int32 camera of each frame (default 0).
    The terms' arrays (``problem_fields()``; docs/architecture.md):
    match_frames (M, 2) i32, match_uv (M, 4) [ua va ub vb] px, match_depth (M, 2) m (<= 0
    unknown): G as point consistency / reprojection; track_obs_frame (K,) i32, track_obs_point
    (K,) i32, track_obs_uv (K, 2) px, track_obs_depth (K,) m (<= 0 none), track_points (P, 3) m
    world: G as landmark BA; floor_frame (F,) i32, floor_p_in_cam (F, 3) m, floor_plane (F,)
    i32: F, ceiling_* likewise: Ce; planes (Q, 4) [nx ny nz d], unit n; wall_frame (W,) i32,
    wall_p_in_cam (W, 3): W, column_* likewise: Co; segments (S, 4) [x1 y1 x2 y2] m,
    segment_class (S,) i32 (1 wall, 4 column), segment_z (S, 2) [zmin zmax] m, segment_normal
    (S, 2) or (0, 2) optional free-side unit normal ((0, 0) = both sides).
    """

    def __init__(self, poses: ArrayLike, **arrays: ArrayLike) -> None:
        fields = problem_fields()
        unknown = set(arrays) - set(fields)
        if unknown:
            raise SolverInputError(f"unknown problem array(s) {sorted(unknown)}",
                                   field=sorted(unknown)[0])
        given: dict[str, ArrayLike] = {"poses": poses, **arrays}
        n = len(np.asarray(poses)) if np.ndim(poses) == 2 else 0
        # Defaults that depend on N: timestamps 0..N-1, nothing fixed, one camera for all.
        for name, default in (("timestamps", np.arange(n, dtype=np.float64)),
                              ("pose_fixed", np.zeros(n, dtype=np.int32)),
                              ("frame_camera", np.zeros(n, dtype=np.int32))):
            if np.size(given.get(name, ())) == 0 and n:
                given[name] = default
        self._arrays: dict[str, NDArray[Any]] = {
            name: _normalise(info, given[name]) if name in given else _empty(info)
            for name, info in fields.items()
        }
        validate_arrays(self._arrays)

    def __getattr__(self, name: str) -> NDArray[Any]:
        arrays = self.__dict__.get("_arrays", {})
        if name in arrays:
            return arrays[name]  # type: ignore[no-any-return]
        raise AttributeError(f"Problem has no array {name!r}")

    def __repr__(self) -> str:
        shapes = ", ".join(f"{k}={v.shape}" for k, v in self._arrays.items() if v.size)
        return f"Problem({shapes})"

    @property
    def num_poses(self) -> int:
        return int(self._arrays["poses"].shape[0])

    def arrays(self) -> dict[str, NDArray[Any]]:
        """Every array by name (what ``bimcap._core.solve`` and problem files take)."""
        return dict(self._arrays)

    def replace(self, **arrays: ArrayLike) -> Problem:
        """A copy with some arrays replaced (validated again)."""
        return Problem(**{**self._arrays, **arrays})

    @classmethod
    def from_arrays(
        cls, arrays: Mapping[str, ArrayLike], path: str | PathLike[str] | None = None
    ) -> Problem:
        """Build from a dict of arrays; unknown names raise SolverInputError."""
        unknown = set(arrays) - set(problem_fields())
        if unknown:
            raise SolverInputError(f"unknown problem array(s) {sorted(unknown)}", path)
        if "poses" not in arrays:
            raise SolverInputError("required array missing", path, "poses")
        rest = {k: v for k, v in arrays.items() if k != "poses"}
        try:
            return cls(arrays["poses"], **rest)
        except SolverInputError as exc:
            if path is None:
                raise
            raise SolverInputError(exc.message, path, exc.field) from None


def _normalise(info: FieldInfo, value: ArrayLike) -> NDArray[Any]:
    """``value`` as a C-contiguous array of the field's dtype; a wrong kind or shape raises."""
    arr = np.asarray(value)
    if arr.size == 0 and arr.ndim <= 2:
        return _empty(info)
    if info.dtype is np.int32:
        if not np.issubdtype(arr.dtype, np.integer):
            raise SolverInputError(f"expected an integer array, got dtype {arr.dtype}",
                                   field=info.name)
        if arr.min() < np.iinfo(np.int32).min or arr.max() > np.iinfo(np.int32).max:
            raise SolverInputError("values do not fit in int32", field=info.name)
    elif not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise SolverInputError(f"expected a real array, got dtype {arr.dtype}", field=info.name)
    want_ndim = 2 if info.cols else 1
    if arr.ndim != want_ndim or (info.cols and arr.shape[1] != info.cols):
        want = f"(n, {info.cols})" if info.cols else "(n,)"
        raise SolverInputError(f"expected shape {want}, got {arr.shape}", field=info.name)
    return np.ascontiguousarray(arr, dtype=info.dtype)


def validate_arrays(
    arrays: Mapping[str, NDArray[Any]],
    path: str | PathLike[str] | None = None,
    error: type[SolverInputError] = SolverInputError,
) -> None:
    """The C++ core's ``ValidateProblem``: the first problem raises ``error(message, path,
    field)``. ``arrays`` must have the field table's dtypes and column counts."""
    from bimcap.optimize.core import core

    _core = core()

    try:
        _core.validate_problem(dict(arrays))
    except (ValueError, TypeError) as exc:
        field = getattr(exc, "field", "") or None
        message = str(exc)
        if field and message.startswith(f"{field}: "):
            message = message[len(field) + 2:]
        raise error(message, path, field) from None
