"""The vectorized semantic floor plan: wall and column outlines as segments in metres.

Per storey (step 2 of the pipeline, docs/architecture.md):

1. **Cut** the wall and column meshes in a horizontal band, by default ±0.2 m around 1.2 m above
   the storey elevation (above usual window sills, below door heads; clipped to the storey's own
   z range, below the next storey's elevation), by slicing them exactly at
   ``n_levels`` evenly spaced heights and sampling the slice outlines every ``resolution/4``:
   a dense, uniformly sampled point set on the element surfaces inside the band.
2. **Rasterise** each class into an occupancy image (default 0.05 m cells) whose pixel
   ``(col, row)`` covers ``x ∈ [ox + col·r, ox + (col+1)·r)``, ``y ∈ [oy + row·r, oy + (row+1)·r)``
   (``origin = (ox, oy)``, ``r`` = resolution; row index grows with y).
3. **Clean**: connected components smaller than ``min_component_px`` are removed (specks).
4. **Detect** rough segments with one of :class:`Vectorizer` (probabilistic Hough, OpenCV's LSD,
   or contour polygon approximation).
5. **Refine** each rough segment against the band points: the dominant face within 0.75 cell is
   fitted by total least squares, its points within ``fit_tol_m`` are projected on the line and
   split where they leave a gap longer than ``gap_m`` (door openings stay open).
6. **Merge** collinear pieces of one class (directions within ``merge_angle_deg``, offsets within
   ``merge_offset_m``, overlapping or closer than ``gap_m``), then refine once more.

Columns take another route after step 3 (:func:`column_outlines`): each blob's band points are
wrapped in their convex hull, whose sides are the column's outline segments (class COLUMN).

The exact slice at the cut height is kept as the second opinion
(:func:`bimcap.bim.slicing.agreement`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.bim.ingest import BimModel, concatenate_meshes
from bimcap.bim.slicing import (
    Agreement,
    agreement,
    sample_segments,
    slice_band,
    slice_mesh,
    thin_points,
)
from bimcap.labels import Label

#: The classes a floor plan carries, in drawing order.
PLAN_CLASSES: tuple[Label, ...] = (Label.WALL, Label.COLUMN)


class Vectorizer(str, Enum):
    """Rough line detector run on the occupancy image."""

    HOUGH = "hough"  #: cv2.HoughLinesP
    LSD = "lsd"  #: cv2.createLineSegmentDetector
    CONTOUR = "contour"  #: cv2.findContours + cv2.approxPolyDP


@dataclass(frozen=True)
class FloorPlanOptions:
    """How the floor plan is cut, rasterised and vectorized (lengths in metres).

    Attributes
    ----------
    cut_height_m: height of the cut above the storey elevation.
    half_band_m: half-height of the band around the cut.
    resolution_m: raster cell size.
    n_levels: slices through the band (sampling heights).
    vectorizer: rough detector.
    min_component_px: smaller connected components are specks and removed.
    fit_tol_m: points within this distance of a fitted line belong to it.
    gap_m: a segment is split where its points leave a longer gap; pieces closer than this merge.
    min_length_m: shorter final segments are dropped.
    merge_angle_deg, merge_offset_m: collinearity tolerances for merging.
    margin_m: raster margin around the model's walls and columns.
    reach_m: a refined face is followed up to this far past the rough segment's ends (a rough
        detector often stops short of a corner whose pixels another line took).
    """

    cut_height_m: float = 1.2
    half_band_m: float = 0.2
    resolution_m: float = 0.05
    n_levels: int = 9
    vectorizer: Vectorizer = Vectorizer.HOUGH
    min_component_px: int = 3
    fit_tol_m: float = 0.005
    gap_m: float = 0.04
    min_length_m: float = 0.03
    merge_angle_deg: float = 1.0
    merge_offset_m: float = 0.01
    margin_m: float = 0.5
    reach_m: float = 0.5

    def __post_init__(self) -> None:
        from bimcap.bim.errors import BimOptionsError

        positive = ("half_band_m", "resolution_m", "fit_tol_m", "gap_m", "min_length_m",
                    "merge_offset_m", "reach_m")
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise BimOptionsError(f"FloorPlanOptions.{name} must be > 0, got {value!r}")
        if self.n_levels < 1:
            raise BimOptionsError(f"FloorPlanOptions.n_levels must be >= 1, got {self.n_levels}")
        if not np.isfinite(self.cut_height_m):
            raise BimOptionsError("FloorPlanOptions.cut_height_m must be finite")
        if self.fit_tol_m >= self.resolution_m:
            raise BimOptionsError("FloorPlanOptions.fit_tol_m must be below resolution_m")
        object.__setattr__(self, "vectorizer", Vectorizer(self.vectorizer))

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["vectorizer"] = self.vectorizer.value
        return d


@dataclass
class StoreyPlan:
    """The floor plan of one storey.

    Attributes
    ----------
    storey: storey name. elevation_m: its elevation.
    band: (2,) z range of the cut band in metres. z_range: (2,) z range the segments apply to
        (storey elevation to the next storey's).
    segments: (S, 4) ``x1 y1 x2 y2`` metres. segment_class: (S,) int32 Label ids (1 wall, 4 column).
    exact: class → (K, 4) exact slice at the cut height. exact_band: class → union over the band.
    agreement: class name (and ``"all"``) → coverage / precision against the exact slice.
    images: class → (H, W) uint8 occupancy image (255 = occupied).
    """

    storey: str
    elevation_m: float
    band: NDArray[np.float64]
    z_range: NDArray[np.float64]
    segments: NDArray[np.float64]
    segment_class: NDArray[np.int32]
    exact: dict[Label, NDArray[np.float64]] = field(default_factory=dict)
    exact_band: dict[Label, NDArray[np.float64]] = field(default_factory=dict)
    agreement: dict[str, Agreement] = field(default_factory=dict)
    images: dict[Label, NDArray[np.uint8]] = field(default_factory=dict)

    def lengths(self) -> dict[str, float]:
        """Total segment length per class name, metres."""
        seg_len = np.hypot(self.segments[:, 2] - self.segments[:, 0],
                           self.segments[:, 3] - self.segments[:, 1])
        return {c.name.lower(): float(seg_len[self.segment_class == c].sum()) for c in PLAN_CLASSES}


@dataclass
class FloorPlan:
    """The vectorized floor plan of every storey that has walls or columns in its band.

    Attributes
    ----------
    storeys: per-storey plans. resolution_m: raster cell size. origin: (2,) world xy of the corner
    of pixel (0, 0). shape: (H, W) of the occupancy images. options: the options used.
    """

    storeys: list[StoreyPlan]
    resolution_m: float
    origin: NDArray[np.float64]
    shape: tuple[int, int]
    options: FloorPlanOptions

    @property
    def segments(self) -> NDArray[np.float64]:
        """(S, 4) all storeys' segments."""
        return _cat([s.segments for s in self.storeys], (0, 4), np.float64)

    @property
    def segment_class(self) -> NDArray[np.int32]:
        return _cat([s.segment_class for s in self.storeys], (0,), np.int32)

    @property
    def segment_z(self) -> NDArray[np.float64]:
        """(S, 2) the z range each segment applies to (its storey's)."""
        return _cat(
            [np.repeat(s.z_range[None], len(s.segments), axis=0) for s in self.storeys],
            (0, 2),
            np.float64,
        )

    @property
    def segment_storey(self) -> list[str]:
        return [s.storey for s in self.storeys for _ in range(len(s.segments))]

    def to_dict(self) -> dict[str, Any]:
        """The floor-plan JSON: segments with class and storey, band, resolution,
        origin, plus each storey's coverage / precision."""
        segs = []
        for s in self.storeys:
            for seg, c in zip(s.segments, s.segment_class, strict=True):
                segs.append({
                    "x1": float(seg[0]), "y1": float(seg[1]),
                    "x2": float(seg[2]), "y2": float(seg[3]),
                    "class": Label(int(c)).name.lower(), "storey": s.storey,
                })
        return {
            "format": "bimcap-floorplan",
            "version": 1,
            "units": "m",
            "resolution_m": self.resolution_m,
            "origin": [float(v) for v in self.origin],
            "origin_meaning": "world xy of the corner of pixel (col 0, row 0); rows grow with y",
            "image_shape": list(self.shape),
            "options": self.options.to_dict(),
            "storeys": [
                {
                    "storey": s.storey,
                    "elevation_m": s.elevation_m,
                    "band": [float(v) for v in s.band],
                    "z_range": [float(v) for v in s.z_range],
                    "segment_count": len(s.segments),
                    "length_m": s.lengths(),
                    "agreement": {k: a.to_dict() for k, a in s.agreement.items()},
                }
                for s in self.storeys
            ],
            "segments": segs,
        }


def _cat(parts: list[NDArray[Any]], empty: tuple[int, ...], dtype: Any) -> NDArray[Any]:
    parts = [p for p in parts if len(p)]
    return np.concatenate(parts).astype(dtype) if parts else np.zeros(empty, dtype=dtype)


# --------------------------------------------------------------------------- raster


def rasterize(
    pts: NDArray[np.float64], origin: NDArray[np.float64], res: float, shape: tuple[int, int]
) -> NDArray[np.uint8]:
    """(H, W) uint8 occupancy image of xy points (P, 2) metres; 255 where a point falls."""
    img = np.zeros(shape, dtype=np.uint8)
    if len(pts) == 0:
        return img
    col = np.floor((pts[:, 0] - origin[0]) / res).astype(np.int64)
    row = np.floor((pts[:, 1] - origin[1]) / res).astype(np.int64)
    ok = (col >= 0) & (col < shape[1]) & (row >= 0) & (row < shape[0])
    img[row[ok], col[ok]] = 255
    return img


def clean(img: NDArray[np.uint8], min_component_px: int) -> NDArray[np.uint8]:
    """Remove 8-connected components smaller than ``min_component_px`` pixels."""
    import cv2

    _, lab, stats, _ = cv2.connectedComponentsWithStats(img, connectivity=8)
    small = np.nonzero(stats[:, cv2.CC_STAT_AREA] < min_component_px)[0]
    small = small[small != 0]
    out = img.copy()
    if len(small):
        out[np.isin(lab, small)] = 0
    return out


def detect(img: NDArray[np.uint8], method: Vectorizer, fine: bool = False) -> NDArray[np.float64]:
    """Rough segments ``(S, 4)`` in pixel coordinates ``u1 v1 u2 v2`` (pixel centres integer).

    ``fine`` selects the settings of the second round, run on the pixels that the first round's
    segments do not explain (short wall ends, jambs): Hough accepts shorter, weaker lines.
    """
    import cv2

    if not img.any():
        return np.zeros((0, 4))
    if method == Vectorizer.HOUGH:
        cv2.setRNGSeed(0)  # HoughLinesP is randomised: fix its draw order for reproducible plans
        if fine:
            # Short leftovers (jambs, wall ends of 3-5 pixels) are where Hough is weakest: add
            # the polygon sides of the leftover contours as candidates too.
            lines = cv2.HoughLinesP(img, 1, np.pi / 180, threshold=3, minLineLength=2,
                                    maxLineGap=1)
            hough = np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(np.float64)
            return np.concatenate([hough, detect(img, Vectorizer.CONTOUR)])
        else:
            lines = cv2.HoughLinesP(img, 1, np.pi / 360, threshold=10, minLineLength=5,
                                    maxLineGap=2)
        return np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(np.float64)
    if method == Vectorizer.LSD:
        lsd = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD)
        blurred = cv2.GaussianBlur(cv2.dilate(img, np.ones((3, 3), np.uint8)), (3, 3), 0)
        lines = lsd.detect(blurred)[0]
        return np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4).astype(np.float64)
    if method == Vectorizer.CONTOUR:
        contours, _ = cv2.findContours(img, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
        segs = []
        for c in contours:
            poly = cv2.approxPolyDP(c, 1.0, True).reshape(-1, 2).astype(np.float64)
            if len(poly) < 2:
                continue
            nxt = np.roll(poly, -1, axis=0)
            segs.append(np.concatenate([poly, nxt], axis=1))
        return np.concatenate(segs) if segs else np.zeros((0, 4))
    raise ValueError(f"unknown vectorizer {method!r}")


# --------------------------------------------------------------------------- refine / merge


def _fit_line(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Total least squares line through (P, 2) points: (centroid, unit direction)."""
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    return c, vt[0]


def _runs(t: NDArray[np.float64], gap: float) -> list[tuple[float, float]]:
    """[start, end] intervals of sorted positions ``t`` split where consecutive gaps exceed gap."""
    if len(t) == 0:
        return []
    t = np.sort(t)
    cut = np.nonzero(np.diff(t) > gap)[0]
    starts = np.concatenate([[0], cut + 1])
    ends = np.concatenate([cut, [len(t) - 1]])
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends, strict=True)]


def _faces_in_window(off: NDArray[np.float64], bin_m: float) -> list[float]:
    """Offsets of the faces among point offsets from a rough line: peaks of a histogram with
    ``bin_m`` bins that hold at least a quarter of the largest peak (and 3 points)."""
    bins = np.round(off / bin_m).astype(np.int64)
    vals, counts = np.unique(bins, return_counts=True)
    if len(vals) == 0:
        return []
    full = np.zeros(vals[-1] - vals[0] + 3, dtype=np.int64)
    full[vals - vals[0] + 1] = counts
    peak = (full[1:-1] >= full[:-2]) & (full[1:-1] > full[2:])
    strong = full[1:-1] >= max(3, 0.25 * full.max())
    idx = np.nonzero(peak & strong)[0]
    return [float((i + vals[0]) * bin_m) for i in idx]


@dataclass(frozen=True)
class _FaceSearch:
    """What snapping rough segments needs: the band points ``pts`` (P, 2) metres, their KD-tree,
    the raster cell ``res`` (m) and the options."""

    pts: NDArray[np.float64]
    tree: Any
    res: float
    opts: FloorPlanOptions


@dataclass(frozen=True)
class _RoughSegment:
    """A rough segment from ``a`` (2,) to ``b`` (2,) metres, ``length`` metres long."""

    a: NDArray[np.float64]
    b: NDArray[np.float64]
    length: float


def _to_px(p: NDArray[np.float64], origin: NDArray[np.float64], res: float) -> NDArray[np.int64]:
    """Pixel ``(col, row)`` of xy points (..., 2) metres."""
    return np.floor((p - origin) / res).astype(np.int64)


def _already_refined(seg: _RoughSegment, done: NDArray[np.uint8], origin: NDArray[np.float64],
                     res: float) -> bool:
    """True when the segment's pixels lie on refined segments (90 %) of ``done`` (H, W)."""
    a, b = seg.a, seg.b
    steps = np.linspace(0.0, 1.0, max(2, int(np.ceil(2 * seg.length / res)) + 1))
    px = _to_px(a[None] + steps[:, None] * (b - a)[None], origin, res)
    shape = done.shape
    ok = (px[:, 0] >= 0) & (px[:, 0] < shape[1]) & (px[:, 1] >= 0) & (px[:, 1] < shape[0])
    return bool(ok.all() and done[px[:, 1], px[:, 0]].mean() >= 0.9)


def _draw_segments(done: NDArray[np.uint8], segs: list[NDArray[np.float64]],
                   origin: NDArray[np.float64], res: float) -> None:
    """Mark the pixels of refined segments (4,) metres in ``done`` (H, W), in place."""
    import cv2

    for s_new in segs:
        p0, p1 = _to_px(s_new[:2], origin, res), _to_px(s_new[2:], origin, res)
        cv2.line(done, (int(p0[0]), int(p0[1])), (int(p1[0]), int(p1[1])), 1, 1)


def _settle_face(cand: NDArray[np.float64], near: NDArray[np.float64], seg: _RoughSegment,
                 ctx: _FaceSearch) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Line (centre (2,), unit direction (2,)) of one face refitted until it settles, or None
    when none of its runs meets the rough segment; ``cand`` (C, 2), ``near`` (K, 2) metres."""
    opts, res, a, b = ctx.opts, ctx.res, seg.a, seg.b
    c, u = _fit_line(cand)
    runs: list[tuple[float, float]] = []
    for _ in range(4):
        # Follow the face through the whole neighbourhood (it may run past the rough
        # segment's ends: Hough stops short of corners), keep the runs that meet the
        # rough segment, and refit on their points until the line settles.
        nn = np.array([-u[1], u[0]])
        q = near - c
        on = np.abs(q @ nn) <= opts.fit_tol_m
        t_on = q[on] @ u
        ta, tb = sorted(((a - c) @ u, (b - c) @ u))
        runs = [(lo, hi) for lo, hi in _runs(t_on, opts.gap_m)
                if lo <= tb + res and hi >= ta - res]
        if not runs:
            break
        inside = np.zeros(len(t_on), dtype=bool)
        for lo, hi in runs:
            inside |= (t_on >= lo) & (t_on <= hi)
        if inside.sum() < 3:
            runs = []
            break
        c_new, u_new = _fit_line(near[on][inside])
        u_new = u_new if u_new @ u >= 0 else -u_new
        settled = abs(float(u[0] * u_new[1] - u[1] * u_new[0])) < 1e-7 and abs(
            float((c_new - c) @ nn)) < 1e-6
        c, u = c_new, u_new
        if settled:
            break
    return (c, u) if runs else None


def _face_runs(c: NDArray[np.float64], u: NDArray[np.float64], near: NDArray[np.float64],
               seg: _RoughSegment, ctx: _FaceSearch) -> list[tuple[float, float]]:
    """The runs ``(t0, t1)`` metres along the final line (centre ``c``, direction ``u``) that
    meet the rough segment; a run that reaches the edge of the neighbourhood ``near`` (K, 2)
    goes on beyond it: the neighbourhood is widened until every run ends inside."""
    opts, res, a, b = ctx.opts, ctx.res, seg.a, seg.b
    nn = np.array([-u[1], u[0]])
    mid = (a + b) / 2
    radius = seg.length / 2 + opts.reach_m
    ta, tb = sorted(((a - c) @ u, (b - c) @ u))
    t_mid = float((mid - c) @ u)
    while True:
        q = near - c
        t_on = q[np.abs(q @ nn) <= opts.fit_tol_m] @ u
        kept = [(lo, hi) for lo, hi in _runs(t_on, opts.gap_m)
                if lo <= tb + res and hi >= ta - res]
        reach_edge = any(max(abs(lo - t_mid), abs(hi - t_mid)) >= radius - res
                         for lo, hi in kept)
        if not reach_edge:
            return kept
        radius *= 2
        near = ctx.pts[np.asarray(ctx.tree.query_ball_point(mid, radius), dtype=np.int64)]


def _refine_segment(seg: _RoughSegment, ctx: _FaceSearch) -> list[NDArray[np.float64]]:
    """The refined segments (4,) metres of every face within 1.5 cells of one rough segment."""
    opts, res, pts, a, b = ctx.opts, ctx.res, ctx.pts, seg.a, seg.b
    d = (b - a) / seg.length
    n = np.array([-d[1], d[0]])
    idx = np.asarray(ctx.tree.query_ball_point((a + b) / 2, seg.length / 2 + opts.reach_m),
                     dtype=np.int64)
    if len(idx) < 3:
        return []
    q = pts[idx] - a
    t = q @ d
    off = q @ n
    sel = (np.abs(off) <= 1.5 * res) & (t >= -res) & (t <= seg.length + res)
    if sel.sum() < 3:
        return []
    local = pts[idx[sel]]
    out: list[NDArray[np.float64]] = []
    for face_off in _faces_in_window(off[sel], opts.fit_tol_m):
        cand = local[np.abs(off[sel] - face_off) <= 2 * opts.fit_tol_m]
        if len(cand) < 3:
            continue
        near = pts[idx]
        line = _settle_face(cand, near, seg, ctx)
        if line is None:
            continue
        c, u = line
        for lo, hi in _face_runs(c, u, near, seg, ctx):
            if hi - lo >= opts.min_length_m:
                out.append(np.concatenate([c + lo * u, c + hi * u]))
    return out


def refine(
    rough: NDArray[np.float64],
    pts: NDArray[np.float64],
    tree: Any,
    res: float,
    opts: FloorPlanOptions,
    origin: NDArray[np.float64],
    shape: tuple[int, int],
) -> NDArray[np.float64]:
    """Snap rough segments (S, 4) metres onto the face points ``pts`` (P, 2); (S', 4) metres.

    Every face within 1.5 cells of a rough segment (both faces of a thin wall, say) is fitted on
    its own: offsets from the rough line are histogrammed in ``fit_tol_m`` bins, each strong peak
    is a face; its points are fitted by total least squares, the face is followed through the
    neighbourhood (up to ``reach_m`` past the rough ends) and refitted until the line settles,
    then split at gaps longer than ``gap_m``. Rough segments are taken longest first, and one
    whose pixels already lie on refined segments (90 %) is skipped: it would find them again.
    """
    ctx = _FaceSearch(pts=pts, tree=tree, res=res, opts=opts)
    out: list[NDArray[np.float64]] = []
    done = np.zeros(shape, dtype=np.uint8)
    lengths = np.hypot(rough[:, 2] - rough[:, 0], rough[:, 3] - rough[:, 1])
    for si in np.argsort(-lengths, kind="stable"):
        seg = _RoughSegment(a=rough[si][:2], b=rough[si][2:], length=float(lengths[si]))
        if seg.length < 1e-6 or _already_refined(seg, done, origin, res):
            continue
        found = _refine_segment(seg, ctx)
        out += found
        _draw_segments(done, found, origin, res)
    return np.asarray(out, dtype=np.float64).reshape(-1, 4)


def merge_collinear(segs: NDArray[np.float64], opts: FloorPlanOptions) -> NDArray[np.float64]:
    """Merge collinear overlapping (or nearly touching) segments (S, 4) metres into (S', 4).

    Greedy, longest first: a segment joins a kept one when their directions differ by less than
    ``merge_angle_deg``, both its endpoints lie within ``merge_offset_m`` of the kept one's line,
    and their extents along it overlap or leave a gap below ``gap_m``; the kept line (the longer
    segment's, an exact fit already) is extended over the union.
    """
    if len(segs) == 0:
        return segs
    length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    order = np.argsort(-length, kind="stable")
    cos_tol = np.cos(np.deg2rad(opts.merge_angle_deg))
    n = len(segs)
    C = np.empty((n, 2))  # a point on each kept line
    U = np.empty((n, 2))  # its unit direction
    iv = np.empty((n, 2))  # its extent [t0, t1] along U from C
    k = 0
    for i in order:
        a, b = segs[i, :2], segs[i, 2:]
        u = (b - a) / max(length[i], 1e-12)
        if k:
            Ck, Uk = C[:k], U[:k]
            par = np.abs(Uk @ u) >= cos_tol
            cand = np.nonzero(par)[0]
            if len(cand):
                Cc, Uc = Ck[cand], Uk[cand]
                da, db = a - Cc, b - Cc
                off_a = np.abs(da[:, 0] * Uc[:, 1] - da[:, 1] * Uc[:, 0])
                off_b = np.abs(db[:, 0] * Uc[:, 1] - db[:, 1] * Uc[:, 0])
                ta = (da * Uc).sum(1)
                tb = (db * Uc).sum(1)
                lo, hi = np.minimum(ta, tb), np.maximum(ta, tb)
                ivc = iv[cand]
                ok = ((off_a <= opts.merge_offset_m) & (off_b <= opts.merge_offset_m)
                      & (lo <= ivc[:, 1] + opts.gap_m) & (hi >= ivc[:, 0] - opts.gap_m))
                if ok.any():
                    j = int(np.argmax(ok))
                    kk = cand[j]
                    iv[kk, 0] = min(iv[kk, 0], lo[j])
                    iv[kk, 1] = max(iv[kk, 1], hi[j])
                    continue
        C[k], U[k], iv[k] = a, u, (0.0, length[i])
        k += 1
    out = np.concatenate([C[:k] + iv[:k, :1] * U[:k], C[:k] + iv[:k, 1:] * U[:k]], axis=1)
    return out


def explained(
    pts: NDArray[np.float64], segs: NDArray[np.float64], tol: float
) -> NDArray[np.bool_]:
    """(P,) True where a point (P, 2) lies within ``tol`` metres of a segment (S, 4)."""
    from scipy.spatial import cKDTree

    if len(segs) == 0 or len(pts) == 0:
        return np.zeros(len(pts), dtype=bool)
    samples, _ = sample_segments(segs, tol / 2)
    dist, _ = cKDTree(samples).query(pts, k=1, distance_upper_bound=2 * tol)
    return dist <= tol


def vectorize(
    pts: NDArray[np.float64],
    origin: NDArray[np.float64],
    shape: tuple[int, int],
    opts: FloorPlanOptions,
) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """Occupancy image → detected, refined, merged segments.

    Parameters
    ----------
    pts: (P, 2) band points of one class, metres. origin: (2,) raster origin. shape: (H, W).

    Returns
    -------
    segments (S, 4) metres, and the cleaned (H, W) uint8 occupancy image.
    """
    from scipy.spatial import cKDTree

    res = opts.resolution_m
    img = clean(rasterize(pts, origin, res, shape), opts.min_component_px)
    if len(pts) < 3:
        return np.zeros((0, 4)), img
    tree = cKDTree(pts)
    found = []
    residual = img
    for fine in (False, True):
        px = detect(residual, opts.vectorizer, fine)
        rough = origin[[0, 1, 0, 1]] + (px + 0.5) * res
        found.append(refine(rough, pts, tree, res, opts, origin, shape))
        if not fine:
            # Second round on what the first did not explain.
            done = np.concatenate(found)
            left = pts[~explained(pts, done, 2 * opts.fit_tol_m)]
            residual = clean(rasterize(left, origin, res, shape), opts.min_component_px)
    segs = np.concatenate(found)
    for _ in range(4):  # greedy merging is order dependent: repeat until nothing changes
        n_before = len(segs)
        segs = merge_collinear(segs, opts)
        if len(segs) == n_before:
            break
    length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    return segs[length >= opts.min_length_m], img


def column_outlines(
    pts: NDArray[np.float64],
    origin: NDArray[np.float64],
    shape: tuple[int, int],
    opts: FloorPlanOptions,
) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """Column outlines: one convex polygon per connected blob of the column image.

    Columns are small and (nearly always) convex, rectangular or round: line detectors find only
    a few pixels per side, so each blob's band points are wrapped in their convex hull, simplified
    to ``fit_tol_m`` (a round column of radius r becomes a polygon whose sides deviate from the
    circle by at most that much), and its sides become the segments.

    Returns
    -------
    segments (S, 4) metres and the cleaned (H, W) uint8 occupancy image.
    """
    import cv2
    import shapely

    res = opts.resolution_m
    img = clean(rasterize(pts, origin, res, shape), opts.min_component_px)
    if len(pts) < 3:
        return np.zeros((0, 4)), img
    # Blobs of the dilated image, so that the two faces of a hollow outline stay one blob.
    n, lab = cv2.connectedComponents(cv2.dilate(img, np.ones((3, 3), np.uint8)), connectivity=8)
    col = np.floor((pts[:, 0] - origin[0]) / res).astype(np.int64)
    row = np.floor((pts[:, 1] - origin[1]) / res).astype(np.int64)
    ok = (col >= 0) & (col < shape[1]) & (row >= 0) & (row < shape[0])
    blob = np.zeros(len(pts), dtype=np.int64)
    blob[ok] = lab[row[ok], col[ok]]
    out = []
    for k in range(1, n):
        p = pts[blob == k]
        if len(p) < 3:
            continue
        hull = shapely.MultiPoint(p).convex_hull.simplify(opts.fit_tol_m)
        if hull.geom_type != "Polygon":
            continue
        ring = np.asarray(hull.exterior.coords)
        out.append(np.concatenate([ring[:-1], ring[1:]], axis=1))
    segs = np.concatenate(out) if out else np.zeros((0, 4))
    length = np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1])
    return segs[length > 1e-6], img


# --------------------------------------------------------------------------- per storey


def raster_frame(
    model: BimModel, opts: FloorPlanOptions
) -> tuple[NDArray[np.float64], tuple[int, int]]:
    """Origin (2,) and image shape (H, W) covering every wall and column, plus a margin."""
    elems = model.by_label(*PLAN_CLASSES)
    xy = np.concatenate([e.vertices[:, :2] for e in elems]) if elems else np.zeros((1, 2))
    res = opts.resolution_m
    lo = np.floor((xy.min(axis=0) - opts.margin_m) / res) * res
    hi = xy.max(axis=0) + opts.margin_m
    w, h = np.ceil((hi - lo) / res).astype(int) + 1
    return lo.astype(np.float64), (int(h), int(w))


def storey_plan(
    model: BimModel,
    index: int,
    origin: NDArray[np.float64],
    shape: tuple[int, int],
    opts: FloorPlanOptions,
) -> StoreyPlan:
    """The floor plan of storey ``model.storeys[index]`` (see the module docstring)."""
    st = model.storeys[index]
    if index + 1 < len(model.storeys):
        top = model.storeys[index + 1].elevation_m
    else:
        tops = [e.zmax for e in model.by_label(Label.WALL)]
        top = max([st.elevation_m + 3.0, *tops])
    # The band never leaves its storey (a low storey such as a foundation level must not pick up
    # the walls standing on the next one); the cut stays in the middle of what is left.
    lo = max(st.elevation_m + opts.cut_height_m - opts.half_band_m, st.elevation_m)
    hi = min(st.elevation_m + opts.cut_height_m + opts.half_band_m, top - 1e-3)
    if hi <= lo:
        lo, hi = st.elevation_m, max(top - 1e-3, st.elevation_m)
    zc = 0.5 * (lo + hi)
    segs_all, cls_all = [], []
    exact, exact_band, images, agree = {}, {}, {}, {}
    for cls in PLAN_CLASSES:
        elems = [e for e in model.by_label(cls) if e.zmax >= lo and e.zmin <= hi]
        v, f = concatenate_meshes(elems)
        band_slices = slice_band(v, f, lo, hi, opts.n_levels)
        band = np.concatenate(band_slices) if band_slices else np.zeros((0, 4))
        exact[cls] = slice_mesh(v, f, zc)
        exact_band[cls] = band
        # The band's slices repeat each vertical face: keep one point per fit_tol/2 square.
        pts = thin_points(sample_segments(band, opts.resolution_m / 4, endpoints=True)[0],
                          opts.fit_tol_m / 2)
        if cls == Label.COLUMN:
            segs, img = column_outlines(pts, origin, shape, opts)
        else:
            segs, img = vectorize(pts, origin, shape, opts)
        images[cls] = img
        segs_all.append(segs)
        cls_all.append(np.full(len(segs), int(cls), dtype=np.int32))
        agree[cls.name.lower()] = agreement(exact[cls], band, segs, opts.resolution_m)
    segments = _cat(segs_all, (0, 4), np.float64)
    agree["all"] = agreement(
        _cat(list(exact.values()), (0, 4), np.float64),
        _cat(list(exact_band.values()), (0, 4), np.float64),
        segments,
        opts.resolution_m,
    )
    return StoreyPlan(
        storey=st.name,
        elevation_m=st.elevation_m,
        band=np.array([lo, hi]),
        z_range=np.array([st.elevation_m, top]),
        segments=segments,
        segment_class=_cat(cls_all, (0,), np.int32),
        exact=exact,
        exact_band=exact_band,
        agreement=agree,
        images=images,
    )


def build_floor_plan(model: BimModel, opts: FloorPlanOptions | None = None) -> FloorPlan:
    """Floor plans of all storeys whose band cuts at least one wall or column."""
    opts = opts or FloorPlanOptions()
    origin, shape = raster_frame(model, opts)
    plans = []
    for i in range(len(model.storeys)):
        sp = storey_plan(model, i, origin, shape, opts)
        if any(len(x) for x in sp.exact_band.values()):
            plans.append(sp)
    return FloorPlan(plans, opts.resolution_m, origin, shape, opts)
