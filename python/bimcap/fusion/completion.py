"""Depth completion: sparse LiDAR depth → dense depth, behind one interface.

Methods (:class:`CompletionMethod`):

- ``LINEAR``: barycentric interpolation over a Delaunay triangulation of the sparse returns
  (sub-pixel positions; :class:`Triangulation`: Qhull, or a compiled sweep), of inverse depth
  by default (exact for a plane seen through a pinhole);
  triangles with an edge longer than ``max_edge_px``, a depth ratio ``z_max / z_min >
  max_depth_ratio`` (they bridge a depth edge) or an area under 1 px² leave their pixels at 0.
- ``CLASSICAL``: CPU morphology in the spirit of Ku et al. 2018 ("In Defense of Classical Image
  Processing"): invert depth (so that dilation prefers near returns), diamond-kernel dilation
  (joins the returns along each ring), column-wise interpolation of the gaps between rings in
  1/z (our addition, see :class:`ClassicalOptions`), morphological close, small hole fill,
  optional column-wise extrapolation, large hole fill, median blur, bilateral or Gaussian blur,
  re-invert. Runs at ``work_scale`` of the image
  (the sparse map is min-pooled down, the result resized up; stated in the bench table).
- ``ONNX``: a user-supplied network (CompletionFormer-like: RGB + sparse depth in, dense depth
  out) through ONNX Runtime, see :mod:`bimcap.fusion.onnx_completion`.
- ``HYBRID``: the paper's: ``LINEAR`` first, then the network with the interpolated depth as its
  depth input.

:func:`fill_nearest` (nearest-neighbour filling) is the baseline every method must beat.
:func:`smooth_planar_regions` smooths depth inside floor/ceiling labels.
All depth maps are float32 metres, 0 = unknown, in undistorted pinhole pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.fusion.projection import FusionInputError, SparseDepth
from bimcap.fusion.sparse import downsample_sparse
from bimcap.geometry import Camera
from bimcap.geometry.noise import noise_factor
from bimcap.geometry.vectors import cross_rows, plane_inlier_counts
from bimcap.labels import Label
from bimcap.methods import CompletionMethod

if TYPE_CHECKING:
    from bimcap.fusion.onnx_completion import OnnxCompletionOptions

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


class BlurType(Enum):
    BILATERAL = "bilateral"
    GAUSSIAN = "gaussian"
    NONE = "none"


class Triangulation(Enum):
    """How LINEAR triangulates the returns: both give the Delaunay triangles (docs/speed.md,
    "LiDAR stages, the triangulation and the cache writes")."""

    #: ``scipy.spatial.Delaunay`` (Qhull), 11-18 ms a frame for ~3,600 returns on a loaded box,
    #: the triangles drawn in Qhull's order (where they share edge pixels, the later one's plane
    #: gives their depth). The default.
    QHULL = "qhull"
    #: ``bimcap._core.delaunay_triangles``, a sweep of the convex hull (cpp/bimcap/raster/
    #: delaunay.h), 1.3-1.8 ms there: the same triangles where no four returns lie on one
    #: circle, drawn thinnest first, so that the fattest take the edge pixels they share (with
    #: ``PixelOwner.LAST_DRAWN``; with ``CENTRE`` the same map as Qhull's). Its
    #: depth is closer to the simulator's (mean 0.04-0.07 mm, p99 0.7-2 mm on 4 worlds) but
    #: not the same, and BIMCaP's ATE moved with it (16 runs on 4 worlds: mean +0.007 cm, single
    #: runs up to ±0.04 cm, gen-demo-s0 +0.02-0.03 cm in all four): an option until a wider
    #: accuracy run says otherwise.
    SWEEP = "sweep"


class PixelOwner(Enum):
    """Which kept triangle gives LINEAR a pixel's depth where several reach it.

    Each triangle is first drawn with its outline (``cv2.fillConvexPoly``'s pixels, whose
    centres may lie up to half a pixel outside it: its plane extrapolated there); between the
    LiDAR rings most triangles are slivers 1–2 px across, so about a third of the pixels are
    reached by two or more.
    """

    #: the last triangle drawn: the triangulator's order decides (Qhull's, or the sweep's
    #: thinnest first; docs/speed.md, "The compiled triangulation").
    LAST_DRAWN = "last_drawn"
    #: the triangle that contains the pixel's centre (top-left rule on its edges: exactly one
    #: of a triangulation, bimcap/raster/convex_fill.h), its plane interpolated, never
    #: extrapolated; pixels that no kept triangle contains (next to a dropped one, on the hull)
    #: keep the outline of the last drawn in the order of the triangles' sorted corner indices.
    #: Neither depends on the triangulator's order, so Qhull and the sweep give the same map,
    #: and with the sweep the completion costs ~6.6 instead of ~11.6 ms a frame. Its depth is
    #: closer to the simulator's (mean 0.9–1.0 mm lower on 4 worlds, p99 1–2.5 mm), but BIMCaP's
    #: trajectories moved both ways: better means on the standard and unseen matrices, worse
    #: rotations on the hard one (gen-small-s3 Exp. 2 0.22° → 0.33°), 4 of 76 runs beyond the
    #: bars (docs/speed.md, "Pixels owned by the triangle that contains them"): an option.
    CENTRE = "centre"


@dataclass(frozen=True)
class LinearOptions:
    """LINEAR: mask triangles with an edge > ``max_edge_px``
    or ``z_max/z_min > max_depth_ratio``; ``triangulation``: :class:`Triangulation`;
    ``pixel_owner``: :class:`PixelOwner`."""

    max_edge_px: float = 80.0
    max_depth_ratio: float = 1.5
    inverse_depth: bool = True  #: interpolate 1/z (exact for planes through a pinhole) or z
    triangulation: Triangulation = Triangulation.QHULL
    pixel_owner: PixelOwner = PixelOwner.LAST_DRAWN

    def __post_init__(self) -> None:
        kinds: tuple[tuple[str, type[Enum]], ...] = (
            ("triangulation", Triangulation), ("pixel_owner", PixelOwner))
        for name, kind in kinds:
            value = getattr(self, name)
            try:
                object.__setattr__(self, name, kind(value))
            except ValueError:
                raise FusionInputError(
                    f"{name} must be one of {[k.value for k in kind]}, got {value!r}",
                    field=name) from None


@dataclass(frozen=True)
class ClassicalOptions:
    """CLASSICAL (Ku et al. 2018). Kernel sizes are in pixels of the working resolution.

    work_scale: resolution factor of the work (1 = full; 0.5 halves both sides).
    max_depth_m: inversion constant (``max_depth - z``), larger than any depth.
    dilation_size: size of the diamond kernel of the first dilation.
    close_size, small_fill_size, large_fill_size: full kernels of close / small and large hole fill.
    vertical_interpolation: right after the first dilation, fill the gaps between LiDAR rings
        column by column, linearly in inverse depth (gaps <= ``max_gap_px`` rows whose end depths
        differ by a ratio <= ``max_gap_depth_ratio``). Not in Ku et al. (KITTI's 64 rings leave
        small gaps); for 16-32 ring LiDARs it is what lets the method beat nearest-neighbour
        filling.
    extrapolate: extend each column's top-most and bottom-most values to the image border.
    max_fill_distance_px: pixels (of the full image) farther than this from every LiDAR return
        stay 0 (unknown): where a narrow-FoV LiDAR (VLP-16: ±15°) sees nothing, the fills would
        only smear the nearest ring's depth (wrong depth is worse than none downstream). None
        keeps Ku's fill-everything behaviour.
    median_size: 3 or 5 (cv2 on float32); 0 disables it.
    blur: final blur (bilateral sigma_space 2, sigma_color 1.5 m of inverted depth, as Ku).
    """

    work_scale: float = 0.5
    max_depth_m: float = 100.0
    dilation_size: int = 5
    close_size: int = 5
    small_fill_size: int = 7
    large_fill_size: int = 31
    vertical_interpolation: bool = True
    max_gap_px: int = 40
    max_gap_depth_ratio: float = 1.3
    extrapolate: bool = False
    max_fill_distance_px: float | None = 48.0
    median_size: int = 5
    blur: BlurType = BlurType.BILATERAL

    def __post_init__(self) -> None:
        if not 0.05 <= self.work_scale <= 1.0:
            raise FusionInputError("work_scale must be in [0.05, 1]", field="work_scale")
        if self.median_size not in (0, 3, 5):
            raise FusionInputError("median_size must be 0, 3 or 5", field="median_size")


@dataclass(frozen=True)
class CompletionOptions:
    """Settings of :func:`complete_depth`; ``onnx`` is required for ONNX and HYBRID.
    ``CompletionMethod.GROUND_TRUTH`` is not computed (it is read from a simulated sequence)."""

    method: CompletionMethod = CompletionMethod.LINEAR
    linear: LinearOptions = field(default_factory=LinearOptions)
    classical: ClassicalOptions = field(default_factory=ClassicalOptions)
    onnx: OnnxCompletionOptions | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "method", CompletionMethod(self.method))
        if self.method is CompletionMethod.GROUND_TRUTH:
            raise FusionInputError(
                "ground_truth depth is read from a simulated sequence's "
                "depth/, not computed from LiDAR",
                field="method",
            )


# ----------------------------------------------------------------------------- helpers
def _sparse_arrays(sparse: SparseDepth | ArrayLike) -> tuple[F32, F64, F64]:
    """(depth (H, W), uv (K, 2), z (K,)) from a SparseDepth or an (H, W) sparse map."""
    if isinstance(sparse, SparseDepth):
        return sparse.depth, sparse.uv, sparse.z
    depth = np.asarray(sparse, dtype=np.float32)
    if depth.ndim != 2:
        raise FusionInputError(
            f"sparse depth must be (H, W), got {depth.shape}", field="sparse_depth"
        )
    if not np.isfinite(depth).all() or (depth < 0).any():
        raise FusionInputError("sparse depth must be finite and >= 0", field="sparse_depth")
    rows, cols = np.nonzero(depth > 0)
    return depth, np.stack([cols, rows], 1).astype(np.float64), depth[rows, cols].astype(np.float64)


def _require_points(z: F64, need: int = 1) -> None:
    if len(z) < need:
        raise FusionInputError(
            f"sparse depth has {len(z)} returns, need at least {need}", field="sparse_depth"
        )


def _resize_to(depth: F32, shape: tuple[int, int]) -> F32:
    import cv2

    if depth.shape == shape:
        return depth
    # linear resize of depth with holes would blend 0 into values: resize values and mask apart
    valid = (depth > 0).astype(np.float32)
    num = cv2.resize(depth * valid, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    den = cv2.resize(valid, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    out = np.where(den > 0.5, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)
    return out


# ----------------------------------------------------------------------------- baseline
def fill_nearest(sparse: SparseDepth | ArrayLike) -> F32:
    """Nearest-neighbour filling (the baseline): every pixel takes the nearest return's depth."""
    from scipy import ndimage

    depth, _, z = _sparse_arrays(sparse)
    _require_points(z)
    _, idx = ndimage.distance_transform_edt(depth <= 0, return_indices=True)
    return depth[idx[0], idx[1]].astype(np.float32)


# ----------------------------------------------------------------------------- linear
def complete_linear(sparse: SparseDepth | ArrayLike, options: LinearOptions | None = None) -> F32:
    """LINEAR: Delaunay barycentric interpolation (module docstring). Pixels outside the hull or in
    masked triangles stay 0."""
    from scipy.spatial import Delaunay, QhullError

    from bimcap import _core

    opts = options or LinearOptions()
    depth, uv, z = _sparse_arrays(sparse)
    _require_points(z, 3)
    h, w = depth.shape
    if opts.triangulation is Triangulation.QHULL:
        try:
            simp = Delaunay(uv).simplices
        except QhullError as exc:
            raise FusionInputError(
                f"cannot triangulate the sparse returns: {exc}", field="sparse_depth"
            ) from None
    else:
        try:
            simp = _core.delaunay_triangles(np.ascontiguousarray(uv, dtype=np.float64))
        except _core.InputError as exc:
            raise FusionInputError(
                f"cannot triangulate the sparse returns: {exc}", field="sparse_depth"
            ) from None
    # the triangles kept (no edge over max_edge_px, no depth ratio over max_depth_ratio, an area
    # of at least 1 px²) and their corners in 1/16 px, in compiled code (numpy's arithmetic:
    # cpp/bimcap/raster/triangle_filter.h)
    simp = np.ascontiguousarray(simp, dtype=np.int32)
    good_idx, corners, edge, det = _core.filter_triangles(
        np.ascontiguousarray(uv, dtype=np.float64), np.ascontiguousarray(z, dtype=np.float64),
        simp, float(opts.max_edge_px), float(opts.max_depth_ratio))
    if opts.pixel_owner is PixelOwner.CENTRE:
        # the outline pass in an order of the triangles themselves (their sorted corner
        # indices), not the triangulator's; the centre pass below owes nothing to any order
        key = np.sort(simp[good_idx], axis=1)
        order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
        good_idx, corners = good_idx[order], corners[order]
    elif opts.triangulation is Triangulation.SWEEP:
        # where triangles share edge pixels the last one drawn gives their depth, extrapolated
        # up to half a pixel outside it: draw the slivers (1-2 px across between LiDAR rings)
        # first and the fattest triangles (largest least altitude, twice the area over the
        # longest edge) last. The order of the triangles alone decides, not the triangulator's;
        # against the simulator's ground truth it gave 0.04-0.07 mm lower mean and 0.7-2 mm
        # lower 99th-percentile depth errors than Qhull's order on 4 worlds (docs/speed.md)
        order = np.argsort(np.abs(det[good_idx]) / edge[good_idx], kind="stable")
        good_idx, corners = good_idx[order], corners[order]
    tri_id = _core.fill_triangle_ids(corners, (good_idx + 1).astype(np.int32), h, w, shift=4,
                                     centres=opts.pixel_owner is PixelOwner.CENTRE)
    # per triangle, the affine function f(u, v) = a u + b v + c through its three corners, with
    # f = 1/z (exact for a plane seen through a pinhole) or f = z, evaluated at every pixel by
    # its triangle id (column 0: no triangle, f = 0 and the pixel stays 0) in compiled code
    # with numpy's operations and rounding (cpp/bimcap/raster/piecewise_affine.h). Pixel
    # centres up to half a pixel outside their rasterised triangle are extrapolated (exact for
    # a plane); slivers (area < 1 px²) were dropped above, so this stays well conditioned.
    gi = good_idx
    mat = np.ones((len(gi), 3, 3))
    mat[:, :, :2] = uv[simp[gi]]
    zt = z[simp[gi]]
    vals = 1.0 / zt if opts.inverse_depth else zt
    coef_good = np.linalg.solve(mat, vals[:, :, None])[:, :, 0]
    coef = np.zeros((3, len(simp) + 1))
    coef[:, gi + 1] = coef_good.T
    out: F32 = _core.evaluate_piecewise_affine(tri_id, coef, opts.inverse_depth)
    return out


# ----------------------------------------------------------------------------- classical
def _diamond(size: int) -> NDArray[np.uint8]:
    r = size // 2
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    return (np.abs(xx) + np.abs(yy) <= r).astype(np.uint8)


def _extrapolate_columns(d: F32) -> F32:
    """Extend each column's top-most and bottom-most values to the image border (Ku's step)."""
    present = d > 0.1
    cols = np.arange(d.shape[1])
    any_col = present.any(0)
    top = np.argmax(present, axis=0)
    bottom = d.shape[0] - 1 - np.argmax(present[::-1], axis=0)
    rr = np.arange(d.shape[0])[:, None]
    out = np.where((rr < top) & any_col, d[top, cols], d)
    return np.where((rr > bottom) & any_col, d[bottom, cols], out).astype(np.float32)


def _fill_vertical_gaps(d_inv: F32, opts: ClassicalOptions) -> F32:
    """Fill the gaps between LiDAR rings column by column, linearly in inverse depth (exact for a
    plane seen through a pinhole), where the gap is at most ``max_gap_px`` rows and the depths
    above and below differ by a ratio of at most ``max_gap_depth_ratio`` (else it is a depth edge
    and Ku's foreground-preferring dilation fills it). Works on the inverted map ``max - z``."""
    h = d_inv.shape[0]
    valid = d_inv > 0.1
    rows = np.arange(h)[:, None]
    above = np.maximum.accumulate(np.where(valid, rows, -1), axis=0)
    below = np.minimum.accumulate(np.where(valid, rows, h)[::-1], axis=0)[::-1]
    hole = ~valid & (above >= 0) & (below < h) & ((below - above) <= opts.max_gap_px)
    r, c = np.nonzero(hole)
    a, b = above[r, c], below[r, c]
    za = opts.max_depth_m - d_inv[a, c]
    zb = opts.max_depth_m - d_inv[b, c]
    ok = np.maximum(za, zb) <= opts.max_gap_depth_ratio * np.minimum(za, zb)
    r, c, a, b, za, zb = r[ok], c[ok], a[ok], b[ok], za[ok], zb[ok]
    t = (r - a) / (b - a)
    z = 1.0 / ((1.0 - t) / za + t / zb)
    out = d_inv.copy()
    out[r, c] = (opts.max_depth_m - z).astype(np.float32)
    return out


def complete_classical(
    sparse: SparseDepth | ArrayLike, options: ClassicalOptions | None = None
) -> F32:
    """CLASSICAL: Ku et al. 2018's fill-in-fast pipeline (module docstring) at ``work_scale``."""
    import cv2

    opts = options or ClassicalOptions()
    depth, uv, z = _sparse_arrays(sparse)
    _require_points(z)
    if opts.work_scale < 1.0:
        d, _, _ = downsample_sparse(uv, z, depth.shape, opts.work_scale)
    else:
        d = depth.copy()
    d = d.astype(np.float32)
    sparse_work = d.copy()
    valid = d > 0.1
    d[valid] = opts.max_depth_m - d[valid]
    d = cv2.dilate(d, _diamond(opts.dilation_size))
    if opts.vertical_interpolation:
        d = _fill_vertical_gaps(d, opts)
    if opts.close_size > 1:
        d = cv2.morphologyEx(d, cv2.MORPH_CLOSE, np.ones((opts.close_size,) * 2, np.uint8))
    if opts.small_fill_size > 1:
        empty = d < 0.1
        dil = cv2.dilate(d, np.ones((opts.small_fill_size,) * 2, np.uint8))
        d[empty] = dil[empty]
    if opts.extrapolate:
        d = _extrapolate_columns(d)
    if opts.large_fill_size > 1:
        empty = d < 0.1
        dil = cv2.dilate(d, np.ones((opts.large_fill_size,) * 2, np.uint8))
        d[empty] = dil[empty]
    if opts.median_size:
        d = cv2.medianBlur(d, opts.median_size)
    valid = d > 0.1
    if opts.blur is BlurType.BILATERAL:
        d = cv2.bilateralFilter(d, 5, 1.5, 2.0)
    elif opts.blur is BlurType.GAUSSIAN:
        blurred = cv2.GaussianBlur(d, (5, 5), 0)
        d[valid] = blurred[valid]
    out = np.zeros_like(d)
    out[valid] = opts.max_depth_m - d[valid]
    out[out < 0] = 0.0
    if opts.max_fill_distance_px is not None:
        scale = d.shape[1] / depth.shape[1]
        seen = (sparse_work > 0).astype(np.uint8)
        dist = cv2.distanceTransform(1 - seen, cv2.DIST_L2, 3)
        out[dist > opts.max_fill_distance_px * scale] = 0.0
    return _resize_to(out.astype(np.float32), depth.shape)


# ----------------------------------------------------------------------------- dispatcher
def complete_depth(
    sparse: SparseDepth | ArrayLike,
    options: CompletionOptions | None = None,
    image: ArrayLike | None = None,
) -> F32:
    """Complete a sparse depth map with the method chosen in ``options``.

    Parameters
    ----------
    sparse: :class:`SparseDepth` from :func:`project_lidar`, or an (H, W) float32 sparse map.
    options: :class:`CompletionOptions` (``onnx`` required for ONNX and HYBRID).
    image: (H, W, 3) uint8 RGB undistorted image (ONNX and HYBRID only).

    Returns
    -------
    (H, W) float32 depth in metres, 0 where the method gives nothing.
    """
    opts = options or CompletionOptions()
    if opts.method is CompletionMethod.LINEAR:
        return complete_linear(sparse, opts.linear)
    if opts.method is CompletionMethod.CLASSICAL:
        return complete_classical(sparse, opts.classical)
    from bimcap.fusion.onnx_completion import run_completion_model

    if opts.onnx is None:
        raise FusionInputError(
            f"{opts.method.name} needs CompletionOptions.onnx (the model)", field="onnx"
        )
    if image is None:
        raise FusionInputError(f"{opts.method.name} needs the RGB image", field="image")
    depth, _, _ = _sparse_arrays(sparse)
    if opts.method is CompletionMethod.ONNX:
        return run_completion_model(np.asarray(image), depth, opts.onnx)
    interpolated = complete_linear(sparse, opts.linear)
    return run_completion_model(np.asarray(image), interpolated, opts.onnx)


# ----------------------------------------------------------------------------- planar smoothing
class PlanarSmoothing(Enum):
    PLANE_FIT = "plane_fit"  #: robust 3-D planes per connected region, depth moved onto them
    BLUR = "blur"  #: the paper's: normalised Gaussian blur inside the region


class PlaneFitPoints(Enum):
    """What :func:`smooth_planar_regions` (PLANE_FIT) fits a region's planes to."""

    RETURNS = "returns"  #: the sensor's own returns inside the region (the pixels without enough)
    PIXELS = "pixels"  #: every pixel of the region, interpolated ones included


@dataclass(frozen=True)
class PlanarSmoothingOptions:
    """Settings of :func:`smooth_planar_regions`.

    labels: classes smoothed. Walls are planar in a BIM too: smoothing them takes the range noise
        out of the keypoint depths and wall samples (on the demo world, from ground-truth poses,
        the wall samples' noise drops from 2.3 cm to about 0.3 cm).
    min_region_px: smaller connected regions (and smaller planes) are left alone.
    ransac_threshold_m: inlier distance of the RANSAC fits; ransac_iterations; sample_size:
        points per region used for the fits.
    max_planes: planes fitted per connected region, one after the other on the pixels the
        earlier planes did not explain (two walls meeting in a corner, a floor with a step).
    assign_threshold_m: in a region with several planes a pixel moves onto its nearest plane
        (3-D distance of its back-projected point) only when it is within this distance; the
        others keep their depth (near a corner, a pixel of one wall must not be dragged onto the
        other's extension). A region with one plane moves every pixel (as the paper's
        smoothing does: interpolation across the region's edges is what it takes out).
    max_change_rel: no pixel moves when its depth would change by more than this fraction (a
        labelling error should not drag depth onto the plane).
    blur_sigma_px: BLUR.
    fit_to: what the planes are fitted to (:class:`PlaneFitPoints`) when the measured depth is
        given. The returns: an interpolated pixel is no measurement, and across a concave
        corner (wall over floor, wall beside wall) its depth is a chord through the room, short
        of both surfaces; fitted to every pixel the floor plane came out 3-5 mm above the floor
        and the walls 1-2 mm in front of themselves, all of one sign, and pulled the fixed point
        (Duplex_A 0.40 cm, docs/generalization.md "What pulled the fixed point").
        RETURNS is the default since its fit is refitted robustly (``returns_refit_*``; without
        it SampleHouse4's Exp 2 ended at 0.84 cm instead of 0.27): fixed point and Exp 2 at
        least as good as PIXELS on the ten benchmark worlds (docs/generalization.md).
    min_region_returns: with RETURNS, a region with fewer returns (or a plane with fewer inlier
        returns) is fitted to its pixels instead.
    noise_reference_m, noise_adapt_above, noise_threshold_sigmas, noise_assign_sigmas: the
        thresholds above are for range noise of about ``noise_reference_m``; :meth:`for_noise`
        widens them for noisier depth (the geometric segmenter's rule,
        ``GeometricOptions.for_noise``).
    returns_refit_iterations, returns_refit_sigmas: with RETURNS, each plane's least squares is
        repeated this many times on the returns within ``returns_refit_sigmas`` robust standard
        deviations (1.4826 x the median absolute distance, at least ``ransac_threshold_m``) of
        the previous fit. The returns carry the scan's whole range noise (sigma 2.3-2.7 cm
        across a wall at the standard 3 cm), as wide as the 3 cm RANSAC window: least squares on
        that window alone is truncated around the 3-point hypothesis and keeps its tilt and
        offset (SampleHouse4 Exp 2 frame 52: a wall 0.4 cm off, 0.8 cm at its 90th percentile,
        against 0.04 / 0.17 cm refitted; the run 0.84 cm against 0.27 cm with the pixels).
        0 iterations: the single truncated fit. The pixels' fit is not refitted (their noise is
        smoothed by the interpolation).
    returns_max_sigma_m: with RETURNS, a region whose returns lie further from their planes than
        this (robust standard deviation, 1.4826 x the median distance) is fitted to its pixels:
        the interpolation averages that noise, the returns' fit does not (hard setting, 8 cm of
        range noise: gen-demo-s11 Exp 2 2.49 cm with the returns' fit, 1.47 cm with the
        pixels'). At the standard 3 cm the returns' robust sigma stays under 3 cm.
    reject_oblique, max_incidence_deg: with ``reject_oblique`` (set by :meth:`for_noise`) no
        plane is fitted that the camera sees more obliquely than ``max_incidence_deg``
        (:func:`fit_plane_ransac`); a region whose next plane would be one gets no more planes.
        At 8 cm of range noise the 12 cm RANSAC window let planes through the camera centre win
        on small regions (wrong labels on a window: every pixel of a 75 px wide band at 1.4 m
        lies within 12 cm of such a plane, whatever its depth), and their pixels were moved
        onto them by up to ``max_change_rel``: on gen-small-s3 hard these became frame 55's
        wall samples and turned it 2.6° (docs/generalization.md, "Hard tilt").
    """

    mode: PlanarSmoothing = PlanarSmoothing.PLANE_FIT
    labels: tuple[Label, ...] = (Label.FLOOR, Label.CEILING, Label.WALL)
    min_region_px: int = 500
    ransac_threshold_m: float = 0.03
    ransac_iterations: int = 64
    sample_size: int = 3000
    max_planes: int = 4
    assign_threshold_m: float = 0.08
    max_change_rel: float = 0.15
    blur_sigma_px: float = 5.0
    fit_to: PlaneFitPoints = PlaneFitPoints.RETURNS
    min_region_returns: int = 40
    returns_refit_iterations: int = 3
    returns_refit_sigmas: float = 2.5
    returns_max_sigma_m: float = 0.045
    noise_reference_m: float = 0.03
    noise_adapt_above: float = 1.5
    noise_threshold_sigmas: float = 1.5
    noise_assign_sigmas: float = 3.0
    reject_oblique: bool = False
    max_incidence_deg: float = 80.0

    def for_noise(self, range_noise_m: float | None) -> PlanarSmoothingOptions:
        """These options for depth with range noise σ = ``range_noise_m`` (metres; None or not
        finite: unknown, unchanged). Unchanged up to ``noise_adapt_above`` ×
        ``noise_reference_m``; above, the RANSAC inlier threshold is at least
        ``noise_threshold_sigmas`` · σ and the assignment threshold at least
        ``noise_assign_sigmas`` · σ (8 cm noise: 3 → 12 cm and 8 → 24 cm), and planes seen
        edge-on are not fitted (``reject_oblique``).

        With thresholds made for 3 cm noise, a region of 8 cm noise keeps a third of its pixels
        as inliers, and the pixels beyond ``assign_threshold_m`` (a third of them) become
        "planes" of their own, parallel to the wall a few centimetres off, onto which the noisy
        pixels are then moved: on gen-small-s3 hard (8 cm noise) the walls' depth error stayed
        at 6-7 cm rms (the interpolation's 5.5 cm), and with the widened thresholds falls to
        under 1 cm on walls seen whole (frames 40, 52, 57, 58: rms 0.7-2.0 cm).
        """
        if (range_noise_m is None or noise_factor(range_noise_m, self.noise_reference_m,
                                                  self.noise_adapt_above) is None):
            return self
        return replace(
            self,
            ransac_threshold_m=max(self.ransac_threshold_m,
                                   self.noise_threshold_sigmas * float(range_noise_m)),
            assign_threshold_m=max(self.assign_threshold_m,
                                   self.noise_assign_sigmas * float(range_noise_m)),
            reject_oblique=True,
        )


def _inlier_counts(points: F64, normals: F64, d: F64, threshold: float) -> NDArray[np.int64]:
    """(I,) how many of ``points`` (N, 3) lie within ``threshold`` of each plane ``normals``
    (I, 3), ``d`` (I,) (all float64): ``(|points·normalsᵀ + d| < threshold).sum(0)`` bit for
    bit (:func:`bimcap.geometry.vectors.plane_inlier_counts`)."""
    return plane_inlier_counts(points, normals, d, threshold)


def fit_plane_ransac(
    points: F64, threshold: float, iterations: int, rng: np.random.Generator,
    min_cos_incidence: float | None = None,
) -> tuple[F64, NDArray[np.bool_]] | None:
    """Robust plane ``n·p + d = 0`` through points (N, 3): 3-point RANSAC then least squares on
    the inliers. Returns ((4,) plane with unit n, inlier mask) or None (< 3 points).

    ``min_cos_incidence``: with points in a camera frame (the centre at the origin), only
    hypotheses seen from the centre at ``|n·a| / |a| >=`` this (the cosine of the angle between
    the normal and the ray to the hypothesis' first point ``a``) compete. A plane that (nearly)
    contains the rays holds every point of a band of the image whatever its depth: with a
    threshold of 12 cm (8 cm of range noise) that band is 35 px wide at 3 m, and such a plane
    wins over the true one on a narrow strip of wall; the fitted plane must be seen at that
    angle too (else None)."""
    n = len(points)
    if n < 3:
        return None
    idx = rng.integers(0, n, size=(iterations, 3))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    normals = cross_rows(b - a, c - a)  # np.cross's numbers
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / norm[ok, None]
    d = -(normals * a[ok]).sum(1)
    if min_cos_incidence is not None:
        seen = np.abs(d) >= min_cos_incidence * np.linalg.norm(a[ok], axis=1)
        if not seen.any():
            return None
        normals, d = normals[seen], d[seen]
    best = int(np.argmax(_inlier_counts(points, normals, d, threshold)))
    # the best plane's column of the (N, I) table: a product with two columns is a
    # matrix-matrix one, whose entries are the table's bit for bit
    cols = [best, best] if len(normals) > 1 else [best]
    inl = np.abs(points @ normals[cols].T + d[cols])[:, 0] < threshold
    if inl.sum() < 3:
        return None
    p = points[inl]
    centroid = p.mean(0)
    _, _, vt = np.linalg.svd(p - centroid, full_matrices=False)
    nrm = vt[2]
    plane = np.concatenate([nrm, [-nrm @ centroid]])
    if min_cos_incidence is not None and abs(plane[3]) < min_cos_incidence * float(
            np.linalg.norm(centroid)):
        return None  # the least squares of a narrow strip of inliers turned edge-on
    inl = np.abs(points @ nrm + plane[3]) < threshold
    return plane, inl


def _median(a: F64) -> float:
    """``float(np.median(a))`` of a 1-D float64 array bit for bit (the same partition; np.mean's
    sum of the middle one or two, which starts from +0, over their count; NaN when a NaN is
    present or ``a`` is empty), without np.median's generic-axis handling (~3× cheaper on the
    refits' few thousand distances)."""
    n = len(a)
    if n == 0:
        return float("nan")
    half = n // 2
    kth = [half, n - 1] if n % 2 else [half - 1, half, n - 1]
    part = np.partition(a, kth)
    if np.isnan(part[-1]):
        return float("nan")
    if n % 2:
        return float(0.0 + part[half])
    return float((0.0 + part[half - 1] + part[half]) / 2.0)


def refit_plane_robust(points: F64, plane: F64, threshold: float, sigmas: float,
                       iterations: int) -> F64:
    """``plane`` (4,) (unit normal) refitted by least squares to the ``points`` (N, 3) within
    ``max(threshold, sigmas * s)`` of the previous fit, ``s`` = 1.4826 x the median absolute
    distance (a robust standard deviation), ``iterations`` times; the normal keeps its side.
    Unbiased where the points' noise is as wide as ``threshold`` (a window of the threshold
    alone truncates the noise around the plane it started from)."""
    for _ in range(iterations):
        dist = points @ plane[:3] + plane[3]
        scale = 1.4826 * _median(np.abs(dist))
        keep = np.abs(dist) < max(threshold, sigmas * scale)
        if keep.sum() < 3:
            break
        p = points[keep]
        centroid = p.mean(0)
        _, _, vt = np.linalg.svd(p - centroid, full_matrices=False)
        nrm = vt[2] if vt[2] @ plane[:3] >= 0 else -vt[2]
        plane = np.concatenate([nrm, [-nrm @ centroid]])
    return plane


def _region_planes(
    points: F64, opts: PlanarSmoothingOptions, rng: np.random.Generator,
    min_points: int | None = None, refit_iterations: int = 0,
) -> list[F64]:
    """Up to ``opts.max_planes`` planes ``(4,)`` through ``points`` (N, 3), by RANSAC, each on the
    points further than ``assign_threshold_m`` from the earlier ones; a plane needs
    ``min_points`` inliers (None: ``opts.min_region_px``); each plane refitted
    ``refit_iterations`` times (:func:`refit_plane_robust`) to the points within
    ``assign_threshold_m`` of it."""
    need = opts.min_region_px if min_points is None else min_points
    planes: list[F64] = []
    left = points
    while len(planes) < opts.max_planes and len(left) >= need:
        pick = rng.choice(len(left), size=min(opts.sample_size, len(left)), replace=False)
        fit = fit_plane_ransac(left[pick], opts.ransac_threshold_m, opts.ransac_iterations, rng,
                               float(np.cos(np.deg2rad(opts.max_incidence_deg)))
                               if opts.reject_oblique else None)
        if fit is None:
            break
        plane = fit[0]
        if refit_iterations > 0:
            near = np.abs(left @ plane[:3] + plane[3]) <= opts.assign_threshold_m
            plane = refit_plane_robust(left[near], plane, opts.ransac_threshold_m,
                                       opts.returns_refit_sigmas, refit_iterations)
        dist = np.abs(left @ plane[:3] + plane[3])
        if (dist < opts.ransac_threshold_m).sum() < need:
            break
        planes.append(plane)
        # Drop everything the plane may claim, not only its RANSAC inliers: the noise tail of
        # a big wall would otherwise make a ghost plane parallel to it a few centimetres away.
        left = left[dist > opts.assign_threshold_m]
    return planes


def _points(x: F64, y: F64, z: F64) -> F64:
    """(N, 3) points ``rays · z`` for rays ``(x, y, 1)`` (N,) each and z-depths ``z`` (N,): the
    products ``Camera.backproject`` forms (``1 · z`` is ``z``)."""
    p = np.empty((len(z), 3))
    np.multiply(x, z, out=p[:, 0])
    np.multiply(y, z, out=p[:, 1])
    p[:, 2] = z
    return p


def _smooth_region(
    out: F32,
    depth: F32,
    flat: NDArray[np.int64],
    width: int,
    camera: Camera,
    opts: PlanarSmoothingOptions,
    rng: np.random.Generator,
    measured: F32 | None = None,
) -> None:
    """Move the depth of one connected region's pixels onto the nearest of its planes, in place;
    the planes are fitted to the region's returns (``measured``, 0 = none) when it has
    ``opts.min_region_returns`` of them and ``opts.fit_to`` asks for it, else to its pixels.

    ``out``, ``depth``, ``measured``: (H·W,) raveled maps; ``flat``: (N,) the region's pixels
    (raveled indices, row-major order) of an image ``width`` pixels wide seen by the pinhole
    ``camera``.
    """
    from bimcap import _core

    # the pixels' rays (x, y, 1) as Camera.rays forms them, their depth, and the points of those
    # with a return (_points of the rays and the returns' depths), in one compiled pass
    # (bimcap/raster/region_rays.h)
    use_returns = measured is not None and opts.fit_to is PlaneFitPoints.RETURNS
    x, y, cur, p_ret = _core.region_rays(flat, width, camera.fx, camera.fy, camera.cx, camera.cy,
                                         depth, measured if use_returns else None)
    planes: list[F64] = []
    if use_returns and len(p_ret) >= opts.min_region_returns:
        planes = _region_planes(p_ret, opts, rng, opts.min_region_returns,
                                opts.returns_refit_iterations)
        if planes:
            pl = np.stack(planes)
            d_ret = np.abs(p_ret @ pl[:, :3].T + pl[:, 3]).min(1)
            if 1.4826 * _median(d_ret) > opts.returns_max_sigma_m:
                planes = []  # the returns too noisy for their fit: the pixels'
    if not planes:
        planes = _region_planes(_points(x, y, cur), opts, rng)
    if not planes:
        return
    pl = np.stack(planes)  # (K, 4)
    products = None
    if len(pl) > 1 and len(flat) < 2:
        # one pixel: numpy's matrix-vector product (rounded otherwise than the matrix-matrix
        # products that move_onto_planes forms for two pixels or more)
        products = _points(x, y, cur) @ pl[:, :3].T
    # each pixel onto its nearest plane along its ray, where that changes its depth by at most
    # max_change_rel (with K > 1 planes: where the nearest is within assign_threshold_m, the
    # products p · n_k formed as numpy's `_points(x, y, cur) @ pl[:, :3].T`); numpy's arithmetic
    # in compiled code (cpp/bimcap/raster/plane_depth.h)
    _core.move_onto_planes(out, flat, x, y, cur, pl, products, opts.assign_threshold_m,
                           opts.max_change_rel)


def smooth_planar_regions(
    depth: ArrayLike,
    labels: ArrayLike,
    camera: Camera,
    options: PlanarSmoothingOptions | None = None,
    seed: int = 0,
    measured: ArrayLike | None = None,
) -> F32:
    """Smooth dense depth inside planar regions (floor, ceiling, walls).

    Parameters
    ----------
    depth: (H, W) float32 metres (0 = unknown), undistorted pinhole pixels of ``camera``.
    labels: (H, W) uint8 label ids.
    camera: the pinhole camera of ``depth`` (its distortion is ignored).
    options: :class:`PlanarSmoothingOptions`; ``PLANE_FIT`` fits, per connected region of each
        class, up to ``max_planes`` RANSAC planes to the back-projected pixels and moves each
        pixel that lies within ``assign_threshold_m`` of its nearest plane onto it (its depth
        becomes the plane's along the pixel ray); ``BLUR`` is the paper's blur (normalised
        Gaussian, so that nothing outside the region or unknown leaks in).
    seed: RANSAC seed.
    measured: (H, W) float32 depth of the sensor's own returns at their pixels (0 = none; the
        sparse map ``depth`` was completed from); with ``options.fit_to`` RETURNS the planes are
        fitted to them (:class:`PlanarSmoothingOptions`). None: to the pixels.

    Returns
    -------
    (H, W) float32 smoothed depth (a new array).
    """
    import cv2

    from bimcap import _core

    opts = options or PlanarSmoothingOptions()
    d = np.asarray(depth, dtype=np.float32)
    lab = np.asarray(labels)
    if d.shape != lab.shape or d.shape != (camera.height, camera.width):
        raise FusionInputError(
            f"depth {d.shape}, labels {lab.shape} and camera {camera.height}x{camera.width} differ",
            field="labels",
        )
    meas = None if measured is None else np.asarray(measured, dtype=np.float32)
    if meas is not None and meas.shape != d.shape:
        raise FusionInputError(f"measured depth {meas.shape} and depth {d.shape} differ",
                               field="measured")
    out = d.copy()
    out_flat, d_flat = out.ravel(), d.ravel()
    meas_flat = None if meas is None else meas.ravel()
    rng = np.random.default_rng(seed)
    for label in opts.labels:
        mask = ((lab == int(label)) & (d > 0)).astype(np.uint8)
        if mask.sum() < opts.min_region_px:
            continue
        if opts.mode is PlanarSmoothing.BLUR:
            m = mask.astype(np.float32)
            num = cv2.GaussianBlur(d * m, (0, 0), opts.blur_sigma_px)
            den = cv2.GaussianBlur(m, (0, 0), opts.blur_sigma_px)
            sel = mask > 0
            out[sel] = num[sel] / np.maximum(den[sel], 1e-6)
            continue
        # the labels alone (OpenCV's same labelling without the statistics and centroids,
        # ~1.5x cheaper); every component's pixels in row-major order (what
        # np.nonzero(comp == c) gives), grouped by component in one pass (a counting sort in
        # bimcap._core), their counts the components' areas
        n_comp, comp = cv2.connectedComponents(mask, connectivity=4)
        pixels, starts = _core.component_pixels(comp, n_comp)
        area = np.diff(starts)
        big = [c for c in range(1, n_comp) if area[c] >= opts.min_region_px]
        if not big:
            continue
        for c in big:
            _smooth_region(out_flat, d_flat, pixels[starts[c]:starts[c + 1]], d.shape[1], camera,
                           opts, rng, meas_flat)
    return out
