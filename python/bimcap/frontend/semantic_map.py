"""Semantic samples (the solver's F / Ce / W / Co observations) and the semantic map PLY.

Labelled pixels with a valid depth are back-projected into the camera frame (undistorted pinhole
pixels, z-depth in metres) and subsampled per class, either

* by a **density**: a pixel at z-depth z covers ``z²·cos α / (fx·fy·cos θ)`` square metres of
  surface (α between its ray and the optical axis, θ between its ray and the surface normal
  estimated from the depth map; on a fronto-parallel plane this is ``z² / (fx·fy)``), so it is
  kept with probability ``min(1, density × area)``; the expected number of samples per square
  metre of wall is then the same near and far, head-on and oblique; or
* by the peers' **stride** (the research code keeps every 150th wall pixel and every 30th floor
  pixel in row-major order): :meth:`SemanticSamplingOptions.peers`.

A per-frame cap per class bounds the cost of one frame. Random choices use a generator seeded by
``(seed, frame index)`` so that a frame's samples do not depend on which process computed it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from enum import Enum
from os import PathLike
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import BimcapError
from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import transform_points
from bimcap.io.ply import PlyError, Precision, read_labelled_ply, write_labelled_ply
from bimcap.labels import Label

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]

#: The classes that become solver observations, with the prefix of their arrays.
SEMANTIC_CLASSES: dict[Label, str] = {
    Label.FLOOR: "floor",
    Label.CEILING: "ceiling",
    Label.WALL: "wall",
    Label.COLUMN: "column",
}


class SemanticMapError(BimcapError):
    """Semantic sampling or PLY writing that cannot proceed (mismatched sizes, bad options)."""


class SampleSource(str, Enum):
    """Which depth the samples take."""

    DENSE = "dense"  #: the completed (dense) depth map, anywhere a labelled pixel has depth
    RETURNS = "returns"  #: the sensor's own returns, at their pixels (no interpolation)


class SamplingMode(str, Enum):
    """How labelled pixels are subsampled."""

    DENSITY = "density"  # points per square metre of surface
    STRIDE = "stride"  # every k-th pixel of the class in row-major order (the peers' way)


@dataclass(frozen=True)
class SemanticSamplingOptions:
    """Subsampling of labelled pixels per class.

    Attributes
    ----------
    source: the completed depth or the returns themselves (:class:`SampleSource`). Returns
        carry the sensor's noise only; completed depth also carries interpolation across
        depth edges (on the demo world 2 % of wall pixels are > 10 cm off against 0.2 % of the
        returns). With returns every return of a class is a sample (the LiDAR already spreads
        them by angle) up to ``max_per_frame``; ``mode`` applies to dense depth only.
    mode: density or stride.
    floor_density, ceiling_density, wall_density, column_density: samples per m² (DENSITY).
    floor_stride, ceiling_stride, wall_stride, column_stride: keep every k-th pixel (STRIDE).
    max_per_frame: at most this many samples per class and frame (None: no cap).
    min_depth_m, max_depth_m: pixels outside this depth range are ignored.
    seed: seed of the random choices.
    """

    source: SampleSource = SampleSource.DENSE
    mode: SamplingMode = SamplingMode.DENSITY
    floor_density: float = 25.0
    ceiling_density: float = 25.0
    wall_density: float = 25.0
    column_density: float = 100.0
    floor_stride: int = 30
    ceiling_stride: int = 30
    wall_stride: int = 150
    column_stride: int = 150
    max_per_frame: int | None = 2000
    min_depth_m: float = 0.1
    max_depth_m: float = 30.0
    seed: int = 0

    def __post_init__(self) -> None:
        dens = (self.floor_density, self.ceiling_density, self.wall_density, self.column_density)
        strides = (self.floor_stride, self.ceiling_stride, self.wall_stride, self.column_stride)
        if any(d < 0 for d in dens):
            raise SemanticMapError("densities must be >= 0 samples per square metre")
        if any(s < 1 for s in strides):
            raise SemanticMapError("strides must be >= 1")
        if self.max_per_frame is not None and self.max_per_frame < 0:
            raise SemanticMapError("max_per_frame must be >= 0 or None")

    @classmethod
    def peers(cls) -> SemanticSamplingOptions:
        """The research code's subsampling: every 150th wall and every 30th floor pixel.

        The peers' ceiling and column strides are not published; they follow floor (30) and
        wall (150) here. No per-frame cap.
        """
        return cls(mode=SamplingMode.STRIDE, max_per_frame=None)

    def density(self, label: Label) -> float:
        return float(getattr(self, f"{SEMANTIC_CLASSES[label]}_density"))

    def stride(self, label: Label) -> int:
        return int(getattr(self, f"{SEMANTIC_CLASSES[label]}_stride"))

    def to_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["mode"] = self.mode.value
        d["source"] = self.source.value
        return d


def pixel_surface_area(depth: NDArray[np.floating], camera: Camera, min_cos: float = 0.1) -> F64:
    """Surface area in m² that each pixel of an undistorted depth map covers.

    The pixel's solid angle is ``cos³α / (fx·fy)`` and its range ``z / cos α``, so it covers
    ``z²·cos α / (fx·fy·cos θ)``: α is the angle between the ray and the optical axis, θ between the
    ray and the surface normal from the depth map's gradient (``cos θ`` clamped at ``min_cos``).

    Returns
    -------
    (H, W) float64, 0 where depth is 0.
    """
    z = np.asarray(depth, dtype=np.float64)
    h, w = z.shape
    # Component by component, the same arithmetic as np.gradient / np.cross / np.linalg.norm on
    # the stacked (H, W, 3) points (bit for bit: tests/test_frontend_speed.py), 2× cheaper.
    x = (np.arange(w, dtype=np.float64) - camera.cx) / camera.fx * z
    y = ((np.arange(h, dtype=np.float64) - camera.cy) / camera.fy)[:, None] * z
    xu, yu, zu = (np.gradient(c, axis=1) for c in (x, y, z))
    xv, yv, zv = (np.gradient(c, axis=0) for c in (x, y, z))
    n0 = yu * zv - zu * yv
    n1 = zu * xv - xu * zv
    n2 = xu * yv - yu * xv
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    pn = np.sqrt(x * x + y * y + z * z)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(n0 * x + n1 * y + n2 * z) / (nn * pn)
    cos = np.where(np.isfinite(cos), cos, 1.0)
    cos = np.clip(cos, min_cos, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_alpha = np.where(pn > 0, z / pn, 1.0)
    return np.where(z > 0, z * z * cos_alpha / (camera.fx * camera.fy) / cos, 0.0)


def sample_semantic_points(
    labels: NDArray[np.integer],
    depth: NDArray[np.floating],
    camera: Camera,
    frame_index: int,
    options: SemanticSamplingOptions | None = None,
) -> dict[Label, F64]:
    """Back-projected, subsampled labelled pixels of one undistorted frame.

    Parameters
    ----------
    labels: (H, W) uint8 label ids (:class:`bimcap.labels.Label`).
    depth: (H, W) float z-depth in metres, 0 = unknown.
    camera: the pinhole camera of both maps.
    frame_index: seeds the frame's random choices.

    Returns
    -------
    For each of floor, ceiling, wall, column: (n, 3) float64 points in the camera frame, metres.
    """
    opts = options or SemanticSamplingOptions()
    lab = np.asarray(labels)
    z = np.asarray(depth, dtype=np.float64)
    if lab.shape != z.shape or lab.ndim != 2:
        raise SemanticMapError(f"labels {lab.shape} and depth {z.shape} must be the same (H, W)")
    if lab.shape != (camera.height, camera.width):
        raise SemanticMapError(
            f"maps are {lab.shape[1]}x{lab.shape[0]} "
            f"but the camera is {camera.width}x{camera.height}"
        )
    ok = (z >= opts.min_depth_m) & (z <= opts.max_depth_m)
    rng = np.random.default_rng([opts.seed, frame_index])
    returns = opts.source is SampleSource.RETURNS
    density = opts.mode is SamplingMode.DENSITY and not returns
    area = pixel_surface_area(np.where(ok, z, 0.0), camera) if density else None
    out: dict[Label, F64] = {}
    flat_lab = lab.ravel()
    flat_ok = ok.ravel()
    for label in SEMANTIC_CLASSES:
        idx = np.flatnonzero((flat_lab == int(label)) & flat_ok)
        if returns:
            pass
        elif opts.mode is SamplingMode.STRIDE:
            idx = idx[:: opts.stride(label)]
        else:
            assert area is not None
            prob = np.minimum(1.0, opts.density(label) * area.ravel()[idx])
            idx = idx[rng.random(len(idx)) < prob]
        if opts.max_per_frame is not None and len(idx) > opts.max_per_frame:
            idx = np.sort(rng.choice(idx, size=opts.max_per_frame, replace=False))
        vv, uu = np.divmod(idx, lab.shape[1])
        uv = np.stack([uu, vv], axis=1).astype(np.float64)
        out[label] = camera.backproject(uv, z.ravel()[idx], distorted=False)
    return out


@dataclass
class SemanticMap:
    """Semantic samples of a whole sequence in the world.

    Attributes
    ----------
    points: (P, 3) float64 world coordinates, metres.
    labels: (P,) uint8 label ids.
    frame: (P,) int32 frame each point came from.
    """

    points: F64
    labels: NDArray[np.uint8]
    frame: I32


def semantic_points(frontend: Any, poses: F64) -> tuple[F64, NDArray[np.uint8]]:
    """A front end's semantic samples (``frontend.semantic_samples()``: label → (frames (K,),
    p_in_cam (K, 3))) mapped to the world with ``poses`` (N, 7): (P, 3) points, (P,) labels."""
    pts, labs = [], []
    for label, (frames, p_cam) in frontend.semantic_samples().items():
        if len(frames):
            pts.append(transform_points(poses[frames], p_cam))
            labs.append(np.full(len(frames), int(label), np.uint8))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, np.uint8)
    return np.concatenate(pts), np.concatenate(labs)


def build_semantic_map(
    samples: dict[Label, tuple[I32, F64]], world_from_cam: F64
) -> SemanticMap:
    """Move per-frame camera-frame samples into the world.

    Parameters
    ----------
    samples: per class ``(frame (n,) int32, p_in_cam (n, 3))``.
    world_from_cam: (N, 7) TUM-order poses.
    """
    pts: list[F64] = []
    labs: list[NDArray[np.uint8]] = []
    frames: list[I32] = []
    for label, (frame, p_in_cam) in samples.items():
        if len(frame) == 0:
            continue
        pts.append(transform_points(world_from_cam[frame], p_in_cam))
        labs.append(np.full(len(frame), int(label), np.uint8))
        frames.append(frame.astype(np.int32))
    if not pts:
        return SemanticMap(np.zeros((0, 3)), np.zeros(0, np.uint8), np.zeros(0, np.int32))
    return SemanticMap(np.concatenate(pts), np.concatenate(labs), np.concatenate(frames))


def write_semantic_ply(
    path: str | PathLike[str], points: F64, labels: NDArray[np.integer]
) -> None:
    """Write the semantic map: (P, 3) world points in metres, (P,) label ids in 0..7, float64
    coordinates, atomically (:func:`bimcap.io.ply.write_labelled_ply`)."""
    try:
        write_labelled_ply(path, points, labels, Precision.FLOAT64,
                           "bimcap semantic map (label ids: 0 unknown 1 wall 2 floor 3 ceiling "
                           "4 column 5 door 6 window 7 clutter)")
    except PlyError as exc:
        raise SemanticMapError(str(exc)) from None


def read_semantic_ply(path: str | PathLike[str]) -> tuple[F64, NDArray[np.uint8]]:
    """Read back a PLY written by :func:`write_semantic_ply`: points (P, 3), labels (P,)."""
    return read_labelled_ply(path)
