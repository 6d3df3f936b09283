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

Before sampling, :func:`check_label_orientation` drops labels that the depth contradicts: a
segmenter's wrong labels come in patches (a piece of wall called floor, ceiling or column), and
such a patch lies on a surface of the wrong orientation. Floor and ceiling need a surface within
``orientation_check_deg`` of horizontal, walls and columns one within it of vertical (normals from
the dense depth at a coarse scale, gravity from the frame's initial pose); a connected region of a
class whose pixels mostly disagree is set to UNKNOWN, and so is every pixel whose normal lies
within ``orientation_strict_deg`` of the other orientation.
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
    min_depth_m, max_depth_m: pixels outside this depth range are ignored. The far limit is
        the LiDAR scan samples' (``bimcap.fusion.scan.ScanSamplingOptions.max_range_m``):
        beyond 15 m a VLP-16's rings are over 0.5 m apart and a pixel's depth is an
        interpolation (and a plane fit) over metres; on Office_A's 30 m corridor view the
        wall samples came out 1-2 cm short, all of one sign (30 m: fixed point 0.64 cm,
        15 m: 0.35 cm; docs/generalization.md).
    seed: seed of the random choices.
    orientation_check_deg: :func:`check_label_orientation`'s tolerance in degrees (None: no
        check; the samples then do not depend on the initial pose).
    orientation_strict_deg: a pixel whose normal is within this many degrees of the other
        orientation (floor/ceiling: horizontal normal; wall/column: vertical) is dropped alone.
    orientation_work_width: the check's working resolution (pixels across).
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
    max_depth_m: float = 15.0
    seed: int = 0
    orientation_check_deg: float | None = 45.0
    orientation_strict_deg: float = 20.0
    orientation_work_width: int = 258

    def __post_init__(self) -> None:
        if self.orientation_check_deg is not None and not (
                0.0 < self.orientation_check_deg < 90.0
                and 0.0 <= self.orientation_strict_deg < 90.0 - self.orientation_check_deg
                and self.orientation_work_width >= 32):
            raise SemanticMapError(
                "orientation_check_deg must be in (0, 90), orientation_strict_deg in "
                "[0, 90 - orientation_check_deg), orientation_work_width >= 32")
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


#: Classes whose surfaces are horizontal (normal along gravity); the others' are vertical.
_HORIZONTAL = (Label.FLOOR, Label.CEILING)


def _coarse_normals(depth: NDArray[np.floating], camera: Camera, step: int = 4, box: int = 11
                    ) -> tuple[F64, NDArray[np.bool_]]:
    """Unit normals (h, w, 3) of a depth map (camera frame) from central differences ``step``
    pixels apart, box-smoothed over ``box`` pixels (coarse: robust to a few cm of range noise),
    turned toward the camera (0 where undefined), and where they are defined (no depth jump,
    all neighbours with depth).

    The segmenter's normals (``bimcap.segmentation.geometric._points_and_normals``) with a
    jump threshold of 2 (0.05 z + 0.1) m: the per-pixel arithmetic in ``bimcap._core``
    (``points_and_cross``, ``orient_normals``), the blur OpenCV's in float32. Numpy's
    arithmetic bit for bit; the numpy code before (tests/_frontend_reference.py:
    ``coarse_normals_02ca12e``) left the normals' sign and the undefined pixels' blurred
    values, which the check never reads (it takes ``|n · up|`` where defined).
    """
    import cv2

    from bimcap import _core

    pts, _, ok, n = _core.points_and_cross(np.ascontiguousarray(depth, dtype=np.float32),
                                           camera.fx, camera.fy, camera.cx, camera.cy, step,
                                           True, jump_offset_m=0.1)
    n = cv2.blur(n, (box, box)).astype(np.float64)
    _core.orient_normals(n, pts, ok)
    return n, ok


def _region_plane_normals(comp: NDArray[np.int32], n_comp: int, valid: NDArray[np.bool_],
                          depth: NDArray[np.float32], camera: Camera, up: F64,
                          min_pixels: int = 20) -> list[tuple[int, float]]:
    """Per connected region (ids 1..n_comp-1 of ``comp``) with at least ``min_pixels`` pixels of
    depth (``valid``; ``depth`` (H, W) float32): ``(id, |n·up|)`` of the least-squares plane
    through its points. A plane n·p = d seen at normalised pixel (x, y) has inverse depth
    1/z = (n_x x + n_y y + n_z) / d, affine in (x, y): a linear fit over every pixel, so that the
    normal stays determined where the range noise swamps local normals (a wall 1 m away seen
    through a narrow lens, 8 cm noise)."""
    from bimcap import _core

    # per region sums of the normal equations of w ≈ a x + b y + c, columns (x, y, 1), over its
    # pixels in row-major order (np.bincount's sums, in compiled code: raster/region_sums.h)
    count, ata, atb = _core.region_plane_sums(
        np.ascontiguousarray(comp, dtype=np.int32), np.ascontiguousarray(valid, dtype=bool),
        np.ascontiguousarray(depth, dtype=np.float32), camera.fx, camera.fy, camera.cx,
        camera.cy, n_comp)
    out = []
    for c in range(1, n_comp):
        if count[c] < min_pixels or abs(np.linalg.det(ata[c])) < 1e-18:
            continue
        n = np.linalg.solve(ata[c], atb[c])
        norm = np.linalg.norm(n)
        if norm > 0:
            out.append((c, float(abs(n @ up) / norm)))
    return out


def check_label_orientation(labels: NDArray[np.integer], depth: NDArray[np.floating],
                            camera: Camera, world_from_cam: F64,
                            options: SemanticSamplingOptions | None = None
                            ) -> tuple[NDArray[np.uint8], dict[str, int]]:
    """Labels with the floor / ceiling / wall / column pixels that the depth contradicts set to
    UNKNOWN (module docstring).

    Parameters
    ----------
    labels: (H, W) uint8 label ids. depth: (H, W) float z-depth in metres, 0 = unknown, pixels
    of the pinhole ``camera``. world_from_cam: (7,) TUM-order pose; only its rotation is used
    (world z is up). options: ``orientation_*`` fields; ``orientation_check_deg`` None returns
    the labels unchanged.

    Returns
    -------
    ((H, W) uint8 labels, {"dropped_pixels": n, "dropped_regions": m}).
    """
    import cv2

    from bimcap.geometry import quat_to_rotmat

    opts = options or SemanticSamplingOptions()
    lab = np.asarray(labels).astype(np.uint8)
    stats = {"dropped_pixels": 0, "dropped_regions": 0}
    if opts.orientation_check_deg is None:
        return lab, stats
    z = np.asarray(depth, dtype=np.float32)
    if lab.shape != z.shape or lab.shape != (camera.height, camera.width):
        raise SemanticMapError(f"labels {lab.shape}, depth {z.shape} and the camera "
                               f"{camera.height}x{camera.width} must agree")
    scale = min(1.0, opts.orientation_work_width / camera.width)
    cam = camera.pinhole().scaled(scale) if scale < 1.0 else camera.pinhole()
    size = (cam.width, cam.height)
    zw = cv2.resize(z, size, interpolation=cv2.INTER_NEAREST) if scale < 1.0 else z
    lw = cv2.resize(lab, size, interpolation=cv2.INTER_NEAREST) if scale < 1.0 else lab
    nrm, ok = _coarse_normals(zw, cam)
    up = quat_to_rotmat(np.asarray(world_from_cam, np.float64)[3:]).T @ np.array([0.0, 0.0, 1.0])
    vertical_cos = np.abs(nrm @ up)  # 1: horizontal surface, 0: vertical surface
    tol = np.cos(np.deg2rad(opts.orientation_check_deg))
    strict = np.sin(np.deg2rad(opts.orientation_strict_deg))
    drop_w = np.zeros(lw.shape, dtype=bool)
    for label in SEMANTIC_CLASSES:
        mask = lw == int(label)
        if not mask.any():
            continue
        if label in _HORIZONTAL:
            wrong = ok & (vertical_cos <= strict)
        else:
            wrong = ok & (vertical_cos >= np.cos(np.deg2rad(opts.orientation_strict_deg)))
        n_comp, comp = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
        bad = np.zeros(n_comp, dtype=bool)
        for c, n_up in _region_plane_normals(comp, n_comp, mask & (zw > 0), zw, cam, up):
            bad[c] = (n_up < tol) if label in _HORIZONTAL else (n_up > tol)
        stats["dropped_regions"] += int(bad.sum())
        drop_w |= mask & (bad[comp] | wrong)
    if not drop_w.any():
        return lab, stats
    drop = (cv2.resize(drop_w.astype(np.uint8), (camera.width, camera.height),
                       interpolation=cv2.INTER_NEAREST).astype(bool) if scale < 1.0 else drop_w)
    # only pixels of the class that was judged at the working resolution there
    same = (cv2.resize(lw, (camera.width, camera.height), interpolation=cv2.INTER_NEAREST)
            == lab) if scale < 1.0 else np.ones(lab.shape, dtype=bool)
    drop &= same
    out = lab.copy()
    out[drop] = int(Label.UNKNOWN)
    stats["dropped_pixels"] = int(drop.sum())
    return out, stats


def pixel_surface_area(depth: NDArray[np.floating], camera: Camera, min_cos: float = 0.1) -> F64:
    """Surface area in m² that each pixel of an undistorted depth map covers.

    The pixel's solid angle is ``cos³α / (fx·fy)`` and its range ``z / cos α``, so it covers
    ``z²·cos α / (fx·fy·cos θ)``: α is the angle between the ray and the optical axis, θ between the
    ray and the surface normal from the depth map's gradient (``cos θ`` clamped at ``min_cos``).

    Computed in ``bimcap._core`` (cpp/bimcap/raster/surface_area.h) with the arithmetic of
    ``np.gradient`` / ``np.cross`` / ``np.linalg.norm`` on the (H, W, 3) points, operation by
    operation (bit for bit: tests/test_frontend_speed.py).

    Parameters
    ----------
    depth: (H, W) z-depth in metres (0 = none), H and W at least 2.

    Returns
    -------
    (H, W) float64, 0 where depth is 0.
    """
    from bimcap import _core

    z = np.ascontiguousarray(depth, dtype=np.float64)
    if z.ndim != 2 or min(z.shape) < 2:
        raise SemanticMapError(f"depth must be (H, W) with H, W >= 2, got {z.shape}")
    area: F64 = _core.pixel_surface_area(z, float(camera.fx), float(camera.fy), float(camera.cx),
                                         float(camera.cy), float(min_cos))
    return area


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
