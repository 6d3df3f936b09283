"""The front end's previous implementations of the stages made faster (issue 14), kept as oracles.

Each ``*_reference`` function is the code as it was before the speed-up, verbatim; the tests
check that the new code gives the same arrays bit for bit on real frames, and
``bench/bench_frontend.py --world`` times both in one process (``REFERENCES``: stage name → a
context in which that stage runs the old code, swapped into its module).
"""

from __future__ import annotations

import functools
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from itertools import repeat
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.fusion.completion import (
    FusionInputError,
    LinearOptions,
    PlanarSmoothing,
    PlanarSmoothingOptions,
    PlaneFitPoints,
    SparseDepth,
    _points,
    _region_planes,
    _require_points,
    _sparse_arrays,
)
from bimcap.geometry.camera import Camera
from bimcap.labels import Label
from bimcap.segmentation.geometric import GeometricOptions, _Plane, _threshold

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
B = NDArray[np.bool_]
U8 = NDArray[np.uint8]


def pixel_surface_area_reference(depth: NDArray[np.floating], camera: Camera,
                                 min_cos: float = 0.1) -> F64:
    """``bimcap.frontend.semantic_map.pixel_surface_area`` before issue 14 (stacked points)."""
    z = np.asarray(depth, dtype=np.float64)
    h, w = z.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (u - camera.cx) / camera.fx * z
    y = (v - camera.cy) / camera.fy * z
    p = np.stack([x, y, z], axis=-1)
    du = np.gradient(p, axis=1)
    dv = np.gradient(p, axis=0)
    n = np.cross(du, dv)
    nn = np.linalg.norm(n, axis=-1)
    pn = np.linalg.norm(p, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs((n * p).sum(axis=-1)) / (nn * pn)
    cos = np.where(np.isfinite(cos), cos, 1.0)
    cos = np.clip(cos, min_cos, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_alpha = np.where(pn > 0, z / pn, 1.0)
    return np.where(z > 0, z * z * cos_alpha / (camera.fx * camera.fy) / cos, 0.0)


# ------------------------------------------------------------- fusion.completion
def complete_linear_reference(sparse: SparseDepth | ArrayLike,
                              options: LinearOptions | None = None) -> F32:
    """``bimcap.fusion.completion.complete_linear`` before issue 14 (one ``fillConvexPoly`` call
    a triangle with numpy scalars, 2-D gathers)."""
    import cv2
    from scipy.spatial import Delaunay, QhullError

    opts = options or LinearOptions()
    depth, uv, z = _sparse_arrays(sparse)
    _require_points(z, 3)
    h, w = depth.shape
    try:
        tri = Delaunay(uv)
    except QhullError as exc:
        raise FusionInputError(
            f"cannot triangulate the sparse returns: {exc}", field="sparse_depth"
        ) from None
    simp = tri.simplices
    pa, pb, pc = uv[simp[:, 0]], uv[simp[:, 1]], uv[simp[:, 2]]
    edge = np.maximum.reduce(
        [
            np.linalg.norm(pa - pb, axis=1),
            np.linalg.norm(pb - pc, axis=1),
            np.linalg.norm(pc - pa, axis=1),
        ]
    )
    zt = z[simp]
    ratio = zt.max(1) / zt.min(1)
    e1, e2 = pb - pa, pc - pa
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # twice the signed area, px²
    good = (edge <= opts.max_edge_px) & (ratio <= opts.max_depth_ratio) & (np.abs(det) > 2.0)
    # rasterise triangle ids (cv2 fill in a loop over kept triangles is far faster than
    # Delaunay.find_simplex on every pixel); id 0 = none
    tri_id = np.zeros((h, w), dtype=np.int32)
    good_idx = np.flatnonzero(good)
    # 4 fractional bits
    corners = np.rint(np.stack([pa, pb, pc], 1)[good_idx] * 16).astype(np.int32)
    for k, poly in zip(good_idx, corners, strict=True):
        cv2.fillConvexPoly(tri_id, poly, int(k) + 1, lineType=cv2.LINE_8, shift=4)
    rows, cols = np.nonzero(tri_id)
    k = tri_id[rows, cols] - 1
    # per triangle, the affine function f(u, v) = a u + b v + c through its three corners, with
    # f = 1/z (exact for a plane seen through a pinhole) or f = z; one gather per pixel. Pixel
    # centres up to half a pixel outside their rasterised triangle are extrapolated (exact for
    # a plane); slivers (area < 1 px²) were dropped above, so this stays well conditioned.
    gi = good_idx
    mat = np.ones((len(gi), 3, 3))
    mat[:, :, :2] = np.stack([pa[gi], pb[gi], pc[gi]], 1)
    vals = 1.0 / zt[gi] if opts.inverse_depth else zt[gi]
    coef_good = np.linalg.solve(mat, vals[:, :, None])[:, :, 0]
    coef = np.zeros((len(simp), 3))
    coef[gi] = coef_good
    ck = coef[k]
    f = ck[:, 0] * cols + ck[:, 1] * rows + ck[:, 2]
    out = np.zeros((h, w), dtype=np.float32)
    if opts.inverse_depth:
        out[rows, cols] = np.where(f > 0, 1.0 / np.maximum(f, 1e-12), 0.0)
    else:
        out[rows, cols] = np.maximum(f, 0.0)
    return out


def fit_plane_ransac_reference(
    points: F64, threshold: float, iterations: int, rng: np.random.Generator
) -> tuple[F64, NDArray[np.bool_]] | None:
    """Robust plane ``n·p + d = 0`` through points (N, 3): 3-point RANSAC then least squares on
    the inliers. Returns ((4,) plane with unit n, inlier mask) or None (< 3 points)."""
    n = len(points)
    if n < 3:
        return None
    idx = rng.integers(0, n, size=(iterations, 3))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    normals = np.cross(b - a, c - a)
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / norm[ok, None]
    d = -(normals * a[ok]).sum(1)
    dist = np.abs(points @ normals.T + d)  # (N, I)
    best = int(np.argmax((dist < threshold).sum(0)))
    inl = dist[:, best] < threshold
    if inl.sum() < 3:
        return None
    p = points[inl]
    centroid = p.mean(0)
    _, _, vt = np.linalg.svd(p - centroid, full_matrices=False)
    nrm = vt[2]
    plane = np.concatenate([nrm, [-nrm @ centroid]])
    inl = np.abs(points @ nrm + plane[3]) < threshold
    return plane, inl


def region_planes_reference(
    points: F64, opts: PlanarSmoothingOptions, rng: np.random.Generator
) -> list[F64]:
    """Up to ``opts.max_planes`` planes ``(4,)`` through ``points`` (N, 3), by RANSAC, each on the
    points further than ``assign_threshold_m`` from the earlier ones; a plane needs
    ``opts.min_region_px`` inliers."""
    planes: list[F64] = []
    left = points
    while len(planes) < opts.max_planes and len(left) >= opts.min_region_px:
        pick = rng.choice(len(left), size=min(opts.sample_size, len(left)), replace=False)
        fit = fit_plane_ransac_reference(left[pick], opts.ransac_threshold_m,
                                         opts.ransac_iterations, rng)
        if fit is None:
            break
        plane = fit[0]
        dist = np.abs(left @ plane[:3] + plane[3])
        if (dist < opts.ransac_threshold_m).sum() < opts.min_region_px:
            break
        planes.append(plane)
        # Drop everything the plane may claim, not only its RANSAC inliers: the noise tail of
        # a big wall would otherwise make a ghost plane parallel to it a few centimetres away.
        left = left[dist > opts.assign_threshold_m]
    return planes


def smooth_region_reference(
    out: F32,
    depth: F32,
    rows: NDArray[np.int64],
    cols: NDArray[np.int64],
    camera: Camera,
    opts: PlanarSmoothingOptions,
    rng: np.random.Generator,
) -> None:
    """Move the depth of one connected region's pixels onto the nearest of its planes, in place."""
    uv = np.stack([cols, rows], 1).astype(np.float64)
    cur = depth[rows, cols].astype(np.float64)
    pts = camera.backproject(uv, cur, distorted=False)
    planes = region_planes_reference(pts, opts, rng)
    if not planes:
        return
    pl = np.stack(planes)  # (K, 4)
    dist = np.abs(pts @ pl[:, :3].T + pl[:, 3])  # (N, K)
    best = np.argmin(dist, axis=1)
    near = (
        np.ones(len(pts), dtype=bool)
        if len(pl) == 1
        else (dist[np.arange(len(pts)), best] <= opts.assign_threshold_m)
    )
    rays = camera.rays(uv, distorted=False)
    denom = (rays * pl[best, :3]).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_plane = -pl[best, 3] / denom
    ok = (
        near
        & np.isfinite(z_plane)
        & (z_plane > 0)
        & (np.abs(z_plane - cur) <= opts.max_change_rel * cur)
    )
    out[rows[ok], cols[ok]] = z_plane[ok].astype(np.float32)


def _smoothing_inputs(depth: ArrayLike, labels: ArrayLike, camera: Camera,
                      measured: ArrayLike | None) -> tuple[F32, NDArray[Any], F32 | None]:
    """The checks and conversions the frozen ``smooth_planar_regions`` of a219de7 and fe4da1c
    open with, verbatim: (depth float32, labels, measured float32 or None)."""
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
    return d, lab, meas


def _blur_region(out: F32, d: F32, mask: NDArray[np.uint8], sigma_px: float) -> None:
    """``PlanarSmoothing.BLUR`` of one class's mask into ``out``, as every frozen smoothing
    does it (a normalised Gaussian: nothing outside the mask leaks in)."""
    import cv2

    m = mask.astype(np.float32)
    num = cv2.GaussianBlur(d * m, (0, 0), sigma_px)
    den = cv2.GaussianBlur(m, (0, 0), sigma_px)
    sel = mask > 0
    out[sel] = num[sel] / np.maximum(den[sel], 1e-6)


def smooth_planar_regions_reference(
    depth: ArrayLike,
    labels: ArrayLike,
    camera: Camera,
    options: PlanarSmoothingOptions | None = None,
    seed: int = 0,
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

    Returns
    -------
    (H, W) float32 smoothed depth (a new array).
    """
    import cv2

    opts = options or PlanarSmoothingOptions()
    d = np.asarray(depth, dtype=np.float32)
    lab = np.asarray(labels)
    if d.shape != lab.shape or d.shape != (camera.height, camera.width):
        raise FusionInputError(
            f"depth {d.shape}, labels {lab.shape} and camera {camera.height}x{camera.width} differ",
            field="labels",
        )
    out = d.copy()
    rng = np.random.default_rng(seed)
    for label in opts.labels:
        mask = ((lab == int(label)) & (d > 0)).astype(np.uint8)
        if mask.sum() < opts.min_region_px:
            continue
        if opts.mode is PlanarSmoothing.BLUR:
            _blur_region(out, d, mask, opts.blur_sigma_px)
            continue
        n_comp, comp = cv2.connectedComponents(mask, connectivity=4)
        for c in range(1, n_comp):
            rows, cols = np.nonzero(comp == c)
            if len(rows) < opts.min_region_px:
                continue
            smooth_region_reference(out, d, rows, cols, camera, opts, rng)
    return out


# ------------------------------------------------------------- a219de7
# ``pixel_surface_area`` and ``complete_linear`` as of a219de7 (after the first speed-ups of
# issue 14, before the vectorised stages), verbatim but for the names: what the bench's
# previous-code column times.
def pixel_surface_area_a219de7(depth: NDArray[np.floating], camera: Camera,
                              min_cos: float = 0.1) -> F64:
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


def _complete_linear_reference(sparse: SparseDepth | ArrayLike, options: LinearOptions | None,
                               float_grid: bool) -> F32:
    """``complete_linear`` as of a219de7 (``float_grid`` False: each covered pixel's row and
    column by ``np.divmod``) or c52a7fb (True: gathered from the cached float64 pixel grid);
    otherwise verbatim. LINEAR: Delaunay barycentric interpolation; pixels outside the hull or
    in masked triangles stay 0."""
    import cv2
    from scipy.spatial import Delaunay, QhullError

    opts = options or LinearOptions()
    depth, uv, z = _sparse_arrays(sparse)
    _require_points(z, 3)
    h, w = depth.shape
    try:
        tri = Delaunay(uv)
    except QhullError as exc:
        raise FusionInputError(
            f"cannot triangulate the sparse returns: {exc}", field="sparse_depth"
        ) from None
    simp = tri.simplices
    pa, pb, pc = uv[simp[:, 0]], uv[simp[:, 1]], uv[simp[:, 2]]
    edge = np.maximum.reduce(
        [
            np.linalg.norm(pa - pb, axis=1),
            np.linalg.norm(pb - pc, axis=1),
            np.linalg.norm(pc - pa, axis=1),
        ]
    )
    zt = z[simp]
    ratio = zt.max(1) / zt.min(1)
    e1, e2 = pb - pa, pc - pa
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # twice the signed area, px²
    good = (edge <= opts.max_edge_px) & (ratio <= opts.max_depth_ratio) & (np.abs(det) > 2.0)
    # rasterise triangle ids (cv2 fill in a loop over kept triangles is far faster than
    # Delaunay.find_simplex on every pixel); id 0 = none
    tri_id = np.zeros((h, w), dtype=np.int32)
    good_idx = np.flatnonzero(good)
    # 4 fractional bits
    corners = np.rint(np.stack([pa, pb, pc], 1)[good_idx] * 16).astype(np.int32)
    fill, line8 = cv2.fillConvexPoly, cv2.LINE_8
    for tid, poly in zip((good_idx + 1).tolist(), list(corners), strict=True):
        fill(tri_id, poly, tid, line8, 4)
    flat = np.flatnonzero(tri_id)
    k = tri_id.ravel()[flat] - 1
    if float_grid:
        grid_rows, grid_cols = pixel_grid_c52a7fb(h, w)
        rows, cols = grid_rows[flat], grid_cols[flat]
    else:
        rows, cols = np.divmod(flat, w)
    # per triangle, the affine function f(u, v) = a u + b v + c through its three corners, with
    # f = 1/z (exact for a plane seen through a pinhole) or f = z; one gather per pixel. Pixel
    # centres up to half a pixel outside their rasterised triangle are extrapolated (exact for
    # a plane); slivers (area < 1 px²) were dropped above, so this stays well conditioned.
    gi = good_idx
    mat = np.ones((len(gi), 3, 3))
    mat[:, :, :2] = np.stack([pa[gi], pb[gi], pc[gi]], 1)
    vals = 1.0 / zt[gi] if opts.inverse_depth else zt[gi]
    coef_good = np.linalg.solve(mat, vals[:, :, None])[:, :, 0]
    coef = np.zeros((3, len(simp)))
    coef[:, gi] = coef_good.T
    f = coef[0][k] * cols + coef[1][k] * rows + coef[2][k]
    out = np.zeros(h * w, dtype=np.float32)
    if opts.inverse_depth:
        out[flat] = np.where(f > 0, 1.0 / np.maximum(f, 1e-12), 0.0)
    else:
        out[flat] = np.maximum(f, 0.0)
    return out.reshape(h, w)


def complete_linear_a219de7(sparse: SparseDepth | ArrayLike,
                            options: LinearOptions | None = None) -> F32:
    """``bimcap.fusion.completion.complete_linear`` as of a219de7."""
    return _complete_linear_reference(sparse, options, float_grid=False)


# ------------------------------------------------------------- planar smoothing at a219de7
# ``bimcap.fusion.completion._smooth_region`` / ``smooth_planar_regions`` as of a219de7 (with the
# returns' fit), before the vectorised stages; verbatim but for the names.
def smooth_region_a219de7(
    out: F32,
    depth: F32,
    rows: NDArray[np.int64],
    cols: NDArray[np.int64],
    camera: Camera,
    opts: PlanarSmoothingOptions,
    rng: np.random.Generator,
    measured: F32 | None = None,
) -> None:
    """Move the depth of one connected region's pixels onto the nearest of its planes, in place;
    the planes are fitted to the region's returns (``measured`` (H, W), 0 = none) when it has
    ``opts.min_region_returns`` of them and ``opts.fit_to`` asks for it, else to its pixels."""
    uv = np.stack([cols, rows], 1).astype(np.float64)
    cur = depth[rows, cols].astype(np.float64)
    rays = camera.rays(uv, distorted=False)
    pts = rays * cur[:, None]  # camera.backproject, sharing its rays with the plane depths below
    planes: list[F64] = []
    if measured is not None and opts.fit_to is PlaneFitPoints.RETURNS:
        z_ret = measured[rows, cols].astype(np.float64)
        has = z_ret > 0
        if has.sum() >= opts.min_region_returns:
            p_ret = rays[has] * z_ret[has, None]
            planes = _region_planes(p_ret, opts, rng, opts.min_region_returns,
                                    opts.returns_refit_iterations)
            if planes:
                pl = np.stack(planes)
                d_ret = np.abs(p_ret @ pl[:, :3].T + pl[:, 3]).min(1)
                if 1.4826 * float(np.median(d_ret)) > opts.returns_max_sigma_m:
                    planes = []  # the returns too noisy for their fit: the pixels'
    if not planes:
        planes = _region_planes(pts, opts, rng)
    if not planes:
        return
    pl = np.stack(planes)  # (K, 4)
    dist = np.abs(pts @ pl[:, :3].T + pl[:, 3])  # (N, K)
    best = np.argmin(dist, axis=1)
    near = (
        np.ones(len(pts), dtype=bool)
        if len(pl) == 1
        else (dist[np.arange(len(pts)), best] <= opts.assign_threshold_m)
    )
    denom = (rays * pl[best, :3]).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_plane = -pl[best, 3] / denom
    ok = (
        near
        & np.isfinite(z_plane)
        & (z_plane > 0)
        & (np.abs(z_plane - cur) <= opts.max_change_rel * cur)
    )
    out[rows[ok], cols[ok]] = z_plane[ok].astype(np.float32)


def smooth_planar_regions_a219de7(
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

    opts = options or PlanarSmoothingOptions()
    d, lab, meas = _smoothing_inputs(depth, labels, camera, measured)
    out = d.copy()
    rng = np.random.default_rng(seed)
    for label in opts.labels:
        mask = ((lab == int(label)) & (d > 0)).astype(np.uint8)
        if mask.sum() < opts.min_region_px:
            continue
        if opts.mode is PlanarSmoothing.BLUR:
            _blur_region(out, d, mask, opts.blur_sigma_px)
            continue
        n_comp, comp, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4)
        big = [c for c in range(1, n_comp) if stats[c, cv2.CC_STAT_AREA] >= opts.min_region_px]
        if not big:
            continue
        # every big component's pixels in row-major order (what np.nonzero(comp == c) gives),
        # from one stable sort instead of one pass over the image per component
        flat = np.flatnonzero(comp)
        ids = comp.ravel()[flat]
        order = np.argsort(ids, kind="stable")
        starts = np.searchsorted(ids[order], np.arange(n_comp + 1))
        for c in big:
            rows, cols = np.divmod(flat[order[starts[c]:starts[c + 1]]], comp.shape[1])
            smooth_region_a219de7(out, d, rows, cols, camera, opts, rng, meas)
    return out


# ------------------------------------------------------------- planar smoothing at fe4da1c
# ``bimcap.fusion.completion._smooth_region`` / ``smooth_planar_regions`` as of fe4da1c (numpy's
# ray-plane intersections and distance minima), before they moved to ``bimcap._core``
# (``move_onto_planes``); verbatim but for the names.
def smooth_region_fe4da1c(
    out: F32,
    depth: F32,
    flat: NDArray[np.int64],
    ray_x: F64,
    ray_y: F64,
    opts: PlanarSmoothingOptions,
    rng: np.random.Generator,
    measured: F32 | None = None,
) -> None:
    """Move the depth of one connected region's pixels onto the nearest of its planes, in place;
    the planes are fitted to the region's returns (``measured``, 0 = none) when it has
    ``opts.min_region_returns`` of them and ``opts.fit_to`` asks for it, else to its pixels.

    ``out``, ``depth``, ``measured``: (H·W,) raveled maps; ``flat``: (N,) the region's pixels
    (raveled indices, row-major order); ``ray_x``, ``ray_y``: (H·W,) the pinhole rays' x and y
    (z = 1) of every pixel (``Camera.rays``).
    """
    x, y = ray_x[flat], ray_y[flat]
    cur = depth[flat].astype(np.float64)
    pts = None
    planes: list[F64] = []
    if measured is not None and opts.fit_to is PlaneFitPoints.RETURNS:
        z_ret = measured[flat].astype(np.float64)
        has = z_ret > 0
        if has.sum() >= opts.min_region_returns:
            p_ret = _points(x[has], y[has], z_ret[has])
            planes = _region_planes(p_ret, opts, rng, opts.min_region_returns,
                                    opts.returns_refit_iterations)
            if planes:
                pl = np.stack(planes)
                d_ret = np.abs(p_ret @ pl[:, :3].T + pl[:, 3]).min(1)
                if 1.4826 * float(np.median(d_ret)) > opts.returns_max_sigma_m:
                    planes = []  # the returns too noisy for their fit: the pixels'
    if not planes:
        pts = _points(x, y, cur)
        planes = _region_planes(pts, opts, rng)
    if not planes:
        return
    pl = np.stack(planes)  # (K, 4)
    if len(pl) == 1:  # every pixel on the one plane
        near: NDArray[np.bool_] | bool = True
        n0, n1, n2, offset = pl[0]
        denom = x * n0 + y * n1 + n2  # the ray (x, y, 1) · n, summed left to right
    else:
        if pts is None:
            pts = _points(x, y, cur)
        dist = pts @ pl[:, :3].T  # (N, K) |n·p + d|, in place
        dist += pl[:, 3]
        np.abs(dist, out=dist)
        best = np.argmin(dist, axis=1)
        nearest = dist[:, 0].copy()  # the minimum column by column: min(axis=1)'s values
        for k in range(1, len(pl)):
            np.minimum(nearest, dist[:, k], out=nearest)
        near = nearest <= opts.assign_threshold_m
        denom = x * pl[best, 0] + y * pl[best, 1] + pl[best, 2]
        offset = pl[best, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        z_plane = -offset / denom
    ok = (
        np.isfinite(z_plane)
        & (z_plane > 0)
        & (np.abs(z_plane - cur) <= opts.max_change_rel * cur)
    )
    if near is not True:
        ok &= near
    out[flat[ok]] = z_plane[ok].astype(np.float32)


def move_onto_planes_fe4da1c(out: F32, flat: NDArray[np.int64], x: F64, y: F64, cur: F64,
                             pl: F64, products: F64 | None, assign_threshold_m: float,
                             max_change_rel: float) -> None:
    """The per-pixel half of :func:`smooth_region_fe4da1c` (from its ``pl = np.stack(planes)``
    on), verbatim but for its inputs: the region's rays ``x``, ``y`` and depths ``cur`` (N,),
    its planes ``pl`` (K, 4) and, for K > 1, the product ``pts @ pl[:, :3].T`` (N, K) given."""
    if len(pl) == 1:  # every pixel on the one plane
        near: NDArray[np.bool_] | bool = True
        n0, n1, n2, offset = pl[0]
        denom = x * n0 + y * n1 + n2  # the ray (x, y, 1) · n, summed left to right
    else:
        assert products is not None
        dist = products.copy()  # (N, K) |n·p + d|, in place
        dist += pl[:, 3]
        np.abs(dist, out=dist)
        best = np.argmin(dist, axis=1)
        nearest = dist[:, 0].copy()  # the minimum column by column: min(axis=1)'s values
        for k in range(1, len(pl)):
            np.minimum(nearest, dist[:, k], out=nearest)
        near = nearest <= assign_threshold_m
        denom = x * pl[best, 0] + y * pl[best, 1] + pl[best, 2]
        offset = pl[best, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        z_plane = -offset / denom
    ok = (
        np.isfinite(z_plane)
        & (z_plane > 0)
        & (np.abs(z_plane - cur) <= max_change_rel * cur)
    )
    if near is not True:
        ok &= near
    out[flat[ok]] = z_plane[ok].astype(np.float32)


def component_pixels_fe4da1c(comp: NDArray[np.int32], n_comp: int
                            ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Every component's pixels of :func:`smooth_planar_regions_fe4da1c`, verbatim (one stable
    sort): ``(flat[order], starts)``; component c's are ``flat[order][starts[c]:starts[c+1]]``."""
    flat = np.flatnonzero(comp)
    ids = comp.ravel()[flat]
    order = np.argsort(ids, kind="stable")
    starts = np.searchsorted(ids[order], np.arange(n_comp + 1))
    return flat[order], starts


def smooth_planar_regions_fe4da1c(
    depth: ArrayLike,
    labels: ArrayLike,
    camera: Camera,
    options: PlanarSmoothingOptions | None = None,
    seed: int = 0,
    measured: ArrayLike | None = None,
) -> F32:
    """``smooth_planar_regions`` as of fe4da1c: the same contract as
    :func:`smooth_planar_regions_a219de7` (same arrays), its pixels' rays from two whole-image
    lookups and each region moved by :func:`smooth_region_fe4da1c`."""
    import cv2

    opts = options or PlanarSmoothingOptions()
    d, lab, meas = _smoothing_inputs(depth, labels, camera, measured)
    out = d.copy()
    out_flat, d_flat = out.ravel(), d.ravel()
    meas_flat = None if meas is None else meas.ravel()
    rays: tuple[F64, F64] | None = None  # (H·W,) x and y of the pixels' rays, once needed
    rng = np.random.default_rng(seed)
    for label in opts.labels:
        mask = ((lab == int(label)) & (d > 0)).astype(np.uint8)
        if mask.sum() < opts.min_region_px:
            continue
        if opts.mode is PlanarSmoothing.BLUR:
            _blur_region(out, d, mask, opts.blur_sigma_px)
            continue
        n_comp, comp, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4)
        big = [c for c in range(1, n_comp) if stats[c, cv2.CC_STAT_AREA] >= opts.min_region_px]
        if not big:
            continue
        pixels, starts = component_pixels_fe4da1c(comp, n_comp)
        if rays is None:  # every pixel's ray (x, y, 1), as Camera.rays computes it
            h, w = d.shape
            rays = (np.broadcast_to((np.arange(w, dtype=np.float64) - camera.cx) / camera.fx,
                                    (h, w)).ravel(),
                    np.repeat((np.arange(h, dtype=np.float64) - camera.cy) / camera.fy, w))
        for c in big:
            smooth_region_fe4da1c(out_flat, d_flat, pixels[starts[c]:starts[c + 1]], *rays,
                                  opts, rng, meas_flat)
    return out


# ------------------------------------------------------------- segmentation.geometric at fe4da1c
# ``_points_and_normals`` as of fe4da1c (numpy, component by component), before its per-pixel
# arithmetic moved to ``bimcap._core`` (``points_and_cross``, ``orient_normals``); verbatim but
# for the name.
def points_and_normals_fe4da1c(depth: NDArray[np.float32], cam: Camera,
                              opts: GeometricOptions) -> tuple[F64, B, F64, B]:
    """Points (h, w, 3), valid (h, w), unit normals facing the camera (h, w, 3; 0 where no
    normal) and where there is a normal (h, w), of the depth ``depth`` (h, w) seen by ``cam``.

    The normal is the cross product of the central differences along u and v
    (``normal_step_px``), box-blurred (``normal_smooth_px``), normalised and turned toward the
    camera; computed component by component on the pixels that can have one (``np.cross``,
    ``np.linalg.norm`` and the sum over the last axis do the same products and left-to-right
    sums on stacked (h, w, 3) arrays).
    """
    import cv2

    h, w = depth.shape
    u = (np.arange(w) - cam.cx) / cam.fx
    v = (np.arange(h) - cam.cy) / cam.fy
    z = depth.astype(np.float64)
    pts = np.empty((h, w, 3))
    pts[..., 0] = u[None, :] * z
    pts[..., 1] = v[:, None] * z
    pts[..., 2] = z
    valid = z > 0
    s = opts.normal_step_px
    ok = np.zeros((h, w), dtype=bool)
    zc = z[s:-s, s:-s]
    jump = 0.05 * zc + 0.05  # metres: neighbours farther apart in depth are across an edge
    ok_in = (
        valid[s:-s, s:-s]
        & (z[s:-s, 2 * s :] > 0) & (z[s:-s, : -2 * s] > 0)
        & (z[2 * s :, s:-s] > 0) & (z[: -2 * s, s:-s] > 0)
        & (np.abs(z[s:-s, 2 * s :] - z[s:-s, : -2 * s]) < 2 * jump)
        & (np.abs(z[2 * s :, s:-s] - z[: -2 * s, s:-s]) < 2 * jump)
    )
    ok[s:-s, s:-s] = ok_in
    # central differences du (along u) and dv (along v) where both exist: the interior
    du = [pts[s:-s, 2 * s :, i] - pts[s:-s, : -2 * s, i] for i in range(3)]
    dv = [pts[2 * s :, s:-s, i] - pts[: -2 * s, s:-s, i] for i in range(3)]
    cross = (du[1] * dv[2] - du[2] * dv[1],
             du[2] * dv[0] - du[0] * dv[2],
             du[0] * dv[1] - du[1] * dv[0])
    k = opts.normal_smooth_px
    n = np.zeros((h, w, 3), dtype=np.float32 if k > 1 else np.float64)
    for i in range(3):
        n[s:-s, s:-s, i] = np.where(ok_in, cross[i], 0.0)
    if k > 1:
        n = cv2.blur(n, (k, k)).astype(np.float64)
    n0, n1, n2 = n[..., 0], n[..., 1], n[..., 2]
    norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    ok &= norm > 1e-12
    n /= np.maximum(norm, 1e-12)[..., None]
    flip = (n0 * pts[..., 0] + n1 * pts[..., 1] + n2 * pts[..., 2]) > 0  # face the camera
    np.negative(n, out=n, where=flip[..., None])
    n[~ok] = 0.0
    return pts, valid, n, ok


# ------------------------------------------------------------- segmentation.geometric
def ransac_vertical_reference(pts: F64, nrm: F64, up: F64, opts: GeometricOptions,
                     rng: np.random.Generator) -> _Plane | None:
    """Vertical plane (normal ⟂ up) from points (N, 3) with normals (N, 3): 1-point hypotheses."""
    n = len(pts)
    if n < 3:
        return None
    pick = rng.choice(n, size=min(n, opts.ransac_sample), replace=False)
    sub, sub_n = pts[pick], nrm[pick]
    hyp = rng.integers(0, len(sub), size=opts.ransac_iterations)
    hn = sub_n[hyp] - (sub_n[hyp] @ up)[:, None] * up
    ln = np.linalg.norm(hn, axis=1)
    good = ln > 1e-6
    hn = hn[good] / ln[good, None]
    d = -(hn * sub[hyp[good]]).sum(1)
    thr = _threshold(sub[:, 2], opts)[:, None]
    cos_n = np.cos(np.deg2rad(opts.normal_agreement_deg))
    score = ((np.abs(sub @ hn.T + d) < thr) & (np.abs(sub_n @ hn.T) > cos_n)).sum(0)
    if len(score) == 0:
        return None
    best = int(np.argmax(score))
    inl = (np.abs(sub @ hn[best] + d[best]) < thr[:, 0]) & (np.abs(sub_n @ hn[best]) > cos_n)
    if inl.sum() < 3:
        return None
    # refit: a line in the horizontal plane (coordinates along two horizontal axes)
    e1 = np.cross(up, hn[best])
    e1 /= np.linalg.norm(e1)
    q = sub[inl]
    xy = np.stack([q @ e1, q @ hn[best]], 1)
    c = xy.mean(0)
    _, _, vt = np.linalg.svd(xy - c, full_matrices=False)
    dir2 = vt[0]
    normal2 = np.array([-dir2[1], dir2[0]])
    normal = normal2[0] * e1 + normal2[1] * hn[best]
    normal /= np.linalg.norm(normal)
    if normal @ hn[best] < 0:
        normal = -normal
    centroid = q.mean(0)
    return _Plane(normal, float(-normal @ centroid))


def protrudes_reference(region: B, pts: F64, plane: _Plane, opts: GeometricOptions) -> bool:
    """Does the planar region stand out of what surrounds it on the left and on the right?

    Per row and side, walk outward from the region's edge (up to ``protrusion_px`` pixels) to
    the first pixel with depth that is off the region's plane; the region protrudes on that side
    when that point lies **behind** the plane's extension (a depth jump to the background, or
    the other face of a convex corner: a column). A concave corner (a room corner: the adjacent
    wall is in front of the extension) or an occluder fails. Needs ``protrusion_min_rows`` of
    the decided rows to pass on every decided side (a side is undecided at the image border or
    when fewer than 20 % of the rows find an off-plane pixel), and ``protrusion_sides`` decided
    sides (default 2: a wall seen between the image border and a doorway protrudes on its one
    visible side just as a column does; walls being far more common, a region cut by the image
    border stays a wall).
    """
    rows = np.flatnonzero(region.any(1))
    w = region.shape[1]
    sub = region[rows]
    left = np.argmax(sub, axis=1)
    right = w - 1 - np.argmax(sub[:, ::-1], axis=1)
    cam_side = np.sign(plane.offset) if plane.offset != 0 else 1.0  # the camera (origin) side
    sides = 0
    for edge, step in ((left, -1), (right, 1)):
        decided = np.zeros(len(rows), dtype=bool)
        behind = np.zeros(len(rows), dtype=bool)
        inside_any = np.zeros(len(rows), dtype=bool)
        margin = opts.normal_step_px + 1  # no normals there: the image border for this purpose
        for j in range(1, opts.protrusion_px + 1):
            col = edge + step * j
            inside = (col >= margin) & (col < w - margin)
            inside_any |= inside
            colc = np.clip(col, 0, w - 1)
            p = pts[rows, colc]
            z = p[:, 2]
            sd = p @ plane.normal + plane.offset
            off = inside & (z > 0) & (np.abs(sd) > _threshold(z, opts)) & ~decided
            behind[off] = (sd[off] * cam_side) < 0
            decided |= off
        if inside_any.mean() < 0.5 or decided.mean() < 0.2:
            continue  # the image border, or nothing off the plane nearby: unknown side
        sides += 1
        if behind[decided].mean() < opts.protrusion_min_rows:
            return False
    return sides >= opts.protrusion_sides


def upsample_labels_reference(
    labels: U8,
    region_id: NDArray[np.int32],
    regions: list[tuple[Label, _Plane]],
    depth: NDArray[np.float32],
    camera: Camera,
    opts: GeometricOptions,
) -> U8:
    """Bring work-resolution labels to full resolution, plane-guided along borders.

    Nearest-neighbour upsampling, then every full-resolution pixel in a border cell (a work
    pixel whose 3×3 neighbourhood holds more than one region) takes, among the planar regions
    of that neighbourhood, the one whose plane its own 3-D point lies nearest (if within the
    plane threshold). Plane parameters are scale-free (camera-frame metres), so the work
    resolution's planes apply to full-resolution points directly.
    """
    import cv2

    size = (camera.width, camera.height)
    up = cv2.resize(labels, size, interpolation=cv2.INTER_NEAREST)
    up[depth <= 0] = int(Label.UNKNOWN)
    if not regions:
        return up
    kernel = np.ones((3, 3), np.uint8)
    rid = region_id + 1  # 0 = none
    lo = cv2.erode(rid.astype(np.float32), kernel)
    hi = cv2.dilate(rid.astype(np.float32), kernel)
    border_lo = (lo != hi).astype(np.uint8)
    border = cv2.resize(border_lo, size, interpolation=cv2.INTER_NEAREST) > 0
    border &= depth > 0
    r, c = np.nonzero(border)
    if len(r) == 0:
        return up
    z = depth[r, c].astype(np.float64)
    p = np.stack([(c - camera.cx) / camera.fx * z, (r - camera.cy) / camera.fy * z, z], 1)
    best = _threshold(z, opts) * 2.0
    choice = np.full(len(r), -1, dtype=np.int64)
    for k, (_, plane) in enumerate(regions):
        near_lo = cv2.dilate((region_id == k).astype(np.uint8), kernel)
        near = cv2.resize(near_lo, size, interpolation=cv2.INTER_NEAREST)[r, c] > 0
        dist = np.abs(p @ plane.normal + plane.offset)
        take = near & (dist < best)
        best[take] = dist[take]
        choice[take] = k
    lut = np.array([int(lab) for lab, _ in regions], dtype=np.uint8)
    sel = choice >= 0
    up[r[sel], c[sel]] = lut[choice[sel]]
    return up


# ------------------------------------------------------------- fusion.completion at c52a7fb
@functools.lru_cache(maxsize=4)
def pixel_grid_c52a7fb(h: int, w: int) -> tuple[F64, F64]:
    """``bimcap.fusion.completion._pixel_grid`` as of c52a7fb: (H·W,) float64 row and column of
    every pixel in row-major order (read-only; cached per image size)."""
    rows = np.repeat(np.arange(h, dtype=np.float64), w)
    cols = np.tile(np.arange(w, dtype=np.float64), h)
    rows.flags.writeable = False
    cols.flags.writeable = False
    return rows, cols


def complete_linear_c52a7fb(sparse: SparseDepth | ArrayLike,
                            options: LinearOptions | None = None) -> F32:
    """``bimcap.fusion.completion.complete_linear`` as of c52a7fb (a gather of each covered
    pixel's row and column from the cached pixel grid)."""
    return _complete_linear_reference(sparse, options, float_grid=True)


# ------------------------------------------------------------- semantic_map at ec113ba
#: Rows of :func:`pixel_surface_area_ec113ba` computed at once: its ~40 temporaries then stay in the
#: cache (1.5× cheaper than whole (H, W) float64 images at 516 × 386 on the 2-core box).
_AREA_ROWS_EC113BA = 32


def _gradient_into_ec113ba(c: F64, axis: int, out: F64) -> F64:
    """``np.gradient(c, axis=axis)`` of a 2-D array (unit spacing, first-order ends: the same
    subtractions and halvings) written into ``out``."""
    if axis == 1:
        c, out = c.T, out.T
    np.subtract(c[2:], c[:-2], out=out[1:-1])
    out[1:-1] /= 2.0
    np.subtract(c[1], c[0], out=out[0])
    np.subtract(c[-1], c[-2], out=out[-1])
    return out.T if axis == 1 else out


def pixel_surface_area_ec113ba(depth: NDArray[np.floating], camera: Camera,
                               min_cos: float = 0.1) -> F64:
    """``bimcap.frontend.semantic_map.pixel_surface_area`` as of ec113ba (numpy, in blocks of
    rows), verbatim: the surface area in m² that each pixel of an undistorted depth map covers.

    The pixel's solid angle is ``cos³α / (fx·fy)`` and its range ``z / cos α``, so it covers
    ``z²·cos α / (fx·fy·cos θ)``: α is the angle between the ray and the optical axis, θ between the
    ray and the surface normal from the depth map's gradient (``cos θ`` clamped at ``min_cos``).

    Parameters
    ----------
    depth: (H, W) z-depth in metres (0 = none), H and W at least 2.

    Returns
    -------
    (H, W) float64, 0 where depth is 0.
    """
    z = np.asarray(depth, dtype=np.float64)
    if z.ndim != 2 or min(z.shape) < 2:
        raise ValueError(f"depth must be (H, W) with H, W >= 2, got {z.shape}")
    h, w = z.shape
    # Component by component, the same arithmetic as np.gradient / np.cross / np.linalg.norm on
    # the stacked (H, W, 3) points (bit for bit: tests/test_frontend_speed.py), in blocks of
    # rows, each with one row more on either side for the central differences along v.
    ray_x = (np.arange(w, dtype=np.float64) - camera.cx) / camera.fx
    ray_y = ((np.arange(h, dtype=np.float64) - camera.cy) / camera.fy)[:, None]
    out = np.empty((h, w))
    for a in range(0, h, _AREA_ROWS_EC113BA):
        b = min(h, a + _AREA_ROWS_EC113BA)
        lo, hi = max(0, a - 1), min(h, b + 1)
        zb = z[lo:hi]
        x = ray_x * zb
        y = ray_y[lo:hi] * zb
        xu, yu, zu = (_gradient_into_ec113ba(c, 1, np.empty_like(zb)) for c in (x, y, zb))
        xv, yv, zv = (_gradient_into_ec113ba(c, 0, np.empty_like(zb)) for c in (x, y, zb))
        own = slice(a - lo, b - lo)  # the block's rows (the others' v-gradients are one-sided)
        x, y, zb = x[own], y[own], zb[own]
        xu, yu, zu, xv, yv, zv = (g[own] for g in (xu, yu, zu, xv, yv, zv))
        n0 = yu * zv - zu * yv
        n1 = zu * xv - xu * zv
        n2 = xu * yv - yu * xv
        nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        pn = np.sqrt(x * x + y * y + zb * zb)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.abs(n0 * x + n1 * y + n2 * zb) / (nn * pn)
        cos = np.where(np.isfinite(cos), cos, 1.0)
        cos = np.clip(cos, min_cos, 1.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos_alpha = np.where(pn > 0, zb / pn, 1.0)
        out[a:b] = np.where(zb > 0, zb * zb * cos_alpha / (camera.fx * camera.fy) / cos, 0.0)
    return out


# ------------------------------------------------------------- fusion.completion at ec113ba
@functools.lru_cache(maxsize=4)
def pixel_axes_ec113ba(h: int, w: int) -> tuple[F64, F64]:
    """``bimcap.fusion.completion._pixel_axes`` as of ec113ba: (1, W) float64 columns and
    (H, 1) float64 rows (read-only; cached per image size)."""
    cols = np.arange(w, dtype=np.float64)[None, :]
    rows = np.arange(h, dtype=np.float64)[:, None]
    cols.flags.writeable = False
    rows.flags.writeable = False
    return cols, rows


def triangle_ids_opencv(corners: NDArray[np.int32], ids: NDArray[np.int32], h: int, w: int,
                        shift: int = 4) -> NDArray[np.int32]:
    """The (h, w) triangle-id image of ec113ba's ``complete_linear``: one
    ``cv2.fillConvexPoly(tri_id, corners[t], ids[t], LINE_8, shift)`` a triangle, in order, on a
    zero image (driven by ``map``)."""
    import cv2

    tri_id = np.zeros((h, w), dtype=np.int32)
    deque(map(cv2.fillConvexPoly, repeat(tri_id), list(corners), np.asarray(ids).tolist(),
              repeat(cv2.LINE_8), repeat(shift)), maxlen=0)
    return tri_id


def piecewise_affine_numpy(tri_id: NDArray[np.int32], coef: F64, inverse_depth: bool) -> F32:
    """The per-pixel half of ec113ba's ``complete_linear``: ``coef`` (3, N) gathered by
    ``tri_id`` (H, W), ``f = c0 u + c1 v + c2``, then 1/f or f as float32; verbatim."""
    h, w = tri_id.shape
    cols, rows = pixel_axes_ec113ba(h, w)
    f = coef[0][tri_id]
    f *= cols
    f += coef[1][tri_id] * rows
    f += coef[2][tri_id]
    if inverse_depth:  # noqa: SIM108 (verbatim)
        out = np.where(f > 0, 1.0 / np.maximum(f, 1e-12), 0.0)
    else:
        out = np.maximum(f, 0.0)
    return out.astype(np.float32)


def complete_linear_ec113ba(sparse: SparseDepth | ArrayLike,
                            options: LinearOptions | None = None) -> F32:
    """``bimcap.fusion.completion.complete_linear`` as of ec113ba (one ``cv2.fillConvexPoly``
    call a kept triangle, numpy's per-pixel gathers); verbatim but for the two helpers above."""
    from scipy.spatial import Delaunay, QhullError

    opts = options or LinearOptions()
    depth, uv, z = _sparse_arrays(sparse)
    _require_points(z, 3)
    h, w = depth.shape
    try:
        tri = Delaunay(uv)
    except QhullError as exc:
        raise FusionInputError(
            f"cannot triangulate the sparse returns: {exc}", field="sparse_depth"
        ) from None
    simp = tri.simplices
    pa, pb, pc = uv[simp[:, 0]], uv[simp[:, 1]], uv[simp[:, 2]]
    edge = np.maximum.reduce(
        [
            np.linalg.norm(pa - pb, axis=1),
            np.linalg.norm(pb - pc, axis=1),
            np.linalg.norm(pc - pa, axis=1),
        ]
    )
    zt = z[simp]
    ratio = zt.max(1) / zt.min(1)
    e1, e2 = pb - pa, pc - pa
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # twice the signed area, px²
    good = (edge <= opts.max_edge_px) & (ratio <= opts.max_depth_ratio) & (np.abs(det) > 2.0)
    good_idx = np.flatnonzero(good)
    corners = np.rint(np.stack([pa, pb, pc], 1)[good_idx] * 16).astype(np.int32)
    tri_id = triangle_ids_opencv(corners, good_idx + 1, h, w)
    gi = good_idx
    mat = np.ones((len(gi), 3, 3))
    mat[:, :, :2] = np.stack([pa[gi], pb[gi], pc[gi]], 1)
    vals = 1.0 / zt[gi] if opts.inverse_depth else zt[gi]
    coef_good = np.linalg.solve(mat, vals[:, :, None])[:, :, 0]
    coef = np.zeros((3, len(simp) + 1))
    coef[:, gi + 1] = coef_good.T
    return piecewise_affine_numpy(tri_id, coef, opts.inverse_depth)


# ------------------------------------------------------------- features.matching
def top2_columns_reference(sim: NDArray[np.float32]
                           ) -> tuple[NDArray[np.int64], NDArray[np.float32], NDArray[np.float32]]:
    """``bimcap.features.matching._top2_columns`` before issue 14 (``np.argmax`` on axis 0)."""
    best = np.argmax(sim, axis=0)
    cols = np.arange(sim.shape[1])
    s1 = sim[best, cols].copy()
    sim[best, cols] = -np.inf
    s2 = sim.max(axis=0)
    sim[best, cols] = s1
    return best, s1, s2


def top2_columns_opencv_reference(
    sim: NDArray[np.float32],
) -> tuple[NDArray[np.int64], NDArray[np.float32], NDArray[np.float32]]:
    """``bimcap.features.matching._top2_columns`` as of c52a7fb (issue 14's first matching
    speed-up), verbatim. Per column: what :func:`_top2` gives on ``sim.T``, without copying the
    transpose.

    The column-wise arg-max is OpenCV's (``reduceArgMax``: the first row of the largest value,
    as ``np.argmax``, which copies the transpose and costs 3× as much on a 1200 × 1100 block).
    """
    import cv2

    best = cv2.reduceArgMax(np.ascontiguousarray(sim), 0).ravel().astype(np.int64)
    cols = np.arange(sim.shape[1])
    s1 = sim[best, cols].copy()
    sim[best, cols] = -np.inf
    s2 = sim.max(axis=0)
    sim[best, cols] = s1
    return best, s1, s2


def match_numpy_reference(a: U8, b: U8, opts: Any) -> NDArray[np.int32]:
    """``bimcap.features.matching._match_numpy`` as of c52a7fb, verbatim (a column-wise arg-max
    and top 2 of every block, merged across blocks)."""
    from bimcap.features.matching import ORB_DESCRIPTOR_BYTES, _as_float, _passes, _top2

    binary = a.shape[1] == ORB_DESCRIPTOR_BYTES
    fa, fb = _as_float(a), _as_float(b)
    chunk = 2048
    best_ab = np.empty(len(a), np.int64)
    ok_ab = np.empty(len(a), bool)
    # Column-wise top 2 merged across row chunks for the b → a direction.
    col_s1 = np.full(len(b), -np.inf, np.float32)
    col_s2 = np.full(len(b), -np.inf, np.float32)
    col_best = np.zeros(len(b), np.int64)
    for start in range(0, len(a), chunk):
        sim = fa[start : start + chunk] @ fb.T
        best, s1, s2 = _top2(sim)
        best_ab[start : start + len(sim)] = best
        ok_ab[start : start + len(sim)] = _passes(s1, s2, opts, binary)
        cb, c1, c2 = top2_columns_opencv_reference(sim)
        new_best = c1 > col_s1
        col_s2 = np.where(new_best, np.maximum(col_s1, c2), np.maximum(col_s2, c1))
        col_best = np.where(new_best, cb + start, col_best)
        col_s1 = np.where(new_best, c1, col_s1)
    ia = np.flatnonzero(ok_ab)
    ib = best_ab[ia]
    if opts.cross_check:
        ok_ba = _passes(col_s1, col_s2, opts, binary)
        keep = ok_ba[ib] & (col_best[ib] == ia)
        ia, ib = ia[keep], ib[keep]
    return np.stack([ia, ib], axis=1).astype(np.int32)


def match_numpy_4206b3e(a: U8, b: U8, opts: Any) -> NDArray[np.int32]:
    """``bimcap.features.matching._match_numpy`` as of 4206b3e, verbatim: the similarities as
    one BLAS ``sgemm`` of float32 descriptors, blocks of 2,048 rows (the candidate columns
    multiplied again as rows past one block)."""
    from bimcap.features.matching import ORB_DESCRIPTOR_BYTES, _as_float, _passes, _top2

    binary = a.shape[1] == ORB_DESCRIPTOR_BYTES
    fa, fb = _as_float(a), _as_float(b)
    chunk = 2048
    best_ab = np.empty(len(a), np.int64)
    s1_ab = np.empty(len(a), np.float32)
    ok_ab = np.empty(len(a), bool)
    col_s1 = np.full(len(b), -np.inf, np.float32)
    sim = np.zeros((0, len(b)), np.float32)
    for start in range(0, len(a), chunk):
        sim = fa[start : start + chunk] @ fb.T
        best, s1, s2 = _top2(sim)
        best_ab[start : start + len(sim)] = best
        s1_ab[start : start + len(sim)] = s1
        ok_ab[start : start + len(sim)] = _passes(s1, s2, opts, binary)
        np.maximum(col_s1, sim.max(axis=0), out=col_s1)
    ia = np.flatnonzero(ok_ab)
    ib = best_ab[ia]
    if opts.cross_check:
        # the rows that are their column's best, then those alone in their column
        top = s1_ab[ia] == col_s1[ib]
        ia, ib = ia[top], ib[top]
        alone = np.bincount(ib, minlength=len(b))[ib] == 1
        ia, ib = ia[alone], ib[alone]
        if len(a) <= chunk:  # the one block of rows is still there
            sim[ia, ib] = -np.inf
            col_s2 = sim.max(axis=0)[ib]
        else:  # the candidate columns again, as rows (the same numbers)
            col_s2 = np.empty(len(ib), np.float32)
            for start in range(0, len(ib), chunk):
                part = fb[ib[start : start + chunk]] @ fa.T
                part[np.arange(len(part)), ia[start : start + chunk]] = -np.inf
                col_s2[start : start + len(part)] = part.max(axis=1)
        keep = _passes(col_s1[ib], col_s2, opts, binary)
        ia, ib = ia[keep], ib[keep]
    return np.stack([ia, ib], axis=1).astype(np.int32)


# ------------------------------------------------------------- semantic_map at 02ca12e
# The label orientation check's coarse normals and region plane fits as of 02ca12e (numpy),
# before the normals' per-pixel arithmetic moved to ``bimcap._core`` and the fits' normal
# equations summed each entry once; verbatim but for the names.
def coarse_normals_02ca12e(depth: NDArray[np.floating], camera: Camera, step: int = 4,
                           box: int = 11) -> tuple[F64, NDArray[np.bool_]]:
    """Unit normals (h, w, 3) of a depth map (camera frame) from central differences ``step``
    pixels apart, box-smoothed over ``box`` pixels (coarse: robust to a few cm of range noise),
    and where they are defined (no depth jump, all neighbours with depth)."""
    import cv2

    z = np.asarray(depth, dtype=np.float64)
    h, w = z.shape
    u = (np.arange(w) - camera.cx) / camera.fx
    v = (np.arange(h) - camera.cy) / camera.fy
    pts = np.stack([u[None, :] * z, v[:, None] * z, z], axis=-1)
    s = step
    du = np.zeros_like(pts)
    dv = np.zeros_like(pts)
    du[:, s:-s] = pts[:, 2 * s:] - pts[:, :-2 * s]
    dv[s:-s] = pts[2 * s:] - pts[:-2 * s]
    ok = np.zeros((h, w), dtype=bool)
    zc = z[s:-s, s:-s]
    jump = 2.0 * (0.05 * zc + 0.1)
    ok[s:-s, s:-s] = ((zc > 0) & (z[s:-s, 2 * s:] > 0) & (z[s:-s, :-2 * s] > 0)
                      & (z[2 * s:, s:-s] > 0) & (z[:-2 * s, s:-s] > 0)
                      & (np.abs(z[s:-s, 2 * s:] - z[s:-s, :-2 * s]) < jump)
                      & (np.abs(z[2 * s:, s:-s] - z[:-2 * s, s:-s]) < jump))
    n = np.cross(du, dv)
    n[~ok] = 0.0
    n = cv2.blur(n.astype(np.float32), (box, box)).astype(np.float64)
    norm = np.linalg.norm(n, axis=2)
    ok &= norm > 1e-12
    return n / np.maximum(norm, 1e-12)[..., None], ok


def region_plane_normals_02ca12e(comp: NDArray[np.int32], n_comp: int, valid: NDArray[np.bool_],
                                 depth: NDArray[np.floating], camera: Camera, up: F64,
                                 min_pixels: int = 20) -> list[tuple[int, float]]:
    """Per connected region (ids 1..n_comp-1 of ``comp``) with at least ``min_pixels`` pixels of
    depth: ``(id, |n·up|)`` of the least-squares plane through its points."""
    ids = comp[valid]
    if len(ids) == 0:
        return []
    v, u = np.nonzero(valid)
    x = (u - camera.cx) / camera.fx
    y = (v - camera.cy) / camera.fy
    w = 1.0 / depth[valid].astype(np.float64)
    # per region sums of the normal equations of w ≈ a x + b y + c
    cols = np.stack([x, y, np.ones_like(x)], axis=1)
    count = np.bincount(ids, minlength=n_comp)
    ata = np.zeros((n_comp, 3, 3))
    atb = np.zeros((n_comp, 3))
    for r in range(3):
        atb[:, r] = np.bincount(ids, cols[:, r] * w, minlength=n_comp)
        for c in range(3):
            ata[:, r, c] = np.bincount(ids, cols[:, r] * cols[:, c], minlength=n_comp)
    out = []
    for c in range(1, n_comp):
        if count[c] < min_pixels or abs(np.linalg.det(ata[c])) < 1e-18:
            continue
        n = np.linalg.solve(ata[c], atb[c])
        norm = np.linalg.norm(n)
        if norm > 0:
            out.append((c, float(abs(n @ up) / norm)))
    return out


# ------------------------------------------------------------- segmentation.geometric at 02ca12e
def _row_blocks(n: int) -> list[tuple[int, int]]:
    """``[start, stop)`` blocks of 512 rows covering ``n``, none of one row (a one-row product
    would go to BLAS's matrix-vector routine, whose sums may differ)."""
    starts = list(range(0, n, 512))
    if len(starts) > 1 and n - starts[-1] < 2:
        starts.pop()
    return [(a, b) for a, b in zip(starts, [*starts[1:], n], strict=True)]


def plane_scores_02ca12e(sub: F64, hn: F64, d: F64, thr: F64, sub_n: F64 | None = None,
                         cos_n: float = 0.0) -> NDArray[np.int64]:
    """``_plane_scores`` as of 02ca12e: the blocks' elementwise tests and counts in numpy."""
    if len(hn) < 2:
        ok_whole = np.abs(sub @ hn.T + d) < thr
        if sub_n is not None:
            ok_whole &= np.abs(sub_n @ hn.T) > cos_n
        whole: NDArray[np.int64] = ok_whole.sum(0)
        return whole
    score = np.zeros(len(hn), np.int64)
    for a, b in _row_blocks(len(sub)):
        dist = sub[a:b] @ hn.T
        dist += d
        np.abs(dist, out=dist)
        ok = dist < thr[a:b]
        if sub_n is not None:
            agree = sub_n[a:b] @ hn.T
            np.abs(agree, out=agree)
            ok &= agree > cos_n
        # the block's counts (at most _SCORE_ROWS + 1 < 2¹⁶): a byte-wise sum, not count_nonzero
        score += np.add.reduce(ok.view(np.uint8), axis=0, dtype=np.uint16)
    return score


@contextmanager
def swapped(module: Any, **functions: Callable[..., Any]) -> Iterator[None]:
    """Replace ``module``'s attributes by ``functions`` for the duration of the block."""
    saved = {name: getattr(module, name) for name in functions}
    try:
        for name, fn in functions.items():
            setattr(module, name, fn)
        yield
    finally:
        for name, fn in saved.items():
            setattr(module, name, fn)


def old_semantic_sampling() -> AbstractContextManager[None]:
    from bimcap.frontend import semantic_map

    return swapped(semantic_map, pixel_surface_area=pixel_surface_area_ec113ba)


def old_completion() -> AbstractContextManager[None]:
    from bimcap.fusion import completion

    return swapped(completion, complete_linear=complete_linear_ec113ba)


@contextmanager
def old_planar_smoothing() -> Iterator[None]:
    from bimcap import fusion
    from bimcap.fusion import completion

    with swapped(completion, smooth_planar_regions=smooth_planar_regions_fe4da1c), \
            swapped(fusion, smooth_planar_regions=smooth_planar_regions_fe4da1c):
        yield


def old_segmentation() -> AbstractContextManager[None]:
    """``segment_geometric`` as of fe4da1c / 02ca12e: its points and normals
    (:func:`points_and_normals_fe4da1c`) and its RANSAC score counts
    (:func:`plane_scores_02ca12e`) in numpy. (``_geometric_reference`` is the whole module as
    of a219de7, before the vectorised stages.)"""
    from bimcap.segmentation import geometric

    return swapped(geometric, _points_and_normals=points_and_normals_fe4da1c,
                   _plane_scores=plane_scores_02ca12e)


def old_label_orientation() -> AbstractContextManager[None]:
    """``check_label_orientation`` as of 02ca12e: its coarse normals and region plane fits in
    numpy (:func:`coarse_normals_02ca12e`, :func:`region_plane_normals_02ca12e`)."""
    from bimcap.frontend import semantic_map

    return swapped(semantic_map, _coarse_normals=coarse_normals_02ca12e,
                   _region_plane_normals=region_plane_normals_02ca12e)


def old_matching() -> AbstractContextManager[None]:
    """``_match_numpy`` as of c52a7fb (issue 14's first matching speed-up)."""
    from bimcap.features import matching

    return swapped(matching, _match_numpy=match_numpy_reference)


def float32_matching() -> AbstractContextManager[None]:
    """``_match_numpy`` as of 4206b3e: the products in BLAS float32 (before the integer
    products of ONNX Runtime)."""
    from bimcap.features import matching

    return swapped(matching, _match_numpy=match_numpy_4206b3e)


def to_gray_u8_882f965(image: NDArray[np.generic]) -> NDArray[np.uint8]:
    """``bimcap.features.sift.to_gray_u8``'s RGB branch as of 882f965 (numpy), verbatim."""
    img = np.asarray(image)
    g = img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114
    return np.ascontiguousarray(np.clip(np.rint(g), 0, 255).astype(np.uint8))


def old_gray() -> AbstractContextManager[None]:
    """SIFT's grey conversion as of 882f965 (numpy: :func:`to_gray_u8_882f965`)."""
    from bimcap.features import sift

    def to_gray_u8(image: NDArray[np.generic]) -> NDArray[np.uint8]:
        img = np.asarray(image)
        return to_gray_u8_882f965(img) if img.ndim == 3 else np.ascontiguousarray(img)

    return swapped(sift, to_gray_u8=to_gray_u8)


#: Stage name (as ``bench_frontend.py --world`` prints it) → a context in which the stage's
#: functions (and the providers that call them) run the old code.
REFERENCES: dict[str, Callable[[], AbstractContextManager[None]]] = {
    "semantic sampling": old_semantic_sampling,
    "depth provider": old_completion,
    "geometric segmentation": old_segmentation,
    "planar smoothing": old_planar_smoothing,
    "label orientation check": old_label_orientation,
    "matching": float32_matching,
    "SIFT": old_gray,
}
