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
   ceiling's) fitted normal then replaces the pose's up vector for the walls.
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
   ``top_gap_m`` below the fitted ceiling (below the camera when no ceiling is seen), and that
   is not cut by the image's top, is clutter (crates, tables, cabinets' sides).
4. Everything else with depth is clutter; no depth is unknown. Pixels left undecided (no normal
   at depth edges, blended normals along creases) take the label of the planar region within
   ``crease_px`` whose plane they lie on (the nearest such plane).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry import Camera, quat_to_rotmat
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
    column_min_height_m: float = 1.0
    protrusion_px: int = 24
    protrusion_min_rows: float = 0.6
    crease_px: int = 8
    protrusion_sides: int = 2
    top_gap_m: float = 0.4
    seed: int = 0

    def __post_init__(self) -> None:
        if self.work_width < 32:
            raise SegmentationInputError("work_width must be >= 32 pixels", field="work_width")


@dataclass(frozen=True)
class _Plane:
    normal: F64  # (3,) unit, camera frame
    offset: float  # n·p + offset = 0


def _points_and_normals(depth: NDArray[np.float32], cam: Camera, opts: GeometricOptions) -> tuple[F64, B, F64, B]:
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
    du = np.zeros_like(pts)
    dv = np.zeros_like(pts)
    du[:, s:-s] = pts[:, 2 * s :] - pts[:, : -2 * s]
    dv[s:-s] = pts[2 * s :] - pts[: -2 * s]
    ok = np.zeros((h, w), dtype=bool)
    zc = z[s:-s, s:-s]
    jump = 0.05 * zc + 0.05  # metres: neighbours farther apart in depth are across an edge
    ok[s:-s, s:-s] = (
        valid[s:-s, s:-s]
        & (z[s:-s, 2 * s :] > 0) & (z[s:-s, : -2 * s] > 0) & (z[2 * s :, s:-s] > 0) & (z[: -2 * s, s:-s] > 0)
        & (np.abs(z[s:-s, 2 * s :] - z[s:-s, : -2 * s]) < 2 * jump)
        & (np.abs(z[2 * s :, s:-s] - z[: -2 * s, s:-s]) < 2 * jump)
    )
    n = np.cross(du, dv)
    n[~ok] = 0.0
    k = opts.normal_smooth_px
    if k > 1:
        n = cv2.blur(n.astype(np.float32), (k, k)).astype(np.float64)
    norm = np.linalg.norm(n, axis=2)
    ok &= norm > 1e-12
    n = n / np.maximum(norm, 1e-12)[..., None]
    flip = (n * pts).sum(2) > 0  # face the camera
    n[flip] *= -1.0
    n[~ok] = 0.0
    return pts, valid, n, ok


def _threshold(z: F64, opts: GeometricOptions) -> F64:
    return opts.plane_threshold_m + opts.plane_threshold_rel * z


def _ransac_horizontal(pts: F64, up: F64, cos_max: float, opts: GeometricOptions, rng: np.random.Generator) -> _Plane | None:
    """Plane through points (N, 3) whose normal is within acos(cos_max) of ±up."""
    n = len(pts)
    if n < 3:
        return None
    sub = pts[rng.choice(n, size=min(n, opts.ransac_sample), replace=False)]
    idx = rng.integers(0, len(sub), size=(opts.ransac_iterations, 3))
    a, b, c = sub[idx[:, 0]], sub[idx[:, 1]], sub[idx[:, 2]]
    nrm = np.cross(b - a, c - a)
    ln = np.linalg.norm(nrm, axis=1)
    good = ln > 1e-9
    nrm = nrm[good] / ln[good, None]
    a = a[good]
    good = np.abs(nrm @ up) >= cos_max
    if not good.any():
        return None
    nrm, a = nrm[good], a[good]
    d = -(nrm * a).sum(1)
    thr = _threshold(sub[:, 2], opts)[:, None]
    score = (np.abs(sub @ nrm.T + d) < thr).sum(0)
    best = int(np.argmax(score))
    inl = np.abs(sub @ nrm[best] + d[best]) < thr[:, 0]
    if inl.sum() < 3:
        return None
    q = sub[inl]
    centroid = q.mean(0)
    _, _, vt = np.linalg.svd(q - centroid, full_matrices=False)
    normal = vt[2] if vt[2] @ nrm[best] > 0 else -vt[2]
    return _Plane(normal, float(-normal @ centroid))


def _ransac_vertical(pts: F64, nrm: F64, up: F64, opts: GeometricOptions, rng: np.random.Generator) -> _Plane | None:
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


def _plane_inliers(pts: F64, nrm: F64, plane: _Plane, mask: B, opts: GeometricOptions) -> B:
    dist = np.abs(pts @ plane.normal + plane.offset)
    cos_n = np.cos(np.deg2rad(opts.normal_agreement_deg))
    return mask & (dist < _threshold(pts[..., 2], opts)) & (np.abs(nrm @ plane.normal) > cos_n)


def _protrudes(region: B, pts: F64, plane: _Plane, opts: GeometricOptions) -> bool:
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


def _reaches_up(region: B, pts: F64, up: F64, top_needed: float, opts: GeometricOptions) -> bool:
    """Does the region reach ``top_needed`` metres above the camera (or the image's top rows)?"""
    rows = np.flatnonzero(region.any(1))
    if rows[0] <= opts.normal_step_px + 1:
        return True
    return float(np.percentile(pts[region] @ up, 98)) >= top_needed


def _classify_vertical_region(
    region: B, pts: F64, plane: _Plane, up: F64, top_needed: float, opts: GeometricOptions
) -> Label:
    if not _reaches_up(region, pts, up, top_needed, opts):
        return Label.CLUTTER  # walls and columns reach the ceiling; crates and tables do not
    cols = np.flatnonzero(region.any(0))
    w = region.shape[1]
    margin = opts.normal_step_px + 1
    if cols[0] <= margin and cols[-1] >= w - 1 - margin:
        return Label.WALL
    t = np.cross(up, plane.normal)
    t /= np.linalg.norm(t)
    s = pts[region] @ t
    width = float(np.percentile(s, 98) - np.percentile(s, 2))
    if width >= opts.column_max_width_m:
        return Label.WALL
    return Label.COLUMN if _protrudes(region, pts, plane, opts) else Label.WALL


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
    d_full = np.asarray(depth, dtype=np.float32)
    if d_full.ndim != 2:
        raise SegmentationInputError(f"depth must be (H, W), got {d_full.shape}", field="depth")
    check_shape(d_full, camera, "depth")
    if not np.isfinite(d_full).all():
        raise SegmentationInputError("depth has NaN/inf values", field="depth")
    pose = np.asarray(world_from_cam, dtype=np.float64)
    if pose.shape != (7,) or not np.isfinite(pose).all():
        raise SegmentationInputError(f"world_from_cam must be a finite (7,) pose, got {pose.shape}", field="world_from_cam")
    rng = np.random.default_rng(opts.seed)
    scale = min(1.0, opts.work_width / camera.width)
    cam = camera.pinhole().scaled(scale) if scale < 1.0 else camera.pinhole()
    d = cv2.resize(d_full, (cam.width, cam.height), interpolation=cv2.INTER_NEAREST) if scale < 1.0 else d_full
    pts, valid, nrm, nok = _points_and_normals(d, cam, opts)
    up = quat_to_rotmat(pose[3:]).T @ np.array([0.0, 0.0, 1.0])
    h, w = d.shape
    labels = np.full((h, w), int(Label.UNKNOWN), dtype=np.uint8)
    labels[valid] = int(Label.CLUTTER)
    n_valid = int(valid.sum())
    if n_valid == 0:
        return cv2.resize(labels, (camera.width, camera.height), interpolation=cv2.INTER_NEAREST)
    min_plane = max(20, int(opts.min_plane_fraction * h * w))
    min_region = max(10, int(opts.min_region_fraction * h * w))
    height = pts @ up
    cos_h = np.cos(np.deg2rad(opts.horizontal_angle_deg))
    cos_up = nrm @ up

    # ---- floor and ceiling
    assigned = np.zeros((h, w), dtype=bool)
    planes: dict[Label, _Plane] = {}
    regions: list[tuple[Label, _Plane]] = []  # planar regions: label and plane
    chosen: dict[Label, B] = {}  # the floor's / ceiling's pixels
    region_id = np.full((h, w), -1, dtype=np.int32)
    for label, sign, cand in (
        (Label.FLOOR, 1.0, nok & (cos_up > cos_h) & (height < -opts.floor_min_drop_m)),
        (Label.CEILING, -1.0, nok & (cos_up < -cos_h) & (height > opts.ceiling_min_rise_m)),
    ):
        remaining = cand.copy()
        found: list[tuple[float, _Plane, B]] = []
        for _ in range(opts.max_horizontal_planes):
            if remaining.sum() < min_plane:
                break
            plane = _ransac_horizontal(pts[remaining], up, cos_h, opts, rng)
            if plane is None:
                break
            inl = _plane_inliers(pts, nrm, plane, nok & ~assigned, opts)
            if (inl & remaining).sum() < min_plane:
                break
            # the plane's height along up: points p with n·p + offset = 0 → height ≈ -offset (n ≈ ±up)
            level = float(np.median(height[inl]))
            found.append((level, plane, inl))
            remaining &= ~inl
        if not found:
            continue
        found.sort(key=lambda x: sign * x[0])  # floor: lowest first; ceiling: highest first
        _, plane, inl = found[0]
        chosen[label] = inl
        labels[inl] = int(label)
        assigned |= inl
        planes[label] = plane
        region_id[inl] = len(regions)
        regions.append((label, plane))
        for _, _, other in found[1:]:
            assigned |= other  # tables, sills: clutter
    if Label.FLOOR in planes:
        up_ref = planes[Label.FLOOR].normal * np.sign(planes[Label.FLOOR].normal @ up)
    elif Label.CEILING in planes:
        up_ref = -planes[Label.CEILING].normal * np.sign(planes[Label.CEILING].normal @ -up)
    else:
        up_ref = up
    up_ref = up_ref / np.linalg.norm(up_ref)

    # ---- walls and columns (planar); they must reach up to near the ceiling (or above the
    # camera when no ceiling is seen), which tells them from crates and tables
    # (heights along the refined up: the pose's up may be off by a few degrees)
    if Label.CEILING in chosen:
        top_needed = float(np.median(pts[chosen[Label.CEILING]] @ up_ref)) - opts.top_gap_m
    else:
        top_needed = 0.0
    sin_v = np.sin(np.deg2rad(opts.vertical_angle_deg))
    vert = nok & ~assigned & (np.abs(nrm @ up_ref) < sin_v)
    remaining = vert.copy()
    for _ in range(opts.max_vertical_planes):
        if remaining.sum() < min_plane:
            break
        plane = _ransac_vertical(pts[remaining], nrm[remaining], up_ref, opts, rng)
        if plane is None:
            break
        inl = _plane_inliers(pts, nrm, plane, remaining, opts)
        if inl.sum() < min_plane:
            break
        remaining &= ~inl
        n_comp, comp, stats, _ = cv2.connectedComponentsWithStats(inl.astype(np.uint8), connectivity=8)
        for c in range(1, n_comp):
            if stats[c, cv2.CC_STAT_AREA] < min_region:
                continue
            region = comp == c
            lab = _classify_vertical_region(region, pts, plane, up_ref, top_needed, opts)
            labels[region] = int(lab)
            assigned |= region
            region_id[region] = len(regions)
            regions.append((lab, plane))

    # ---- curved columns: tall, narrow left-over vertical regions
    n_comp, comp, stats, _ = cv2.connectedComponentsWithStats(remaining.astype(np.uint8), connectivity=8)
    for c in range(1, n_comp):
        if stats[c, cv2.CC_STAT_AREA] < min_region:
            continue
        region = comp == c
        p = pts[region]
        hgt = p @ up_ref
        horiz = p - np.outer(hgt, up_ref)
        hc = horiz - horiz.mean(0)
        extent = 2.0 * np.sqrt(max(np.linalg.eigvalsh(hc.T @ hc / len(hc))[-1], 0.0)) * 1.73  # ≈ full width of a uniform spread
        tall = np.percentile(hgt, 98) - np.percentile(hgt, 2)
        if extent < opts.column_max_width_m and tall > opts.column_min_height_m and _reaches_up(region, pts, up_ref, top_needed, opts):
            # a round column stands out of its surroundings; a crease between walls does not
            e1 = np.cross(up_ref, np.array([0.0, 0.0, 1.0]))
            e1 = e1 / max(np.linalg.norm(e1), 1e-12) if np.linalg.norm(e1) > 1e-6 else np.array([1.0, 0.0, 0.0])
            e2 = np.cross(up_ref, e1)
            xy = np.stack([p @ e1, p @ e2], 1)
            c0 = xy.mean(0)
            _, _, vt = np.linalg.svd(xy - c0, full_matrices=False)
            n2 = np.array([-vt[0, 1], vt[0, 0]])
            normal = n2[0] * e1 + n2[1] * e2
            centroid = p.mean(0)
            if normal @ centroid > 0:
                normal = -normal
            # one protruding side is enough here: a curved region is no wall end
            if not _protrudes(region, pts, _Plane(normal, float(-normal @ centroid)), replace(opts, protrusion_sides=1)):
                continue
            labels[region] = int(Label.COLUMN)
            assigned |= region

    # ---- undecided pixels (no normal at depth edges, mixed normals along creases) take the label
    # of the nearby planar region (within ``crease_px``) on whose plane they lie, nearest plane first
    undecided = valid & (labels == int(Label.CLUTTER)) & (region_id < 0)
    if undecided.any() and regions:
        r, c = np.nonzero(undecided)
        p = pts[r, c]
        best = np.full(len(r), np.inf)
        best_label = np.full(len(r), int(Label.CLUTTER), dtype=np.uint8)
        kernel = np.ones((2 * opts.crease_px + 1,) * 2, np.uint8)
        thr = 2.0 * _threshold(p[:, 2], opts)
        for k, (lab, plane) in enumerate(regions):
            near = cv2.dilate((region_id == k).astype(np.uint8), kernel)[r, c] > 0
            dist = np.abs(p @ plane.normal + plane.offset)
            take = near & (dist < thr) & (dist < best)
            best[take] = dist[take]
            best_label[take] = int(lab)
        labels[r, c] = best_label
    if scale < 1.0:
        labels = _upsample_labels(labels, region_id, regions, d_full, camera, opts)
    return labels


def _upsample_labels(
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


@dataclass(frozen=True)
class GeometricSegmenter:
    """Provider wrapper of :func:`segment_geometric` (needs ``frame.depth`` and ``frame.world_from_cam``)."""

    options: GeometricOptions = GeometricOptions()

    def segment(self, frame: FrameInput) -> U8:
        if frame.depth is None or frame.world_from_cam is None:
            raise SegmentationInputError("the geometric segmenter needs dense depth and the initial pose", field="depth")
        return segment_geometric(frame.depth, frame.camera, frame.world_from_cam, self.options)
