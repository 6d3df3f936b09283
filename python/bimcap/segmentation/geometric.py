"""A segmenter that needs no weights: floor, ceiling, walls and columns from depth and gravity.

Inputs: dense depth (undistorted pinhole pixels), the camera and the initial ``world_from_cam``
(only its rotation is used: the world's z axis is up, so ``up_in_cam = R_wcᵀ [0, 0, 1]``).
The work runs on a depth map resampled (nearest-neighbour) to ``work_width`` pixels across
(default 258: ¼ of a 1032-pixel image); labels come back to full resolution by nearest-neighbour
upsampling refined along region borders with the fitted planes (:func:`_upsample_labels`). The
IoU reported by the bench includes what this costs.

1. **Points and normals.** Back-project every pixel; normal = cross product of the central
   differences of the points along u and v (``normal_step_px``), invalid across depth jumps,
   box-smoothed (``normal_smooth_px``), oriented toward the camera.
2. **Floor / ceiling.** Candidates: normal within ``horizontal_angle_deg`` of up (down) and the
   point at least ``floor_min_drop_m`` below (``ceiling_min_rise_m`` above) the camera. A RANSAC
   plane (hypotheses whose normal is within the same angle of up) is fitted, refitted by least
   squares, and up to ``max_horizontal_planes`` are extracted; the **lowest** up-facing plane is
   the floor, the **highest** down-facing one the ceiling, others are clutter (tables, sills).
   Pixels within ``plane_threshold(z)`` of the plane whose normal agrees are labelled. Because
   labelling uses the fitted plane rather than heights from the pose, a pitch error of several
   degrees in the initial pose only tilts the candidate cone, not the result; the floor's (or
   ceiling's) fitted normal then replaces the pose's up vector for the walls, unless it is more
   than ``max_up_correction_deg`` (10°) away from it (then the fit, not the pose, is suspect:
   badly completed floor depth).
3. **Walls and columns.** Candidates: normal within ``vertical_angle_deg`` of horizontal. Vertical
   planes are extracted one at a time by RANSAC with one-point hypotheses (a point and its
   normal made horizontal), refitted by a 2-D line fit in the horizontal plane. Each plane's
   inliers are split into connected image regions; a region is a **column** when it is narrow
   (horizontal extent < ``column_max_width_m``: a BIM column's faces are a few decimetres wide,
   a wall's metres), lies wholly inside the image (a wall cut by the image border can look
   narrow), and protrudes (on both sides the surface next to it is not in front of it: a wall
   piece next to a column has the column in front of it on one side). Otherwise it is a wall.
   Curved columns: left-over vertical-normal pixels that no plane takes form regions; a region
   taller than ``column_min_height_m``, narrower than ``column_max_width_m`` and protruding is
   a column (a round column's normals turn continuously, so no plane takes it, but it is tall
   and thin). Walls and columns reach the ceiling: a vertical region whose top stays more than
   ``top_gap_m`` below the fitted ceiling (when no ceiling is seen: below
   ``top_without_ceiling_m`` relative to the camera, i.e. about 1.1 m above the floor for a
   hand-held camera), and that is not cut by the image's top, is clutter (crates, tables).
4. Everything else with depth is clutter; no depth is unknown. Pixels left undecided (no normal
   at depth edges, blended normals along creases) take the label of the planar region within
   ``crease_px`` whose plane they lie on (the nearest such plane).

**Noisy depth.** The defaults are made for a LiDAR with about 3 cm range noise
(``noise_reference_m``). When the frame's range noise σ is known (``FrameInput.range_noise_m``,
measured on its own scan by :func:`scan_range_noise`) and exceeds ``noise_adapt_above`` ×
``noise_reference_m``, :meth:`GeometricOptions.for_noise` widens the normal baseline and its
smoothing with k = σ / ``noise_reference_m`` and raises the plane threshold to
``noise_threshold_sigmas`` · σ: with 8 cm noise and 2-pixel central differences the normals of a
wall seen from 2 m point anywhere, and RANSAC then fits "floors" and "ceilings" on walls. It also
asks the central differences to span ``normal_baseline_sigmas`` · σ in metres at the frame's
median depth (:func:`_metric_baseline`): a pixel step is short in metres on a wall 1 m away
through a long lens, where the 4-pixel step spans 2 cm and the whole wall became clutter. Below
the limit the options are used as given (same labels as without a noise estimate).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry import Camera, quat_to_rotmat
from bimcap.geometry.noise import noise_factor
from bimcap.geometry.vectors import cross_rows, plane_inlier_counts
from bimcap.labels import Label
from bimcap.segmentation.base import U8, FrameInput, check_shape
from bimcap.segmentation.errors import SegmentationInputError

F64 = NDArray[np.float64]
B = NDArray[np.bool_]


@dataclass(frozen=True)
class GeometricOptions:
    """Settings of :func:`segment_geometric` (angles in degrees, lengths in metres, pixels at the
    working resolution)."""

    work_width: int = 258
    normal_step_px: int = 2
    normal_smooth_px: int = 5
    horizontal_angle_deg: float = 25.0
    vertical_angle_deg: float = 25.0
    normal_agreement_deg: float = 30.0
    floor_min_drop_m: float = 0.4
    ceiling_min_rise_m: float = 0.3
    plane_threshold_m: float = 0.04
    plane_threshold_rel: float = 0.01
    ransac_iterations: int = 150
    ransac_sample: int = 3000
    max_horizontal_planes: int = 2
    max_vertical_planes: int = 8
    min_plane_fraction: float = 0.004
    min_region_fraction: float = 0.002
    column_max_width_m: float = 1.2
    column_min_width_m: float = 0.0
    column_min_height_m: float = 1.0
    protrusion_px: int = 24
    protrusion_min_rows: float = 0.6
    crease_px: int = 8
    protrusion_sides: int = 2
    top_gap_m: float = 0.4
    top_without_ceiling_m: float = -0.4
    max_up_correction_deg: float = 10.0
    seed: int = 0
    noise_reference_m: float = 0.03
    noise_adapt_above: float = 1.5
    noise_threshold_sigmas: float = 1.5
    min_normal_baseline_m: float = 0.0  # 0: the pixel step as given (set by for_noise)
    normal_baseline_sigmas: float = 1.0  # for_noise: min_normal_baseline_m = this · σ
    max_normal_step_px: int = 24  # the widened step's cap (working pixels)

    def __post_init__(self) -> None:
        if self.work_width < 32:
            raise SegmentationInputError("work_width must be >= 32 pixels", field="work_width")
        if not (self.noise_reference_m > 0 and self.noise_adapt_above >= 1.0
                and self.noise_threshold_sigmas > 0):
            raise SegmentationInputError(
                "noise_reference_m and noise_threshold_sigmas must be > 0, noise_adapt_above "
                ">= 1", field="noise_reference_m")
        if not (self.min_normal_baseline_m >= 0 and self.normal_baseline_sigmas >= 0
                and self.max_normal_step_px >= 1):
            raise SegmentationInputError(
                "min_normal_baseline_m and normal_baseline_sigmas must be >= 0, "
                "max_normal_step_px >= 1", field="min_normal_baseline_m")

    def for_noise(self, range_noise_m: float | None) -> GeometricOptions:
        """These options for depth with range noise σ = ``range_noise_m`` (metres; None or not
        finite: unknown, unchanged). Unchanged up to ``noise_adapt_above`` ×
        ``noise_reference_m``; above, with k = σ / ``noise_reference_m`` (at most 4): the normal
        baseline ``normal_step_px`` × 0.75 k, its box ``normal_smooth_px`` × 0.8 k (odd), and the
        plane threshold at least ``noise_threshold_sigmas`` · σ (none of them below the given
        value). 8 cm noise: step 2 → 4 px, box 5 → 11 px, threshold 4 → 12 cm. It also sets
        ``min_normal_baseline_m`` to ``normal_baseline_sigmas`` · σ: the normals' central
        differences must span at least that much at the frame's median depth
        (:func:`_metric_baseline`; a pixel step is metres only at a given depth and focal
        length)."""
        k = noise_factor(range_noise_m, self.noise_reference_m, self.noise_adapt_above)
        if k is None or range_noise_m is None:
            return self
        k = min(4.0, k)
        smooth = round(self.normal_smooth_px * 0.8 * k)
        return replace(
            self,
            normal_step_px=max(self.normal_step_px, round(self.normal_step_px * 0.75 * k)),
            normal_smooth_px=max(self.normal_smooth_px, smooth | 1),
            plane_threshold_m=max(self.plane_threshold_m,
                                  self.noise_threshold_sigmas * range_noise_m),
            min_normal_baseline_m=max(self.min_normal_baseline_m,
                                      self.normal_baseline_sigmas * range_noise_m),
        )


def _metric_baseline(opts: GeometricOptions, depth: NDArray[Any], cam: Camera
                     ) -> GeometricOptions:
    """``opts`` with the normal step widened so that the central differences (2 · step
    pixels) span at least ``min_normal_baseline_m`` at the median depth of ``depth`` (h, w;
    metres, 0 = none) seen by ``cam`` (the working camera), at most ``max_normal_step_px``, and
    its box grown by half the step's factor (odd); unchanged when ``min_normal_baseline_m`` is 0
    or already met.

    At 8 cm of range noise a wall 1 m away seen through a long lens (working fx 441 px) has a
    4-pixel step's differences span 2 cm: its normals point anywhere, no vertical plane gets
    enough agreeing inliers and the whole view is labelled clutter (or a "floor" band)."""
    if opts.min_normal_baseline_m <= 0.0:
        return opts
    z = depth[depth > 0]
    if len(z) == 0:
        return opts
    z_med = float(np.median(z))
    step = int(np.ceil(opts.min_normal_baseline_m * cam.fx / (2.0 * z_med)))
    step = min(step, opts.max_normal_step_px)
    if step <= opts.normal_step_px:
        return opts
    box = max(opts.normal_smooth_px, round(opts.normal_smooth_px * step / opts.normal_step_px
                                           * 0.5) | 1)
    return replace(opts, normal_step_px=step, normal_smooth_px=box)


def scan_range_noise(p_in_sensor: NDArray[np.floating], ring_bin_deg: float = 0.5,
                     max_step_deg: float = 0.5) -> float | None:
    """The range noise σ (metres) of a spinning LiDAR's scan, from the scan alone.

    Returns of one ring (elevation binned to ``ring_bin_deg``, sorted by azimuth) at equal
    azimuth steps below ``max_step_deg`` see nearly the same surface, so their range's second
    difference r[k-1] − 2 r[k] + r[k+1] is the noise (σ √6) plus a curvature term that is
    negligible at such steps; σ = median |Δ²r| / (0.6745 √6) (robust to depth edges). The ring
    spacing of the sensor must exceed ``ring_bin_deg`` (a VLP-16's is 2°).

    Parameters
    ----------
    p_in_sensor: (M, ≥3) points in the sensor frame (x y z, metres; more columns are ignored).

    Returns
    -------
    σ in metres, or None when fewer than 100 triples qualify.
    """
    from bimcap import _core

    p = np.asarray(p_in_sensor)
    if p.ndim != 2 or p.shape[1] < 3 or len(p) < 3:
        return None
    # in compiled code, numpy's arithmetic bit for bit (bimcap/raster/range_noise.h)
    xyz = np.ascontiguousarray(p[:, :3], dtype=np.float64)
    try:
        sigma: float | None = _core.scan_range_noise(xyz, ring_bin_deg, max_step_deg)
    except _core.InputError as exc:
        raise SegmentationInputError(str(exc), field="ring_bin_deg") from None
    return sigma


@dataclass(frozen=True)
class _Plane:
    normal: F64  # (3,) unit, camera frame
    offset: float  # n·p + offset = 0


def _points_and_normals(depth: NDArray[np.float32], cam: Camera, opts: GeometricOptions
                        ) -> tuple[F64, B, F64, B]:
    """Points (h, w, 3), valid (h, w), unit normals facing the camera (h, w, 3; 0 where no
    normal) and where there is a normal (h, w), of the depth ``depth`` (h, w) seen by ``cam``.

    The normal is the cross product of the central differences along u and v
    (``normal_step_px``), box-blurred (``normal_smooth_px``, OpenCV's ``blur`` in float32),
    normalised and turned toward the camera; the per-pixel arithmetic before and after the blur
    runs in ``bimcap._core`` (``points_and_cross``, ``orient_normals``: numpy's component by
    component products and left-to-right sums bit for bit, cpp/bimcap/raster/depth_normals.h).
    """
    import cv2

    from bimcap import _core

    k = opts.normal_smooth_px
    pts, valid, ok, n = _core.points_and_cross(np.ascontiguousarray(depth, dtype=np.float32),
                                               cam.fx, cam.fy, cam.cx, cam.cy,
                                               opts.normal_step_px, k > 1)
    if k > 1:
        n = cv2.blur(n, (k, k)).astype(np.float64)
    _core.orient_normals(n, pts, ok)
    return pts, valid, n, ok


def _cross3(a: F64, b: F64) -> F64:
    """``np.cross`` of two (3,) vectors: the same products and differences, without its
    array-shape handling (a few µs instead of ~20 per call)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def _threshold(z: F64, opts: GeometricOptions) -> F64:
    return opts.plane_threshold_m + opts.plane_threshold_rel * z


def _percentiles(a: F64, qs: tuple[float, ...]) -> list[float]:
    """``np.percentile(a, qs)`` (its default "linear" method) of a 1-D float64 array ``a`` (not
    empty), bit for bit, without numpy's per-call machinery (~50 µs a call): numpy's virtual
    index ``(n − 1) · q / 100``, the same partition (kth 0, −1 and the neighbours of every
    index; indexes at or past the last one read the last value), numpy's interpolation
    ``a + (b − a) t`` (``b − (b − a)(1 − t)`` from t = 0.5) and NaN when ``a`` has one. Python
    floats are IEEE doubles, as numpy's float64 scalars (tests/test_segmentation_speed.py)."""
    n = len(a)
    idx = []
    for q in qs:
        v = (n - 1) * (q / 100)
        lo = hi = -1
        if v < n - 1:
            lo = math.floor(v)
            hi = lo + 1
        idx.append((v, lo, hi))
    part = np.partition(a, sorted({0, -1, *(i[1] for i in idx), *(i[2] for i in idx)}))
    if math.isnan(part[-1]):
        return [math.nan] * len(qs)
    out = []
    for v, lo, hi in idx:
        a_lo, a_hi = float(part[lo]), float(part[hi])
        t = v - lo
        diff = a_hi - a_lo
        out.append(a_hi - diff * (1 - t) if t >= 0.5 else a_lo + diff * t)
    return out


def _ransac_horizontal(scene: _WorkScene, cand: NDArray[np.int64], up: F64, cos_max: float,
                       opts: GeometricOptions, rng: np.random.Generator) -> _Plane | None:
    """Plane through the points of the pixels ``cand`` (N,) (raveled indices, row-major) whose
    normal is within acos(cos_max) of ±up. Only the RANSAC's sample of them is read."""
    n = len(cand)
    if n < 3:
        return None
    pick = cand[rng.choice(n, size=min(n, opts.ransac_sample), replace=False)]
    sub = np.take(scene.pts_flat, pick, axis=0)
    idx = rng.integers(0, len(sub), size=(opts.ransac_iterations, 3))
    a, b, c = sub[idx[:, 0]], sub[idx[:, 1]], sub[idx[:, 2]]
    nrm = cross_rows(b - a, c - a)  # np.cross's numbers
    ln = np.linalg.norm(nrm, axis=1)
    good = ln > 1e-9
    nrm = nrm[good] / ln[good, None]
    a = a[good]
    good = np.abs(nrm @ up) >= cos_max
    if not good.any():
        return None
    nrm, a = nrm[good], a[good]
    d = -(nrm * a).sum(1)
    thr = np.take(scene.thr_flat, pick)[:, None]  # _threshold of the sample's depths
    score = _plane_scores(sub, nrm, d, thr)
    best = int(np.argmax(score))
    inl = np.abs(sub @ nrm[best] + d[best]) < thr[:, 0]
    if inl.sum() < 3:
        return None
    q = sub[inl]
    centroid = q.mean(0)
    _, _, vt = np.linalg.svd(q - centroid, full_matrices=False)
    normal = vt[2] if vt[2] @ nrm[best] > 0 else -vt[2]
    return _Plane(normal, float(-normal @ centroid))


def _ransac_vertical(scene: _WorkScene, cand: NDArray[np.int64], up: F64,
                     opts: GeometricOptions, rng: np.random.Generator) -> _Plane | None:
    """Vertical plane (normal ⟂ up) through the points (with their normals) of the pixels
    ``cand`` (N,) (raveled indices, row-major): 1-point hypotheses. Only the RANSAC's sample of
    them is read."""
    n = len(cand)
    if n < 3:
        return None
    pick = cand[rng.choice(n, size=min(n, opts.ransac_sample), replace=False)]
    sub, sub_n = np.take(scene.pts_flat, pick, axis=0), np.take(scene.nrm_flat, pick, axis=0)
    hyp = rng.integers(0, len(sub), size=opts.ransac_iterations)
    hn = sub_n[hyp] - (sub_n[hyp] @ up)[:, None] * up
    ln = np.linalg.norm(hn, axis=1)
    good = ln > 1e-6
    hn = hn[good] / ln[good, None]
    d = -(hn * sub[hyp[good]]).sum(1)
    thr = np.take(scene.thr_flat, pick)[:, None]  # _threshold of the sample's depths
    cos_n = np.cos(np.deg2rad(opts.normal_agreement_deg))
    score = _plane_scores(sub, hn, d, thr, sub_n, cos_n)
    if len(score) == 0:
        return None
    best = int(np.argmax(score))
    inl = (np.abs(sub @ hn[best] + d[best]) < thr[:, 0]) & (np.abs(sub_n @ hn[best]) > cos_n)
    if inl.sum() < 3:
        return None
    # refit: a line in the horizontal plane (coordinates along two horizontal axes)
    e1 = _cross3(up, hn[best])
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


def _plane_scores(sub: F64, hn: F64, d: F64, thr: F64, sub_n: F64 | None = None,
                  cos_n: float = 0.0) -> NDArray[np.int64]:
    """Per hypothesis (``hn`` (I, 3) unit normals, ``d`` (I,) offsets): how many of the points
    ``sub`` (N, 3) lie within ``thr`` (N, 1) of its plane and (unless ``sub_n`` is None) have a
    normal (``sub_n`` (N, 3)) within acos(``cos_n``) of it.

    The same counts as ``((|sub·hnᵀ + d| < thr) & (|sub_n·hnᵀ| > cos_n)).sum(0)`` bit for bit
    (:func:`bimcap.geometry.vectors.plane_inlier_counts`).
    """
    return plane_inlier_counts(sub, hn, d, thr[:, 0], sub_n, cos_n)


def _rows_dot(p: F64, idx: NDArray[np.intp], v: F64) -> F64:
    """``(p @ v)[idx]`` for points ``p`` (N, 3), rows ``idx`` (M,) and ``v`` (3,), the product
    taken on the gathered rows only when there are at least two (numpy hands an (M, 3) × (3,)
    product with M ≥ 2 to BLAS's gemv, whose every entry is the same 3-term sum wherever the row
    sits, as in the whole image's row-by-row product; one row would go to its dot routine,
    whose rounding may differ, so it is taken from the whole product:
    tests/test_segmentation_speed.py)."""
    if len(idx) >= 2:
        return np.take(p, idx, axis=0) @ v
    return (p @ v)[idx]


def _plane_inliers(scene: _WorkScene, plane: _Plane, mask: B, opts: GeometricOptions) -> B:
    """(h, w) the pixels of ``mask`` within the threshold of ``plane`` whose normal agrees.

    Where ``mask`` holds under a quarter of the image, the distances and agreements are
    computed at its pixels only (:func:`_rows_dot`: the same numbers as the whole image's)."""
    cos_n = np.cos(np.deg2rad(opts.normal_agreement_deg))
    idx = np.flatnonzero(mask)
    if len(idx) >= 2 and 4 * len(idx) < mask.size:
        dist_m = _rows_dot(scene.pts_flat, idx, plane.normal)
        dist_m += plane.offset
        np.abs(dist_m, out=dist_m)
        agree_m = _rows_dot(scene.nrm_flat, idx, plane.normal)
        np.abs(agree_m, out=agree_m)
        ok = dist_m < np.take(scene.thr_flat, idx)
        ok &= agree_m > cos_n
        out = np.zeros(mask.shape, dtype=bool)
        out.reshape(-1)[idx[ok]] = True
        return out
    dist = scene.pts @ plane.normal
    dist += plane.offset
    np.abs(dist, out=dist)
    agree = scene.nrm @ plane.normal
    np.abs(agree, out=agree)
    inl = dist < scene.thr
    inl &= agree > cos_n
    inl &= mask
    return inl


@dataclass(frozen=True)
class _Components:
    """``cv2.connectedComponentsWithStats`` (8-connected) of a mask, run on the box of its rows
    and columns with pixels, widened to start at an even row and column: OpenCV's algorithms
    scan 2 × 2 blocks, so the components come out numbered as on the whole image (checked on
    3000 random masks, 1, 2 and 4 threads), for the box's share of the work. ``labels`` and
    ``stats`` are the box's (stats' left and top relative to it)."""

    count: int
    labels: NDArray[np.int32]
    stats: NDArray[np.int32]
    top: int
    left: int

    @classmethod
    def of(cls, mask: B) -> _Components:
        import cv2

        rows = np.flatnonzero(mask.any(1))
        if len(rows) == 0:
            return cls(1, np.zeros((0, 0), np.int32), np.zeros((1, 5), np.int32), 0, 0)
        cols = np.flatnonzero(mask.any(0))
        top, left = int(rows[0]) & ~1, int(cols[0]) & ~1
        box = mask[top:int(rows[-1]) + 1, left:int(cols[-1]) + 1].astype(np.uint8)
        count, labels, stats, _ = cv2.connectedComponentsWithStats(box, connectivity=8)
        return cls(int(count), labels, stats, top, left)


@dataclass
class _Region:
    """A region of the working image: its bounding box ``rows`` × ``cols`` and its pixels
    ``mask`` inside the box; its points (M, 3) in row-major order (``pts[full mask]``) are
    gathered once, on first use (:meth:`points`)."""

    rows: slice
    cols: slice
    mask: B  # (box height, box width)
    pts: F64  # (h, w, 3) the whole image's points
    _p: F64 | None = None

    @classmethod
    def from_mask(cls, mask: B, pts: F64) -> _Region:
        """The region of the pixels ``mask`` (h, w) (not empty)."""
        rows = np.flatnonzero(mask.any(1))
        cols = np.flatnonzero(mask.any(0))
        box = (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1))
        return cls(box[0], box[1], mask[box], pts)

    @classmethod
    def component(cls, comps: _Components, c: int, pts: F64) -> _Region:
        """Connected component ``c`` of ``comps``."""
        x, y, bw, bh = (int(v) for v in comps.stats[c, :4])
        mask = comps.labels[y:y + bh, x:x + bw] == c
        y += comps.top
        x += comps.left
        return cls(slice(y, y + bh), slice(x, x + bw), mask, pts)

    @property
    def top(self) -> int:
        return int(self.rows.start)

    def flat(self) -> NDArray[np.intp]:
        """(M,) the region's pixels as raveled indices of the whole image, row-major."""
        row, col = np.divmod(np.flatnonzero(self.mask), self.mask.shape[1])
        row += self.rows.start
        row *= self.pts.shape[1]
        row += col
        row += self.cols.start
        return row

    def points(self) -> F64:
        """(M, 3) the region's points, row-major (``np.take`` of the raveled image: the same
        values as a boolean gather of the box, ~3× faster)."""
        if self._p is None:
            self._p = np.take(self.pts.reshape(-1, 3), self.flat(), axis=0)
        return self._p

    def full_mask(self) -> B:
        """(h, w) the region's pixels."""
        out = np.zeros(self.pts.shape[:2], dtype=bool)
        out[self.rows, self.cols] = self.mask
        return out


def _protrudes(region: _Region, pts: F64, plane: _Plane, opts: GeometricOptions) -> bool:
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
    box_rows = np.flatnonzero(region.mask.any(1))
    rows = box_rows + region.top
    w = pts.shape[1]
    sub = region.mask[box_rows]
    x0 = region.cols.start
    left = np.argmax(sub, axis=1) + x0
    right = x0 + sub.shape[1] - 1 - np.argmax(sub[:, ::-1], axis=1)
    cam_side = np.sign(plane.offset) if plane.offset != 0 else 1.0  # the camera (origin) side
    sides = 0
    margin = opts.normal_step_px + 1  # no normals there: the image border for this purpose
    steps = np.arange(1, opts.protrusion_px + 1)
    for edge, step in ((left, -1), (right, 1)):
        # every row's walk at once: (rows, steps) columns, then the first off-plane pixel
        col = edge[:, None] + step * steps[None, :]
        inside = (col >= margin) & (col < w - margin)
        inside_any = inside.any(1)
        colc = np.clip(col, 0, w - 1)
        p = np.take(pts.reshape(-1, 3), (rows[:, None] * w + colc).ravel(), axis=0)
        z = p[:, 2]
        sd = p @ plane.normal + plane.offset
        off = (inside.ravel() & (z > 0) & (np.abs(sd) > _threshold(z, opts))).reshape(col.shape)
        decided = off.any(1)
        first = np.argmax(off, axis=1)
        sd_first = sd.reshape(col.shape)[np.arange(len(rows)), first]
        behind = decided & ((sd_first * cam_side) < 0)
        if inside_any.mean() < 0.5 or decided.mean() < 0.2:
            continue  # the image border, or nothing off the plane nearby: unknown side
        sides += 1
        if behind[decided].mean() < opts.protrusion_min_rows:
            return False
    return sides >= opts.protrusion_sides


def _reaches_up(region: _Region, up: F64, top_needed: float, opts: GeometricOptions,
                height: F64 | None = None) -> bool:
    """Does the region reach ``top_needed`` metres above the camera (or the image's top rows)?
    ``height``: (M,) its points' heights along ``up``, when already computed."""
    if region.top <= opts.normal_step_px + 1 or top_needed == -np.inf:
        return True  # (every finite height reaches -inf: the plane's region reaches up)
    hgt = region.points() @ up if height is None else height
    return _percentiles(hgt, (98,))[0] >= top_needed


def _classify_vertical_region(
    region: _Region, pts: F64, plane: _Plane, up: F64, top_needed: float, opts: GeometricOptions
) -> Label:
    if not _reaches_up(region, up, top_needed, opts):
        return Label.CLUTTER  # walls and columns reach the ceiling; crates and tables do not
    w = pts.shape[1]
    margin = opts.normal_step_px + 1
    if region.cols.start <= margin and region.cols.stop - 1 >= w - 1 - margin:
        return Label.WALL
    t = _cross3(up, plane.normal)
    t /= np.linalg.norm(t)
    s = region.points() @ t
    lo, hi = _percentiles(s, (2, 98))
    width = hi - lo
    if width >= opts.column_max_width_m or width < opts.column_min_width_m:
        return Label.WALL  # too wide, or as thin as a doorway's reveal (a wall's thickness)
    return Label.COLUMN if _protrudes(region, pts, plane, opts) else Label.WALL


@dataclass
class _WorkScene:
    """The depth at the working resolution, back-projected: what every step reads."""

    pts: F64  # (h, w, 3) camera-frame points, metres
    valid: B  # (h, w) pixels with depth
    nrm: F64  # (h, w, 3) unit normals facing the camera (0 where ``nok`` is False)
    nok: B  # (h, w) pixels with a normal
    up: F64  # (3,) the pose's up, camera frame
    height: F64  # (h, w) metres along ``up`` from the camera
    min_plane: int  # pixels a plane needs
    min_region: int  # pixels a region needs
    thr: F64  # (h, w) the plane threshold at each pixel's depth (``_threshold``)

    @property
    def pts_flat(self) -> F64:
        """(h·w, 3) ``pts`` raveled (a view)."""
        return self.pts.reshape(-1, 3)

    @property
    def nrm_flat(self) -> F64:
        """(h·w, 3) ``nrm`` raveled (a view)."""
        return self.nrm.reshape(-1, 3)

    @property
    def thr_flat(self) -> F64:
        """(h·w,) ``thr`` raveled (a view)."""
        return self.thr.reshape(-1)


@dataclass
class _Labelling:
    """The labels being decided and the planar regions found so far (working resolution)."""

    labels: U8  # (h, w) Label ids
    assigned: B  # (h, w) pixels taken by a plane or a region
    region_id: NDArray[np.int32]  # (h, w) index into ``regions``, -1 = none
    regions: list[tuple[Label, _Plane]] = field(default_factory=list)  # planar regions
    bands: list[tuple[int, int]] = field(default_factory=list)  # rows [start, stop) of each
    planes: dict[Label, _Plane] = field(default_factory=dict)  # the floor's / ceiling's plane
    chosen: dict[Label, B] = field(default_factory=dict)  # the floor's / ceiling's pixels

    @classmethod
    def start(cls, valid: B) -> _Labelling:
        """Clutter wherever there is depth (``valid`` (h, w)), unknown elsewhere; no regions."""
        h, w = valid.shape
        labels = np.full((h, w), int(Label.UNKNOWN), dtype=np.uint8)
        labels[valid] = int(Label.CLUTTER)
        return cls(labels=labels, assigned=np.zeros((h, w), dtype=bool),
                   region_id=np.full((h, w), -1, dtype=np.int32))

    def add_region(self, mask: B, label: Label, plane: _Plane) -> None:
        """Label the pixels ``mask`` (h, w) as a planar region of ``plane``."""
        self.labels[mask] = int(label)
        self.assigned |= mask
        self.region_id[mask] = len(self.regions)
        self.regions.append((label, plane))
        rows = np.flatnonzero(mask.any(1))
        self.bands.append((int(rows[0]), int(rows[-1]) + 1) if len(rows) else (0, 0))

    def add_box_region(self, region: _Region, label: Label, plane: _Plane) -> None:
        """:meth:`add_region` of a :class:`_Region` (written inside its bounding box)."""
        box = (region.rows, region.cols)
        self.labels[box][region.mask] = int(label)
        self.assigned[box] |= region.mask
        self.region_id[box][region.mask] = len(self.regions)
        self.regions.append((label, plane))
        self.bands.append((int(region.rows.start), int(region.rows.stop)))


def segment_geometric(
    depth: NDArray[np.float32],
    camera: Camera,
    world_from_cam: F64,
    options: GeometricOptions | None = None,
) -> U8:
    """Label floor, ceiling, walls and columns from dense depth and gravity (module docstring).

    Parameters
    ----------
    depth: (H, W) float32 z-depth in metres, 0 = unknown, pixels of the pinhole ``camera``.
    camera: the pinhole camera of ``depth`` (distortion ignored).
    world_from_cam: (7,) TUM-order pose; only the rotation is used (world z is up).
    options: :class:`GeometricOptions`.

    Returns
    -------
    (H, W) uint8 :class:`Label` ids.
    """
    import cv2

    opts = options or GeometricOptions()
    d_full, pose = _checked_inputs(depth, camera, world_from_cam)
    rng = np.random.default_rng(opts.seed)
    scale = min(1.0, opts.work_width / camera.width)
    cam = camera.pinhole().scaled(scale) if scale < 1.0 else camera.pinhole()
    d = (cv2.resize(d_full, (cam.width, cam.height), interpolation=cv2.INTER_NEAREST)
         if scale < 1.0 else d_full)
    opts = _metric_baseline(opts, d, cam)
    scene = _work_scene(d, cam, pose, opts)
    state = _Labelling.start(scene.valid)
    if not scene.valid.any():
        return cv2.resize(state.labels, (camera.width, camera.height),
                          interpolation=cv2.INTER_NEAREST)
    _floor_and_ceiling(scene, state, opts, rng)
    up_ref = _refined_up(state.planes, scene.up, opts)
    top_needed = _top_needed(scene, state, up_ref, opts)
    remaining = _walls_and_columns(scene, state, up_ref, top_needed, opts, rng)
    _curved_columns(scene, state, remaining, up_ref, top_needed, opts)
    _fill_creases(scene, state, opts)
    if scale < 1.0:
        return _upsample_labels(state.labels, state.region_id, state.regions, d_full, camera,
                                opts, state.bands)
    return state.labels


def _checked_inputs(depth: NDArray[np.float32], camera: Camera, world_from_cam: F64
                    ) -> tuple[NDArray[np.float32], F64]:
    """``(depth (H, W) float32 metres, pose (7,))`` checked against ``camera``; raises
    :class:`SegmentationInputError` naming the bad input."""
    d_full = np.asarray(depth, dtype=np.float32)
    if d_full.ndim != 2:
        raise SegmentationInputError(f"depth must be (H, W), got {d_full.shape}", field="depth")
    check_shape(d_full, camera, "depth")
    if not np.isfinite(d_full).all():
        raise SegmentationInputError("depth has NaN/inf values", field="depth")
    pose = np.asarray(world_from_cam, dtype=np.float64)
    if pose.shape != (7,) or not np.isfinite(pose).all():
        raise SegmentationInputError(
            f"world_from_cam must be a finite (7,) pose, got {pose.shape}", field="world_from_cam"
        )
    return d_full, pose


def _work_scene(d: NDArray[np.float32], cam: Camera, pose: F64, opts: GeometricOptions
                ) -> _WorkScene:
    """Points, normals and heights of the working-resolution depth ``d`` (h, w) seen by ``cam``."""
    pts, valid, nrm, nok = _points_and_normals(d, cam, opts)
    up = quat_to_rotmat(pose[3:]).T @ np.array([0.0, 0.0, 1.0])
    h, w = d.shape
    return _WorkScene(
        pts=pts, valid=valid, nrm=nrm, nok=nok, up=up, height=pts @ up,
        min_plane=max(20, int(opts.min_plane_fraction * h * w)),
        min_region=max(10, int(opts.min_region_fraction * h * w)),
        thr=_threshold(pts[..., 2], opts),
    )


def _floor_and_ceiling(scene: _WorkScene, state: _Labelling, opts: GeometricOptions,
                       rng: np.random.Generator) -> None:
    """The floor (lowest up-facing plane) and the ceiling (highest down-facing one); the other
    horizontal planes found (tables, sills) are left as clutter."""
    cos_h = np.cos(np.deg2rad(opts.horizontal_angle_deg))
    cos_up = scene.nrm @ scene.up
    for label, sign, cand in (
        (Label.FLOOR, 1.0,
         scene.nok & (cos_up > cos_h) & (scene.height < -opts.floor_min_drop_m)),
        (Label.CEILING, -1.0,
         scene.nok & (cos_up < -cos_h) & (scene.height > opts.ceiling_min_rise_m)),
    ):
        found = _horizontal_planes(scene, state.assigned, cand, cos_h, opts, rng)
        if not found:
            continue
        found.sort(key=lambda x: sign * x[0])  # floor: lowest first; ceiling: highest first
        _, plane, inl = found[0]
        state.chosen[label] = inl
        state.planes[label] = plane
        state.add_region(inl, label, plane)
        for _, _, other in found[1:]:
            state.assigned |= other  # tables, sills: clutter


def _horizontal_planes(scene: _WorkScene, assigned: B, cand: B, cos_h: float,
                       opts: GeometricOptions, rng: np.random.Generator
                       ) -> list[tuple[float, _Plane, B]]:
    """Up to ``max_horizontal_planes`` planes through the candidate pixels ``cand`` (h, w), as
    ``(height along up (m), plane, inliers (h, w))`` in the order found."""
    remaining = cand.copy()
    found: list[tuple[float, _Plane, B]] = []
    for _ in range(opts.max_horizontal_planes):
        if remaining.sum() < scene.min_plane:
            break
        plane = _ransac_horizontal(scene, np.flatnonzero(remaining), scene.up, cos_h, opts, rng)
        if plane is None:
            break
        inl = _plane_inliers(scene, plane, scene.nok & ~assigned, opts)
        if (inl & remaining).sum() < scene.min_plane:
            break
        # the plane's height along up: points p with n·p + offset = 0 → height ≈ -offset (n ≈ ±up)
        level = float(np.median(scene.height[inl]))
        found.append((level, plane, inl))
        remaining &= ~inl
    return found


def _refined_up(planes: dict[Label, _Plane], up: F64, opts: GeometricOptions) -> F64:
    """(3,) up, camera frame: the floor's (else the ceiling's) fitted normal, unless it is more
    than ``max_up_correction_deg`` from the pose's ``up``."""
    if Label.FLOOR in planes:
        up_ref = planes[Label.FLOOR].normal * np.sign(planes[Label.FLOOR].normal @ up)
    elif Label.CEILING in planes:
        up_ref = -planes[Label.CEILING].normal * np.sign(planes[Label.CEILING].normal @ -up)
    else:
        up_ref = up
    up_ref = up_ref / np.linalg.norm(up_ref)
    if up_ref @ up < np.cos(np.deg2rad(opts.max_up_correction_deg)):
        up_ref = up  # a fitted floor this far from the pose's up is more likely wrong than the pose
    return up_ref


def _top_needed(scene: _WorkScene, state: _Labelling, up_ref: F64, opts: GeometricOptions
                ) -> float:
    """Height (m along ``up_ref`` from the camera) that walls and columns must reach: near the
    ceiling, or ``top_without_ceiling_m`` when no ceiling is seen."""
    if Label.CEILING in state.chosen:
        return float(np.median(scene.pts[state.chosen[Label.CEILING]] @ up_ref)) - opts.top_gap_m
    return opts.top_without_ceiling_m


def _walls_and_columns(scene: _WorkScene, state: _Labelling, up_ref: F64, top_needed: float,
                       opts: GeometricOptions, rng: np.random.Generator) -> B:
    """Vertical planes one at a time, their regions labelled wall, column or clutter; returns
    the vertical-normal pixels (h, w) that no plane took."""
    sin_v = np.sin(np.deg2rad(opts.vertical_angle_deg))
    vert = scene.nok & ~state.assigned & (np.abs(scene.nrm @ up_ref) < sin_v)
    remaining: B = vert.copy()
    for _ in range(opts.max_vertical_planes):
        if remaining.sum() < scene.min_plane:
            break
        plane = _ransac_vertical(scene, np.flatnonzero(remaining), up_ref, opts, rng)
        if plane is None:
            break
        inl = _plane_inliers(scene, plane, remaining, opts)
        if inl.sum() < scene.min_plane:
            break
        remaining &= ~inl
        # whether the plane reaches the ceiling is judged on all its inliers: noise may split a
        # wall into an upper and a lower region, and the lower one is no crate
        plane_reaches = _reaches_up(_Region.from_mask(inl, scene.pts), up_ref, top_needed, opts)
        _label_plane_regions(scene, state, inl, plane, up_ref,
                             top_needed if not plane_reaches else -np.inf, opts)
    return remaining


def _label_plane_regions(scene: _WorkScene, state: _Labelling, inl: B, plane: _Plane,
                         up_ref: F64, top_needed: float, opts: GeometricOptions) -> None:
    """Label each large enough connected region of a vertical plane's inliers ``inl`` (h, w)."""
    import cv2

    comps = _Components.of(inl)
    for c in range(1, comps.count):
        if comps.stats[c, cv2.CC_STAT_AREA] < scene.min_region:
            continue
        region = _Region.component(comps, c, scene.pts)
        lab = _classify_vertical_region(region, scene.pts, plane, up_ref, top_needed, opts)
        state.add_box_region(region, lab, plane)


def _curved_columns(scene: _WorkScene, state: _Labelling, remaining: B, up_ref: F64,
                    top_needed: float, opts: GeometricOptions) -> None:
    """Columns among the left-over vertical-normal regions ``remaining`` (h, w): tall, narrow
    and protruding (a round column's normals turn, so no plane takes it)."""
    import cv2

    comps = _Components.of(remaining)
    for c in range(1, comps.count):
        if comps.stats[c, cv2.CC_STAT_AREA] < scene.min_region:
            continue
        region = _Region.component(comps, c, scene.pts)
        if _is_curved_column(region, scene.pts, up_ref, top_needed, opts):
            box = (region.rows, region.cols)
            state.labels[box][region.mask] = int(Label.COLUMN)
            state.assigned[box] |= region.mask


def _is_curved_column(region: _Region, pts: F64, up_ref: F64, top_needed: float,
                      opts: GeometricOptions) -> bool:
    """Is the region of points ``pts`` (h, w, 3) tall, narrow, reaching up and standing out of
    its surroundings (a crease between walls does not)?"""
    p = region.points()
    hgt = p @ up_ref
    horiz = p - np.outer(hgt, up_ref)
    hc = horiz - horiz.mean(0)
    # ≈ full width of a uniform spread
    extent = 2.0 * np.sqrt(max(np.linalg.eigvalsh(hc.T @ hc / len(hc))[-1], 0.0)) * 1.73
    lo, hi = _percentiles(hgt, (2, 98))
    tall = hi - lo
    if not (extent < opts.column_max_width_m and tall > opts.column_min_height_m
            and _reaches_up(region, up_ref, top_needed, opts, hgt)):
        return False
    # one protruding side is enough here: a curved region is no wall end
    return _protrudes(region, pts, _vertical_fit(p, up_ref), replace(opts, protrusion_sides=1))


def _vertical_fit(p: F64, up_ref: F64) -> _Plane:
    """The vertical plane (normal ⟂ ``up_ref``, facing the camera) best fitting points (n, 3)."""
    e1 = np.cross(up_ref, np.array([0.0, 0.0, 1.0]))
    e1 = (e1 / max(np.linalg.norm(e1), 1e-12) if np.linalg.norm(e1) > 1e-6
          else np.array([1.0, 0.0, 0.0]))
    e2 = np.cross(up_ref, e1)
    xy = np.stack([p @ e1, p @ e2], 1)
    c0 = xy.mean(0)
    _, _, vt = np.linalg.svd(xy - c0, full_matrices=False)
    n2 = np.array([-vt[0, 1], vt[0, 0]])
    normal = n2[0] * e1 + n2[1] * e2
    centroid = p.mean(0)
    if normal @ centroid > 0:
        normal = -normal
    return _Plane(normal, float(-normal @ centroid))


def _near_region(region_id: NDArray[np.int32], k: int, reach: int, at: NDArray[np.int64],
                 rows_ascending: bool, band: tuple[int, int] | None = None) -> NDArray[np.int64]:
    """Positions (ascending) in ``at`` (M,) (raveled indices of pixels of ``region_id`` (h, w);
    ``rows_ascending``: their rows never decrease) of the pixels that OpenCV's dilation of
    region ``k``'s mask by a ``(2 reach + 1)²`` square covers. ``band``: rows ``[start, stop)``
    that hold every pixel of region ``k`` (None: any row).

    The same pixels as ``cv2.dilate(region_id == k, kernel)`` read at ``at``, in compiled code:
    a table of the region's pixel counts over its band gives each window's count from four
    entries (bimcap/raster/near_region.h), the entries of ``at`` out of reach never read when
    their rows are ascending."""
    from bimcap import _core

    top, stop = band or (0, region_id.shape[0])
    hits: NDArray[np.int64] = _core.near_region(region_id, k, reach, at, rows_ascending, top, stop)
    return hits


def _fill_creases(scene: _WorkScene, state: _Labelling, opts: GeometricOptions) -> None:
    """Undecided pixels (no normal at depth edges, mixed normals along creases) take the label
    of the nearby planar region (within ``crease_px``) on whose plane they lie, nearest first."""
    undecided = scene.valid & (state.labels == int(Label.CLUTTER)) & (state.region_id < 0)
    if not (undecided.any() and state.regions):
        return
    flat = np.flatnonzero(undecided)
    p = np.take(scene.pts_flat, flat, axis=0)
    best = np.full(len(flat), np.inf)
    best_label = np.full(len(flat), int(Label.CLUTTER), dtype=np.uint8)
    thr = 2.0 * _threshold(p[:, 2], opts)
    for k, (lab, plane) in enumerate(state.regions):
        # the distances at the pixels near the region only (_rows_dot: the same numbers); flat
        # is ascending, so are its rows
        near = _near_region(state.region_id, k, opts.crease_px, flat, True, state.bands[k])
        if len(near) == 0:
            continue
        dist = _rows_dot(p, near, plane.normal)
        dist += plane.offset
        np.abs(dist, out=dist)
        take = (dist < thr[near]) & (dist < best[near])
        best[near[take]] = dist[take]
        best_label[near[take]] = int(lab)
    np.put(state.labels, flat, best_label)


@functools.lru_cache(maxsize=4)
def _upsampled_index(shape_lo: tuple[int, int], size: tuple[int, int]) -> NDArray[np.int32]:
    """(H, W) the raveled index of the work pixel (of an image of ``shape_lo`` (h, w)) that
    nearest-neighbour upsampling to ``size`` (W, H) reads at each pixel: an image of work-pixel
    indices resized with the same mapping as any other image (read-only; cached per sizes)."""
    import cv2

    h_lo, w_lo = shape_lo
    src: NDArray[np.int32] = cv2.resize(np.arange(h_lo * w_lo, dtype=np.int32).reshape(h_lo, w_lo),
                                        size, interpolation=cv2.INTER_NEAREST)
    src.flags.writeable = False
    return src


def _upsample_labels(
    labels: U8,
    region_id: NDArray[np.int32],
    regions: list[tuple[Label, _Plane]],
    depth: NDArray[np.float32],
    camera: Camera,
    opts: GeometricOptions,
    bands: list[tuple[int, int]] | None = None,
) -> U8:
    """Bring work-resolution labels to full resolution, plane-guided along borders (``bands``:
    each region's rows, :attr:`_Labelling.bands`; None: not known).

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
    # the work pixel each border pixel's nearest-neighbour upsampling reads: resizing an image
    # of work-pixel indices copies them with the same mapping as any other image
    src = _upsampled_index(region_id.shape, size)[r, c]
    z = depth[r, c].astype(np.float64)
    p = np.stack([(c - camera.cx) / camera.fx * z, (r - camera.cy) / camera.fy * z, z], 1)
    best = _threshold(z, opts) * 2.0
    choice = np.full(len(r), -1, dtype=np.int64)
    # the work rows the border pixels read: row-major border pixels and nearest-neighbour rows
    # never decrease (else every border pixel is looked at for every region)
    at = src.astype(np.int64)
    at_row = at // region_id.shape[1]
    ascending = len(at) < 2 or bool((at_row[1:] >= at_row[:-1]).all())
    for k, (_, plane) in enumerate(regions):
        # the distances at the border pixels near the region only (_rows_dot: the same numbers)
        near = _near_region(region_id, k, 1, at, ascending, bands[k] if bands else None)
        if len(near) == 0:
            continue
        dist = _rows_dot(p, near, plane.normal)
        dist += plane.offset
        np.abs(dist, out=dist)
        take = dist < best[near]
        best[near[take]] = dist[take]
        choice[near[take]] = k
    lut = np.array([int(lab) for lab, _ in regions], dtype=np.uint8)
    sel = choice >= 0
    up[r[sel], c[sel]] = lut[choice[sel]]
    return up


@dataclass(frozen=True)
class GeometricSegmenter:
    """Provider wrapper of :func:`segment_geometric` (needs ``frame.depth`` and
    ``frame.world_from_cam``)."""

    options: GeometricOptions = GeometricOptions()

    def segment(self, frame: FrameInput) -> U8:
        if frame.depth is None or frame.world_from_cam is None:
            raise SegmentationInputError(
                "the geometric segmenter needs dense depth and the initial pose", field="depth"
            )
        return segment_geometric(frame.depth, frame.camera, frame.world_from_cam,
                                 self.options.for_noise(frame.range_noise_m))
