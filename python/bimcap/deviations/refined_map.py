"""The refined map as a product: every LiDAR scan of a sequence through the refined poses.

Each frame's scan (``SEQ/lidar/NNNNNN.bin``, LiDAR frame) goes into the world with
``world_from_lidar = world_from_cam[i] ∘ cam_from_lidar``; the merged returns are
voxel-downsampled (the centroid of the returns in each cubic voxel) and labelled where the front
end labelled the scene: a voxel takes the label of the nearest front-end semantic sample (the
points of ``map_after.ply``) within ``label_radius_m``, else ``Label.UNKNOWN``. The map is written
as ``map_refined.ply`` with :func:`bimcap.io.ply.write_labelled_ply` (float32 ``x y z``, RGB of the
label, ``label``), which Open3D reads as a coloured cloud.

The per-return arrays (:class:`ScanSet`: points, the frame of each return, the sensor centre of
each frame) are kept for the deviation analysis, which needs the rays, not only the points
(free space seen through an element, :mod:`bimcap.deviations.analysis`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from os import PathLike
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.geometry.local_frame import local_origin
from bimcap.geometry.poses import compose, transform_points
from bimcap.io.ply import Precision, write_labelled_ply
from bimcap.labels import Label

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
U8 = NDArray[np.uint8]

#: Default voxel edge of the refined map (metres).
DEFAULT_VOXEL_M = 0.03
#: A map voxel takes the label of a front-end sample at most this far away (metres).
DEFAULT_LABEL_RADIUS_M = 0.10


class RefinedMapError(InputError):
    """Inputs of the refined map that do not fit together (poses per frame, a storey name)."""


@dataclass
class ScanSet:
    """Every LiDAR return of a sequence in the world.

    Attributes
    ----------
    p_in_world: (R, 3) float64 returns in world metres.
    frame: (R,) int32 frame index of each return.
    origins: (N, 3) float64 sensor centre of each frame in the world (metres).
    """

    p_in_world: F64
    frame: I32
    origins: F64

    def __len__(self) -> int:
        return len(self.p_in_world)

    def subsample(self, step: int) -> ScanSet:
        """Every ``step``-th return (the ray tests need fewer rays than the map has)."""
        if step <= 1:
            return self
        return ScanSet(self.p_in_world[::step], self.frame[::step], self.origins)


def load_scans(sequence: Any, world_from_cam: F64, frames: Iterable[int] | None = None,
               min_range_m: float = 0.3, max_range_m: float | None = None) -> ScanSet:
    """The scans of ``sequence`` (a :class:`bimcap.dataset.Sequence`) in the world.

    Parameters
    ----------
    sequence: the sequence (``load_lidar``, ``cam_from_lidar``, ``frames``).
    world_from_cam: (N, 7) TUM-order poses, one per frame of the sequence.
    frames: which frames (default all).
    min_range_m, max_range_m: returns outside this range from the sensor are dropped (metres;
        no upper bound when None); so are non-finite returns.

    Raises
    ------
    RefinedMapError: ``world_from_cam`` does not hold one pose per frame.
    """
    poses = np.asarray(world_from_cam, dtype=np.float64)
    n = len(sequence.frames)
    if poses.ndim != 2 or poses.shape != (n, 7):
        raise RefinedMapError(f"expected ({n}, 7) poses (one per frame), got {poses.shape}",
                              getattr(sequence, "manifest_path", None), "world_from_cam")
    world_from_lidar = compose(poses, np.asarray(sequence.cam_from_lidar, dtype=np.float64))
    pts: list[F64] = []
    idx: list[I32] = []
    for i in (range(n) if frames is None else frames):
        scan = np.asarray(sequence.load_lidar(int(i)), dtype=np.float64)[:, :3]
        r = np.linalg.norm(scan, axis=1)
        keep = np.isfinite(r) & (r >= min_range_m)
        if max_range_m is not None:
            keep &= r <= max_range_m
        if keep.any():
            pts.append(transform_points(world_from_lidar[int(i)], scan[keep]))
            idx.append(np.full(int(keep.sum()), int(i), np.int32))
    if not pts:
        return ScanSet(np.zeros((0, 3)), np.zeros(0, np.int32), world_from_lidar[:, :3].copy())
    return ScanSet(np.concatenate(pts), np.concatenate(idx), world_from_lidar[:, :3].copy())


def voxel_downsample(points: F64, voxel_m: float) -> tuple[F64, NDArray[np.int64]]:
    """Centroid of the points in each cubic voxel of edge ``voxel_m`` (metres).

    Returns
    -------
    centroids: (V, 3) float64; inverse: (P,) index of each input point's voxel.
    """
    if voxel_m <= 0:
        raise RefinedMapError(f"must be > 0 (got {voxel_m})", field="voxel_m")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    key = np.floor((p - p.min(axis=0)) / voxel_m).astype(np.int64)
    dims = key.max(axis=0) + 1
    flat = (key[:, 0] * dims[1] + key[:, 1]) * dims[2] + key[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, p)
    return sums / counts[:, None], inverse.astype(np.int64)


def transfer_labels(points: F64, sample_points: F64, sample_labels: NDArray[np.integer],
                    radius_m: float = DEFAULT_LABEL_RADIUS_M) -> U8:
    """(P,) label of the nearest labelled sample within ``radius_m`` of each point, else
    ``Label.UNKNOWN``."""
    out = np.full(len(points), int(Label.UNKNOWN), np.uint8)
    if len(points) == 0 or len(sample_points) == 0:
        return out
    from scipy.spatial import cKDTree

    dist, nearest = cKDTree(np.asarray(sample_points)).query(points, distance_upper_bound=radius_m)
    hit = np.isfinite(dist)
    out[hit] = np.asarray(sample_labels)[nearest[hit]].astype(np.uint8)
    return out


@dataclass
class RefinedMap:
    """The merged, voxel-downsampled LiDAR map.

    Attributes
    ----------
    points: (P, 3) float64 voxel centroids, world metres.
    labels: (P,) uint8 :class:`~bimcap.labels.Label` ids (UNKNOWN where the front end had none).
    voxel_m: voxel edge (metres).
    frames: scans merged.
    returns: LiDAR returns merged (before downsampling).
    z_range: the crop ``(z_min, z_max)`` in metres, or None.
    """

    points: F64
    labels: U8
    voxel_m: float
    frames: int
    returns: int
    z_range: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        labelled = int(np.count_nonzero(self.labels != Label.UNKNOWN))
        return {"points": len(self.points), "labelled": labelled, "voxel_m": self.voxel_m,
                "frames": self.frames, "returns": self.returns,
                "z_range": None if self.z_range is None else list(self.z_range)}


class VoxelAccumulator:
    """Running centroids of the points in cubic voxels of edge ``voxel_m`` (metres) on the
    world-aligned grid: voxel ``k`` covers ``[k · voxel_m, (k + 1) · voxel_m)`` on each axis, so
    the points may arrive in chunks (a few scans at a time) and two maps of the same scene share
    their voxels. Memory grows with the voxels, not with the points.

    Voxel indices are counted from a whole voxel near the first chunk
    (:func:`~bimcap.geometry.local_frame.local_origin`: the origin, or the nearest kilometre of a
    georeferenced model's coordinates) and must lie within ±2²⁰ of it on each axis (±31 km at
    3 cm); points beyond raise :class:`RefinedMapError`. Sums are kept relative to it too.
    """

    _BITS = 21
    _HALF = 1 << (_BITS - 1)

    def __init__(self, voxel_m: float) -> None:
        if not voxel_m > 0:
            raise RefinedMapError(f"must be > 0 (got {voxel_m})", field="voxel_m")
        self.voxel_m = float(voxel_m)
        self._keys = np.zeros(0, np.int64)
        self._sums = np.zeros((0, 3))
        self._counts = np.zeros(0, np.int64)
        self._origin_cell: NDArray[np.float64] | None = None  # whole voxels, set by the 1st add
        self.points_added = 0

    @property
    def _origin_m(self) -> F64:
        return np.zeros(3) if self._origin_cell is None else self._origin_cell * self.voxel_m

    def add(self, points: F64) -> None:
        """Add (P, 3) points (world metres); non-finite rows raise."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0:
            return
        if self._origin_cell is None:
            self._origin_cell = np.round(local_origin(p[np.isfinite(p).all(axis=1)])
                                         / self.voxel_m)
        cell = np.floor(p / self.voxel_m) - self._origin_cell
        if not np.all(np.abs(cell) < self._HALF):
            raise RefinedMapError(
                f"points lie more than {self._HALF * self.voxel_m / 1000:.0f} km from the "
                "first ones (or are not finite)", field="p_in_world")
        p = p - self._origin_m
        k = cell.astype(np.int64) + self._HALF
        key = (k[:, 0] << (2 * self._BITS)) | (k[:, 1] << self._BITS) | k[:, 2]
        keys, inverse = np.unique(np.concatenate([self._keys, key]), return_inverse=True)
        inverse = inverse.reshape(-1)
        sums = np.empty((len(keys), 3))
        for axis in range(3):
            sums[:, axis] = np.bincount(inverse, np.concatenate([self._sums[:, axis], p[:, axis]]),
                                        minlength=len(keys))
        counts = np.bincount(inverse, np.concatenate([self._counts, np.ones(len(p), np.int64)]),
                             minlength=len(keys))
        self._keys, self._sums, self._counts = keys, sums, counts.round().astype(np.int64)
        self.points_added += len(p)

    def centroids(self) -> F64:
        """(V, 3) centroid of each voxel, in the order of the voxels' packed keys."""
        if not len(self._keys):
            return np.zeros((0, 3))
        return self._sums / self._counts[:, None] + self._origin_m


def _in_z_range(p: F64, z_range: tuple[float, float] | None) -> F64:
    if z_range is None:
        return p
    return p[(p[:, 2] >= z_range[0]) & (p[:, 2] < z_range[1])]


def _labelled_map(acc: VoxelAccumulator, frames: int, label_points: F64 | None,
                  label_values: NDArray[np.integer] | None, label_radius_m: float,
                  z_range: tuple[float, float] | None) -> RefinedMap:
    centroids = acc.centroids()
    if label_points is not None and label_values is not None:
        labels = transfer_labels(centroids, label_points, label_values, label_radius_m)
    else:
        labels = np.full(len(centroids), int(Label.UNKNOWN), np.uint8)
    return RefinedMap(centroids, labels, acc.voxel_m, frames, acc.points_added, z_range)


def build_refined_map(scans: ScanSet, voxel_m: float = DEFAULT_VOXEL_M,
                      label_points: F64 | None = None,
                      label_values: NDArray[np.integer] | None = None,
                      label_radius_m: float = DEFAULT_LABEL_RADIUS_M,
                      z_range: tuple[float, float] | None = None) -> RefinedMap:
    """Merge ``scans`` into a voxel map (:class:`VoxelAccumulator`'s grid), labelled from the
    front end's samples. :func:`stream_refined_map` gives the same map from a sequence without
    holding every return.

    Parameters
    ----------
    scans: the returns in the world (:func:`load_scans` with the refined poses).
    voxel_m: voxel edge (metres).
    label_points, label_values: (K, 3) front-end semantic samples in the world (the refined
        semantic map) and their (K,) labels; None leaves every voxel UNKNOWN.
    label_radius_m: largest distance of a voxel to the sample whose label it takes.
    z_range: keep only returns with ``z_min <= z < z_max`` (a storey; see :func:`storey_z_range`).
    """
    acc = VoxelAccumulator(voxel_m)
    acc.add(_in_z_range(scans.p_in_world, z_range))
    return _labelled_map(acc, len(np.unique(scans.frame)), label_points, label_values,
                         label_radius_m, z_range)


def stream_refined_map(sequence: Any, world_from_cam: F64, voxel_m: float = DEFAULT_VOXEL_M,
                       label_points: F64 | None = None,
                       label_values: NDArray[np.integer] | None = None,
                       label_radius_m: float = DEFAULT_LABEL_RADIUS_M,
                       z_range: tuple[float, float] | None = None,
                       chunk_frames: int = 32) -> RefinedMap:
    """:func:`build_refined_map` of :func:`load_scans` (``sequence``, ``world_from_cam`` (N, 7)),
    reading ``chunk_frames`` scans at a time: the same voxels and centroids (to the rounding of
    their sums), with memory bounded by the map instead of every return (a 1000-frame VLP-16
    walk has 28 M returns, 0.7 GB as float64, and its merge peaked at 2.9 GB)."""
    n = len(sequence.frames)
    acc = VoxelAccumulator(voxel_m)
    frames = 0
    step = max(1, int(chunk_frames))
    for start in range(0, n, step):
        chunk = load_scans(sequence, world_from_cam, frames=range(start, min(n, start + step)))
        frames += len(np.unique(chunk.frame))
        acc.add(_in_z_range(chunk.p_in_world, z_range))
    return _labelled_map(acc, frames, label_points, label_values, label_radius_m, z_range)


def storey_z_range(storeys: list[Any], name: str, below_m: float = 0.3
                   ) -> tuple[float, float]:
    """``(z_min, z_max)`` of the storey ``name`` among ``storeys`` (``.name``,
    ``.elevation_m``; sorted by elevation): from ``below_m`` under its elevation (its floor slab's
    top is seen from above) to the next storey's elevation (unbounded for the top storey).

    Raises :class:`RefinedMapError` naming the storeys there are when ``name`` is not one.
    """
    names = [s.name for s in storeys]
    if name not in names:
        raise RefinedMapError(f"no storey {name!r} in the model (storeys: {names})",
                              field="storey")
    k = names.index(name)
    top = storeys[k + 1].elevation_m if k + 1 < len(storeys) else float("inf")
    return float(storeys[k].elevation_m - below_m), float(top)


def write_refined_map(path: str | PathLike[str], refined: RefinedMap) -> None:
    """Write ``refined`` as a labelled binary PLY (float32 coordinates), atomically."""
    write_labelled_ply(path, refined.points, refined.labels, Precision.FLOAT32,
                       f"bimcap refined LiDAR map, voxel {refined.voxel_m:g} m, "
                       f"{refined.frames} scans (label ids: 0 unknown 1 wall 2 floor 3 ceiling "
                       "4 column 5 door 6 window 7 clutter)")
