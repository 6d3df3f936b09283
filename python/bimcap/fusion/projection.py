"""LiDAR → camera: undistortion, projection into a sparse depth map, image/scan pairing.

The front end works in **undistorted pinhole pixels** of ``camera.pinhole()`` (same K, zero
distortion; docs/architecture.md "Front-end output"). :func:`undistort_image` resamples raw images
into that camera; :func:`project_lidar` projects LiDAR points into it (``distort=True`` projects
into the raw image instead, for comparison with raw ground truth).

Occlusion (parallax) rule of :func:`project_lidar`: the LiDAR and the camera sit at different
places, so the LiDAR sees surfaces that the camera cannot (behind the edge of a column, say);
projected, those returns land among the returns of the occluder. After the per-pixel z-buffer,
a return of depth ``z`` is dropped when some other return within a ``(2r+1) × (2r+1)`` pixel window
(``r = occlusion_radius_px``) has depth ``z_min`` with ``z - z_min > max(occlusion_abs_m,
occlusion_rel · z_min)``. This is the window z-buffer test of depth-completion practice; it also
removes true background returns within ``r`` pixels of a foreground edge, which costs nothing
(they are re-filled by completion from both sides).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.errors import BimcapError, InputError
from bimcap.geometry import Camera, quat_to_rotmat

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


class FusionError(BimcapError):
    """A fusion-stage failure that is not an input problem."""


class FusionInputError(FusionError, InputError):
    """Bad input to the fusion stage (wrong shape, empty scan, NaN points, size mismatch)."""


class NanPolicy(Enum):
    """What :func:`project_lidar` does with non-finite points."""

    RAISE = "raise"  #: raise :class:`FusionInputError`
    DROP = "drop"  #: drop them (drivers that emit NaN for "no return")


@dataclass(frozen=True)
class ProjectionOptions:
    """Settings of :func:`project_lidar`.

    min_depth_m, max_depth_m: keep returns with ``min < z < max`` in the camera frame.
    occlusion_radius_px: half size ``r`` of the window of the parallax test (0 disables it).
    occlusion_abs_m, occlusion_rel: the test's threshold ``max(abs, rel · z_min)``.
    nan_policy: what to do with non-finite points.
    """

    min_depth_m: float = 0.1
    max_depth_m: float = 200.0
    occlusion_radius_px: int = 4
    occlusion_abs_m: float = 0.3
    occlusion_rel: float = 0.1
    nan_policy: NanPolicy = NanPolicy.RAISE

    def __post_init__(self) -> None:
        if not (0.0 <= self.min_depth_m < self.max_depth_m):
            raise FusionInputError("need 0 <= min_depth_m < max_depth_m", field="min_depth_m")
        if self.occlusion_radius_px < 0 or self.occlusion_abs_m < 0 or self.occlusion_rel < 0:
            raise FusionInputError("occlusion settings must be >= 0", field="occlusion_*")


@dataclass(frozen=True)
class SparseDepth:
    """A LiDAR scan projected into one image.

    Attributes
    ----------
    depth: (H, W) float32 z-depth in metres at the pixel nearest each kept return, 0 elsewhere.
    uv: (K, 2) float64 sub-pixel positions of the kept returns (one per non-zero pixel).
    z: (K,) float64 their z-depths in metres (``depth[round(v), round(u)] == z``).
    point_index: (K,) int64 index of each kept return in the input scan.
    counts: how many points survived each step (input, finite, in_front, in_fov, zbuffer, kept).
    """

    depth: F32
    uv: F64
    z: F64
    point_index: NDArray[np.int64]
    counts: dict[str, int]

    def to_dict(self) -> dict[str, Any]:
        return {"shape": list(self.depth.shape), "counts": dict(self.counts)}


def _check_image(image: NDArray[Any], camera: Camera, name: str) -> None:
    if image.ndim not in (2, 3) or image.shape[:2] != (camera.height, camera.width):
        raise FusionInputError(
            f"image of shape {image.shape} does not match the camera's "
            f"{camera.height}x{camera.width} (rows x columns)",
            field=name,
        )


_UNDISTORT_CACHE: dict[Camera, tuple[NDArray[Any], NDArray[Any]]] = {}


def undistort_maps(camera: Camera) -> tuple[NDArray[Any], NDArray[Any]]:
    """Cached ``cv2.remap`` maps from raw pixels to ``camera.pinhole()`` pixels (new K = K)."""
    maps = _UNDISTORT_CACHE.get(camera)
    if maps is None:
        import cv2

        k = camera.K
        maps = cv2.initUndistortRectifyMap(
            k, np.asarray(camera.dist), None, k, (camera.width, camera.height), cv2.CV_32FC1
        )
        if len(_UNDISTORT_CACHE) > 16:
            _UNDISTORT_CACHE.clear()
        _UNDISTORT_CACHE[camera] = maps
    return maps


def undistort_image(image: ArrayLike, camera: Camera, nearest: bool = False) -> NDArray[Any]:
    """Resample a raw image into the undistorted pinhole camera ``camera.pinhole()``.

    Parameters
    ----------
    image: (H, W) or (H, W, C) raw image (any dtype cv2.remap takes) of ``camera``'s size.
    camera: the raw camera (with distortion).
    nearest: nearest-neighbour sampling; use it for label images and depth maps (so that no value
        is mixed across a depth edge or a class border). Pixels mapping outside the raw image
        become 0 (unknown).

    Returns
    -------
    The undistorted image, same shape and dtype. Returned unchanged (a copy) when the camera has
    no distortion.
    """
    import cv2

    img = np.asarray(image)
    _check_image(img, camera, "image")
    if not camera.is_distorted:
        return img.copy()
    map_x, map_y = undistort_maps(camera)
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return cv2.remap(img, map_x, map_y, interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _pose_rt(pose: ArrayLike, name: str) -> tuple[F64, F64]:
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (7,) or not np.isfinite(p).all():
        raise FusionInputError(
            f"expected a finite (7,) TUM-order pose, got shape {p.shape}", field=name
        )
    if abs(np.linalg.norm(p[3:]) - 1.0) > 1e-3:
        raise FusionInputError("quaternion is not unit length", field=name)
    return quat_to_rotmat(p[3:]), p[:3]


@lru_cache(maxsize=16)
def _monotonic_radius(camera: Camera) -> float:
    """Largest undistorted radius up to which the radial model ``r·(1 + k1 r² + k2 r⁴ + k3 r⁶)``
    still grows; beyond it the polynomial folds points back toward the centre (∞ if never)."""
    k1, k2, _, _, k3 = camera.dist
    r = np.linspace(0.0, 5.0, 50001)
    r2 = r * r
    rd = r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
    falling = np.flatnonzero(np.diff(rd) <= 0)
    return float(r[falling[0]]) if len(falling) else float("inf")


@lru_cache(maxsize=16)
def _fov_bounds(camera: Camera) -> tuple[float, float, float, float]:
    """Normalised (x, y) bounds of the raw image's field of view (undistorted border rays)."""
    w, h = camera.width, camera.height
    us = np.linspace(-0.5, w - 0.5, 64)
    vs = np.linspace(-0.5, h - 0.5, 64)
    border = np.concatenate(
        [np.stack([us, np.full_like(us, -0.5)], 1), np.stack([us, np.full_like(us, h - 0.5)], 1),
         np.stack([np.full_like(vs, -0.5), vs], 1), np.stack([np.full_like(vs, w - 0.5), vs], 1)]
    )
    xy = camera.rays(border, distorted=True)[:, :2]
    return (float(xy[:, 0].min()), float(xy[:, 0].max()),
            float(xy[:, 1].min()), float(xy[:, 1].max()))


@dataclass(frozen=True)
class _Returns:
    """The LiDAR returns still kept: index (K,) int64 into the scan, uv (K, 2) float64 pixels,
    z (K,) float64 z-depth in metres."""

    index: NDArray[np.int64]
    uv: F64
    z: F64

    def select(self, keep: NDArray[Any]) -> _Returns:
        """The returns at ``keep`` (a mask or indices)."""
        return _Returns(index=self.index[keep], uv=self.uv[keep], z=self.z[keep])


def _checked_points(points_in_lidar: ArrayLike,
                    opts: ProjectionOptions) -> tuple[F64, NDArray[np.bool_]]:
    """The scan's xyz (M, 3) metres and (M,) True where finite; raises on a bad shape, an empty
    scan, or non-finite points under ``NanPolicy.RAISE``."""
    raw = np.asarray(points_in_lidar)
    if raw.ndim != 2 or raw.shape[1] < 3:
        raise FusionInputError(f"points must have shape (M, 3) or (M, 4), got {raw.shape}",
                               field="points_in_lidar")
    # the xyz columns alone, contiguous float64 (the intensity column is never read)
    pts = np.ascontiguousarray(raw[:, :3], dtype=np.float64)
    n_input = len(pts)
    if n_input == 0:
        raise FusionInputError("the LiDAR scan is empty (0 points)", field="points_in_lidar")
    finite = np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1]) & np.isfinite(pts[:, 2])
    if not finite.all() and opts.nan_policy is NanPolicy.RAISE:
        bad = int((~finite).sum())
        raise FusionInputError(
            f"{bad} of {n_input} points are NaN/inf (ProjectionOptions.nan_policy DROP drops them)",
            field="points_in_lidar",
        )
    return pts, finite


def _in_front(pts: F64, finite: NDArray[np.bool_], cam_from_lidar: ArrayLike,
              opts: ProjectionOptions) -> tuple[NDArray[np.int64], F64, F64]:
    """Finite points with ``min < z < max`` in the camera: index (K,), z (K,) metres and
    normalised coordinates xy (K, 2)."""
    index = np.flatnonzero(finite)
    rot, t = _pose_rt(cam_from_lidar, "cam_from_lidar")
    # every point finite (the usual scan): pts is already pts[index] (contiguous (M, 3))
    p_in_cam = (pts if len(index) == len(pts) else pts[index]) @ rot.T + t
    z = p_in_cam[:, 2]
    front = (z > opts.min_depth_m) & (z < opts.max_depth_m)
    index, p_in_cam, z = index[front], p_in_cam[front], z[front]
    return index, z, p_in_cam[:, :2] / z[:, None]


def _to_pixels(index: NDArray[np.int64], xy: F64, z: F64, camera: Camera,
               distort: bool) -> _Returns:
    """Project normalised coordinates xy (K, 2) to pixels, keeping those inside the image
    (with ``distort``, only points inside the camera's field of view are distorted)."""
    if distort and camera.is_distorted:
        x0, x1, y0, y1 = _fov_bounds(camera)
        r_max = _monotonic_radius(camera)
        in_fov = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
        in_fov &= (xy * xy).sum(1) < r_max * r_max
        index, xy, z = index[in_fov], xy[in_fov], z[in_fov]
        xy = camera.distort_normalized(xy)
    uv = np.stack([camera.fx * xy[:, 0] + camera.cx, camera.fy * xy[:, 1] + camera.cy], axis=1)
    inside = camera.in_image(uv)
    return _Returns(index=index[inside], uv=uv[inside], z=z[inside])


def _zbuffer(ret: _Returns, camera: Camera) -> tuple[_Returns, NDArray[np.int64]]:
    """The nearest return per pixel (rounded to the nearest pixel), and (K,) its pixel id
    ``row·W + col``."""
    h, w = camera.height, camera.width
    col = np.clip(np.rint(ret.uv[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(ret.uv[:, 1]).astype(np.int64), 0, h - 1)
    lin = row * w + col
    order = np.lexsort((ret.z, lin))  # by pixel, then nearest first
    lin_sorted = lin[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = lin_sorted[1:] != lin_sorted[:-1]
    keep = order[first]
    return ret.select(keep), lin[keep]


def _drop_occluded(depth: F32, ret: _Returns, lin: NDArray[np.int64],
                   opts: ProjectionOptions) -> _Returns:
    """The parallax occlusion test (module docstring): zero the occluded returns (pixel ids
    ``lin`` (K,)) in ``depth`` (H, W) metres, in place, and keep the others."""
    from bimcap import _core

    # the nearest return in each return's window, at the returns only (compiled: what
    # cv2.erode of the positive depths gives there, bimcap/raster/window_min.h)
    zmin_at = _core.window_min_at(depth, np.ascontiguousarray(lin, dtype=np.int64),
                                  opts.occlusion_radius_px).astype(np.float64)
    occluded = (ret.z - zmin_at) > np.maximum(opts.occlusion_abs_m, opts.occlusion_rel * zmin_at)
    depth.reshape(-1)[lin[occluded]] = 0.0
    return ret.select(~occluded)


def project_lidar(
    points_in_lidar: ArrayLike,
    cam_from_lidar: ArrayLike,
    camera: Camera,
    options: ProjectionOptions | None = None,
    distort: bool = False,
) -> SparseDepth:
    """Project a LiDAR scan into a sparse depth map of the camera.

    Parameters
    ----------
    points_in_lidar: (M, 3) or (M, ≥3) float LiDAR returns in metres, LiDAR frame (extra columns,
        e.g. intensity, are ignored).
    cam_from_lidar: (7,) TUM-order extrinsic mapping LiDAR points into the camera optical frame.
    camera: the camera. With ``distort=False`` (the front end's convention) points are projected
        with the pinhole model of ``camera`` (its K, no distortion): pixels of ``camera.pinhole()``.
        With ``distort=True`` they are projected with the distortion: pixels of the raw image.
    options: :class:`ProjectionOptions`.

    Steps: transform, keep ``min < z < max``, keep points inside the camera's field of view (only
    those are used: the normalised coordinates must lie within the undistorted raw image's
    bounds and inside the radius up to which the distortion polynomial is monotonic, so that no
    point outside the FoV can wrap into the image through the polynomial), round to the nearest
    pixel, z-buffer (nearest return per pixel), parallax occlusion test (module docstring).

    Raises
    ------
    FusionInputError: wrong shapes, an empty scan, non-finite points (with ``NanPolicy.RAISE``),
        a bad pose.
    """
    opts = options or ProjectionOptions()
    pts, finite = _checked_points(points_in_lidar, opts)
    index, z, xy = _in_front(pts, finite, cam_from_lidar, opts)
    n_front = len(index)
    ret = _to_pixels(index, xy, z, camera, distort)
    n_fov = len(ret.index)
    ret, lin = _zbuffer(ret, camera)
    n_zbuf = len(ret.index)
    depth = np.zeros(camera.height * camera.width, dtype=np.float32)
    depth[lin] = ret.z.astype(np.float32)
    depth = depth.reshape(camera.height, camera.width)
    if opts.occlusion_radius_px > 0 and n_zbuf:
        ret = _drop_occluded(depth, ret, lin, opts)
    counts = {
        "input": len(pts),
        "finite": int(finite.sum()),
        "in_front": n_front,
        "in_fov": n_fov,
        "zbuffer": n_zbuf,
        "kept": len(ret.index),
    }
    return SparseDepth(depth=depth, uv=ret.uv, z=ret.z, point_index=ret.index, counts=counts)


def pair_by_timestamp(image_ts: ArrayLike, scan_ts: ArrayLike, tol: float) -> NDArray[np.int64]:
    """Pair images with LiDAR scans by nearest timestamp, one to one.

    Parameters
    ----------
    image_ts: (N,) image timestamps, seconds.
    scan_ts: (S,) scan timestamps, seconds.
    tol: largest accepted ``|t_image - t_scan|`` in seconds.

    Returns
    -------
    (P, 2) int64 ``[image_index, scan_index]`` rows, sorted by image index. Each image takes its
    nearest scan; when several images take the same scan, only the nearest of them keeps it.
    """
    ti = np.asarray(image_ts, dtype=np.float64).reshape(-1)
    ts = np.asarray(scan_ts, dtype=np.float64).reshape(-1)
    if not (np.isfinite(ti).all() and np.isfinite(ts).all()):
        raise FusionInputError("timestamps must be finite", field="timestamps")
    if not np.isfinite(tol) or tol < 0:
        raise FusionInputError(f"tolerance must be >= 0, got {tol}", field="tol")
    if len(ti) == 0 or len(ts) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    s_order = np.argsort(ts, kind="stable")
    ts_sorted = ts[s_order]
    pos = np.searchsorted(ts_sorted, ti)
    lo = np.clip(pos - 1, 0, len(ts) - 1)
    hi = np.clip(pos, 0, len(ts) - 1)
    pick = np.where(np.abs(ts_sorted[lo] - ti) <= np.abs(ts_sorted[hi] - ti), lo, hi)
    dt = np.abs(ts_sorted[pick] - ti)
    scan = s_order[pick]
    ok = np.flatnonzero(dt <= tol)
    # one to one: for each scan keep the image nearest to it
    order = ok[np.lexsort((dt[ok], scan[ok]))]
    first = np.ones(len(order), dtype=bool)
    first[1:] = scan[order][1:] != scan[order][:-1]
    chosen = np.sort(order[first])
    return np.stack([chosen, scan[chosen]], axis=1).astype(np.int64)
