"""Visibility-aware maps of a floor plan: which side of each segment is free space, and one
distance field / score map / nearest-segment index per (class, viewing direction).

Walls have two faces a few centimetres apart (12-20 cm); a point seen on the inner face of an
exterior wall fits its outer face just as well unless the matcher knows that the outer face
cannot be seen from inside. Each plan segment therefore gets its **free-side normal** (the side
that is not inside a wall or column solid, found by a ray-parity test on the closed outlines of
its class), and the plan is split into ``n_bins`` layers by viewing direction: layer ``k``
holds the segments that a ray travelling in direction ``d_k ± π/n_bins`` can hit from the
free side. A point is matched only against the layer of its own class and of its ray's
direction (camera → point, after the candidate yaw). The bins are centred half a bin off the
plan's main wall direction, so that with four bins a ray along a corridor is never in the same
layer as the corridor walls' outer faces.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import NDArray

from bimcap.labels import Label
from bimcap.registration.distance_field import DistanceField, distance_to_segments

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
I32 = NDArray[np.int32]

#: The classes the coarse stage matches, in layer order.
CLASSES = (int(Label.WALL), int(Label.COLUMN))


def _crossings(p: F64, d: NDArray[np.float64], segments: F64) -> NDArray[np.int64]:
    """Number of segments each ray ``p + s d`` (s > 0) crosses; (M,) for (M, 2) points."""
    return _crossings_many(p, [d], segments)[0]


def _crossings_many(p: F64, dirs: list[NDArray[np.float64]] | tuple[NDArray[np.float64], ...],
                    segments: F64, chunk: int = 64) -> list[NDArray[np.int64]]:
    """:func:`_crossings` of the points (M, 2) for each direction of ``dirs`` (the same
    arithmetic, pair by pair, as testing every point against every segment).

    Per direction the points are sorted across the ray and taken ``chunk`` at a time: a
    segment is tested against a chunk only if it can be hit by one of its rays: it reaches the
    chunk's band across the rays and lies, at least in part, ahead of the chunk's rearmost
    point, with a margin of 1e-6 m both ways (the tests' rounding is orders of magnitude below:
    at most about 1e-11 m on a 100 m plan). Segments within 0.06 deg of parallel to the
    direction (``|d x e| < 1e-3 |e|``), where the division's rounding grows, are always
    tested. A segment left out is one no ray of the chunk crosses, so the counts are those of
    the full test."""
    p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
    a, e = segments[:, :2], segments[:, 2:] - segments[:, :2]
    b = segments[:, 2:]
    length = np.hypot(e[:, 0], e[:, 1])
    tol = 1e-6
    out = []
    for d in dirs:
        den = d[0] * e[:, 1] - d[1] * e[:, 0]
        ok = np.abs(den) > 1e-12
        always = ok & (np.abs(den) < 1e-3 * length)
        perp = np.array([-d[1], d[0]])
        p_across, p_along = p @ perp, p @ d
        s_across = np.c_[a @ perp, b @ perp]
        s_lo, s_hi = s_across.min(1), s_across.max(1)
        s_ahead = np.maximum(a @ d, b @ d)
        order = np.argsort(p_across, kind="stable")
        count = np.zeros(len(p), dtype=np.int64)
        for k in range(0, len(p), chunk):
            rows = order[k:k + chunk]
            lo, hi = p_across[rows].min(), p_across[rows].max()
            cand = np.flatnonzero(always | (ok & (s_hi >= lo - tol) & (s_lo <= hi + tol)
                                            & (s_ahead > p_along[rows].min() - tol)))
            if len(cand) == 0:
                continue
            w = a[cand][None] - p[rows][:, None]
            w0, w1 = w[..., 0], w[..., 1]
            ec = e[cand]
            den_ok = den[cand][None]
            with np.errstate(divide="ignore", invalid="ignore"):
                s_ = (w0 * ec[None, :, 1] - w1 * ec[None, :, 0]) / den_ok
                u = (w0 * d[1] - w1 * d[0]) / den_ok
            hit = (s_ > 0) & (u >= 0) & (u < 1)
            count[rows] = hit.sum(1)
        out.append(count)
    return out


def _inside_clearance(p: F64, own: NDArray[np.int64], segments: F64, chunk: int = 512) -> F64:
    """(M,) distance from each point to the nearest segment other than its own ``own[i]``."""
    a, ab = segments[:, :2], segments[:, 2:] - segments[:, :2]
    len2 = np.maximum((ab ** 2).sum(1), 1e-18)
    out = np.empty(len(p))
    for k in range(0, len(p), chunk):
        q = p[k:k + chunk]
        u = np.clip(((q[:, None, :] - a[None]) * ab[None]).sum(-1) / len2[None], 0.0, 1.0)
        d = np.linalg.norm(q[:, None, :] - (a[None] + u[..., None] * ab[None]), axis=-1)
        d[np.arange(len(q)), own[k:k + chunk]] = np.inf
        out[k:k + chunk] = d.min(1)
    return out


def _on_closed_curves(segments: F64, tol_m: float = 1e-4) -> NDArray[np.bool_]:
    """(S,) True for segments left after repeatedly pruning every segment with an endpoint
    that no other remaining segment shares (dangling chains, open outlines)."""
    ends = np.round(np.r_[segments[:, :2], segments[:, 2:]] / tol_m).astype(np.int64)
    _, vid = np.unique(ends, axis=0, return_inverse=True)
    vid = vid.reshape(2, -1)
    alive = np.ones(len(segments), dtype=bool)
    while True:
        deg = np.bincount(vid[:, alive].ravel(), minlength=int(vid.max()) + 1)
        dangling = alive & ((deg[vid[0]] < 2) | (deg[vid[1]] < 2))
        if not dangling.any():
            return alive
        alive &= ~dangling


def free_normals(segments: NDArray[np.float64], segment_class: NDArray[np.int32],
                 eps_m: float = 0.01, max_thickness_m: float = 1.2, pair_fallback: bool = True,
                 max_pair_gap_m: float = 0.6) -> F64:
    """(S, 2) unit normal of each segment pointing into free space; zero where undecided.

    The outlines of each class are treated as closed curves: a point just beside a segment is
    inside a solid iff a ray from it crosses an odd number of that class's segments. Two
    slanted rays must agree, and exactly one side must be inside; otherwise the segment is
    visible from both sides (zero normal). Segments that are not on a closed curve of their
    class (open outlines: centre lines, single faces; found by pruning dangling segments) get a
    zero normal too, since parity means nothing there. Finally a face is trusted only if the
    point just inside it is within ``max_thickness_m / 2`` of another segment (walls and
    columns are thin; a room drawn as a closed loop of single lines would otherwise look like
    a solid). With ``pair_fallback`` (default) a face with a parallel partner face (the other
    side of its wall, gap up to ``max_pair_gap_m``: :func:`_paired_face_normals`) takes its side
    from the pair, which open outlines (door openings) do not confuse; parity decides faces
    without a partner, and a face the two disagree on gets a zero normal.
    """
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    out = np.zeros((len(seg), 2))
    dirs = (np.array([0.8944, 0.4472]), np.array([-0.3162, 0.9487]))
    for c in np.unique(segment_class):
        rows = np.flatnonzero(segment_class == c)
        s = seg[rows]
        e = s[:, 2:] - s[:, :2]
        length = np.linalg.norm(e, axis=1)
        n = np.c_[-e[:, 1], e[:, 0]] / np.maximum(length, 1e-12)[:, None]
        mid = 0.5 * (s[:, :2] + s[:, 2:])
        shared = _on_closed_curves(s)
        inside = []
        for sign in (1.0, -1.0):
            p = mid + sign * eps_m * n
            odd = [(c % 2 == 1) for c in _crossings_many(p, dirs, s)]
            inside.append(np.where(odd[0] == odd[1], odd[0].astype(np.int8), -1))
        plus, minus = inside
        good = shared & (length > 1e-9) & (plus >= 0) & (minus >= 0) & (plus != minus)
        sign = np.where(plus == 0, 1.0, -1.0)
        free = sign[:, None] * n
        if good.any():
            clear = np.full(len(s), np.inf)
            g = np.flatnonzero(good)
            clear[g] = _inside_clearance(mid[g] - eps_m * free[g], g, s)
            good &= clear <= 0.5 * max_thickness_m
        parity = np.where(good[:, None], free, 0.0)
        if pair_fallback:
            paired = _paired_face_normals(s, min_gap_m=eps_m, max_gap_m=max_pair_gap_m)
            has_pair, has_parity = paired.any(1), parity.any(1)
            agree = (paired * parity).sum(1) > 0
            # Pairs first (parity rays slip through door gaps); parity where a face has no
            # partner; a face the two methods disagree on stays visible from both sides.
            parity = np.where((has_pair & (~has_parity | agree))[:, None], paired,
                              np.where((has_pair & has_parity & ~agree)[:, None], 0.0, parity))
        out[rows] = parity
    return out


def _paired_face_normals(s: F64, min_gap_m: float, max_gap_m: float,
                         max_angle_deg: float = 3.0, chunk: int = 512) -> F64:
    """(S, 2) free-side normals from face pairs: a wall is drawn as two parallel faces a
    thickness apart, so a face whose parallel, overlapping partners (gap in ``[min_gap_m,
    max_gap_m]``) all lie on one side has its solid on that side and its free side on the other.
    Zero where a face has no partner or partners on both sides. Works where the outlines are
    open (door openings break the closed curves :func:`free_normals` needs). Faces are compared
    ``chunk`` at a time against all others (memory O(chunk × S))."""
    a, b = s[:, :2], s[:, 2:]
    length = np.linalg.norm(b - a, axis=1)
    u = (b - a) / np.maximum(length, 1e-12)[:, None]
    n = np.c_[-u[:, 1], u[:, 0]]
    mid = 0.5 * (a + b)
    cos_max = np.cos(np.radians(max_angle_deg))
    out = np.zeros((len(s), 2))
    for k in range(0, len(s), chunk):
        r = slice(k, min(k + chunk, len(s)))
        # Only the parallel pairs (i, j) can be partners: the other tests on those alone (the
        # same arithmetic per pair).
        i, j = np.nonzero((np.abs(u[r] @ u.T) >= cos_max) & (length[r, None] > 1e-9))
        ia = i + r.start
        a0, u0, n0 = a[ia], u[ia], n[ia]
        off = ((mid[j] - a0) * n0).sum(-1)  # which side of face i face j lies on
        # Overlap of face j's extent with face i's, along face i.
        ta, tb = ((a[j] - a0) * u0).sum(-1), ((b[j] - a0) * u0).sum(-1)
        overlap = (np.minimum(np.maximum(ta, tb), length[ia])
                   - np.maximum(np.minimum(ta, tb), 0.0))
        pair = ((np.abs(off) >= min_gap_m) & (np.abs(off) <= max_gap_m) & (overlap > 0.05)
                & (ia != j))
        c = r.stop - r.start
        plus = np.bincount(i[pair & (off > 0)], minlength=c) > 0
        minus = np.bincount(i[pair & (off < 0)], minlength=c) > 0
        out[r][plus & ~minus] = -n[r][plus & ~minus]
        out[r][minus & ~plus] = n[r][minus & ~plus]
    return out


def free_normals_by_storey(segments: NDArray[np.float64], segment_class: NDArray[np.int32],
                           segment_z: NDArray[np.float64] | None = None, **kwargs: float) -> F64:
    """(S, 2) :func:`free_normals` computed separately for each storey (each distinct
    ``segment_z`` row), so that the outlines of storeys stacked over each other do not cross
    each other's parity rays. ``segment_z`` None treats all segments as one storey."""
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    cls = np.asarray(segment_class, dtype=np.int32).reshape(-1)
    out = np.zeros((len(seg), 2))
    if segment_z is None or len(seg) == 0:
        return free_normals(seg, cls, **kwargs) if len(seg) else out
    z = np.asarray(segment_z, dtype=np.float64).reshape(-1, 2)
    _, storey = np.unique(np.round(z, 6), axis=0, return_inverse=True)
    for k in np.unique(storey):
        rows = np.flatnonzero(storey.reshape(-1) == k)
        out[rows] = free_normals(seg[rows], cls[rows], **kwargs)
    return out


def dominant_orientation(segments: NDArray[np.float64]) -> float:
    """The plan's main wall direction modulo 90° (radians, length-weighted circular mean)."""
    e = segments[:, 2:] - segments[:, :2]
    ang = np.arctan2(e[:, 1], e[:, 0])
    z = (np.hypot(e[:, 0], e[:, 1]) * np.exp(4j * ang)).sum()
    return float(np.angle(z) / 4) if abs(z) > 0 else 0.0


def view_bin(view_xy: NDArray[np.float64], n_bins: int, offset: float = 0.0
             ) -> NDArray[np.int64]:
    """(M,) bin of each ray direction; bin k is centred on angle ``offset + 2πk / n_bins``."""
    if n_bins <= 1:
        return np.zeros(len(view_xy), dtype=np.int64)
    ang = np.arctan2(view_xy[:, 1], view_xy[:, 0]) - offset
    return np.asarray(np.round(ang / (2 * np.pi / n_bins)) % n_bins, dtype=np.int64)


@dataclass
class PlanMaps:
    """Per-layer distance fields and score maps of one storey's plan section.

    Layer ``l = slot * n_bins + k`` holds the segments of class ``CLASSES[slot]`` visible to
    rays of bin ``k`` (see the module docstring).

    Attributes
    ----------
    segments: (S, 4); segment_class: (S,) int32; free_normal: (S, 2).
    n_bins: number of viewing-direction bins (1 = no visibility test).
    bin_offset: direction of the centre of bin 0, radians: half a bin off the plan's main
        wall direction, so that no bin holds rays on both sides of a wall's direction (a ray
        travelling along a corridor then cannot be matched to the outer face of its walls).
    rows: per layer, the segment rows it holds.
    coarse, fine: per layer, a :class:`DistanceField` (``fine`` with nearest-segment labels).
    coarse_score, fine_score: per layer, the truncated-Gaussian score map.
    """

    segments: F64
    segment_class: I32
    free_normal: F64
    n_bins: int
    bin_offset: float
    rows: list[NDArray[np.int64]]
    coarse: list[DistanceField]
    coarse_score: list[F32]
    fine: list[DistanceField]
    fine_score: list[F32]

    @classmethod
    def build(cls, segments: NDArray[np.float64], segment_class: NDArray[np.int32],
              bounds_xy: tuple[float, float, float, float], margin_m: float, n_bins: int,
              coarse_resolution_m: float, coarse_sigma_m: float, fine_resolution_m: float,
              fine_sigma_m: float, truncate: float) -> PlanMaps:
        seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
        cls_ = np.asarray(segment_class, dtype=np.int32)
        n_bins = max(int(n_bins), 1)
        normal = free_normals(seg, cls_) if n_bins > 1 else np.zeros((len(seg), 2))
        half = np.pi / n_bins
        offset = dominant_orientation(seg) + half if len(seg) else half
        rows, coarse, coarse_s, fine, fine_s = [], [], [], [], []
        for c in CLASSES:
            for k in range(n_bins):
                if n_bins > 1:
                    a = offset + 2 * np.pi * k / n_bins
                    d = np.array([np.cos(a), np.sin(a)])
                    # Some ray of the bin hits a face from its free side iff n·d < sin(half);
                    # faces exactly parallel to a bin edge are left out (grazing only).
                    vis = (normal @ d < np.sin(half) - 1e-6) | ~normal.any(1)
                else:
                    vis = np.ones(len(seg), dtype=bool)
                r = np.flatnonzero(vis & (cls_ == c))
                rows.append(r)
                cf = DistanceField.from_segments(seg[r], coarse_resolution_m, bounds_xy, margin_m)
                ff = DistanceField.from_segments(seg[r], fine_resolution_m, bounds_xy, margin_m,
                                                 with_nearest=True)
                coarse.append(cf)
                coarse_s.append(cf.score_map(coarse_sigma_m, truncate))
                fine.append(ff)
                fine_s.append(ff.score_map(fine_sigma_m, truncate))
        return cls(seg, cls_, normal, n_bins, offset, rows, coarse, coarse_s, fine, fine_s)

    @property
    def n_layers(self) -> int:
        return len(self.rows)

    def layer_of(self, p_class: NDArray[np.int32], view_xy: NDArray[np.float64]
                 ) -> NDArray[np.int64]:
        """(M,) layer of each point from its class and its ray direction (camera → point)."""
        slot = np.where(np.asarray(p_class) == Label.COLUMN, 1, 0)
        return slot * self.n_bins + view_bin(view_xy, self.n_bins, self.bin_offset)

    def _stack(self) -> _Stack | None:
        """The fine rasters of every layer stacked (L, H, W), built once; None when the layers'
        grids differ (then the per-layer loops are used)."""
        cached = self.__dict__.get("_stacked", False)
        if cached is not False:
            return cast("_Stack | None", cached)
        out: _Stack | None = None
        f0 = self.fine[0] if self.fine else None
        if f0 is not None and all(
                f.distance_m.shape == f0.distance_m.shape and f.resolution_m == f0.resolution_m
                and np.array_equal(f.origin_xy, f0.origin_xy) and f.nearest_segment is not None
                for f in self.fine):
            # Filled in place (no per-layer temporaries, no copy by ``np.stack``); the rows
            # as int32 (a segment index), half the memory of the int64 gather.
            shape = (len(self.fine), *f0.distance_m.shape)
            nearest = np.empty(shape, np.int32)
            distance = np.empty(shape, np.float32)
            score = np.empty(shape, np.float32)
            for k, f in enumerate(self.fine):
                if len(self.rows[k]):
                    np.take(self.rows[k].astype(np.int32), f.nearest_segment,  # type: ignore[arg-type]
                            out=nearest[k])
                else:
                    nearest[k] = -1
                distance[k] = f.distance_m
                score[k] = self.fine_score[k]
            out = _Stack(f0.origin_xy, f0.resolution_m, nearest, distance, score)
        self.__dict__["_stacked"] = out
        return out

    def prepare(self) -> None:
        """Build what the lookups build on first use (the stacked fine rasters) now: before
        several threads read the maps at once (each would build it again)."""
        self._stack()

    def nearest(self, q_xy: NDArray[np.float64], layer: NDArray[np.int64]) -> tuple[F64, F64]:
        """(dist (M,), closest (M, 2)): the exact distance to the segment that the fine raster
        names nearest in each point's layer; ``inf`` (and the point) for an empty layer."""
        q = np.asarray(q_xy, dtype=np.float64).reshape(-1, 2)
        dist = np.full(len(q), np.inf)
        closest = q.copy()
        st = self._stack()
        if st is not None:
            _, h, w = st.nearest.shape
            uv = np.rint((q - st.origin_xy) / st.resolution_m).astype(np.int64)
            # One flat index (the same element as indexing by layer, row, column).
            flat = ((np.asarray(layer, np.int64) * h + np.clip(uv[:, 1], 0, h - 1)) * w
                    + np.clip(uv[:, 0], 0, w - 1))
            idx = np.take(st.nearest.reshape(-1), flat)
            ok = idx >= 0
            if ok.all():  # the usual case: no mask to gather through
                return distance_to_segments(q, self.segments, idx)
            dist[ok], closest[ok] = distance_to_segments(q[ok], self.segments, idx[ok])
            return dist, closest
        for lay in np.unique(layer):
            r = self.rows[lay]
            if len(r) == 0:
                continue
            m = layer == lay
            idx = r[self.fine[lay].nearest_at(q[m])]
            dist[m], closest[m] = distance_to_segments(q[m], self.segments, idx)
        return dist, closest

    def fine_score_at(self, q_xy: NDArray[np.float64], layer: NDArray[np.int64]) -> F64:
        """(M,) each point's score in its layer's fine score map (bilinear)."""
        st = self._stack()
        if st is not None:
            return _lookup_stack(st, st.score, q_xy, layer)
        q = np.asarray(q_xy, dtype=np.float64).reshape(-1, 2)
        score = np.zeros(len(q))
        for lay in np.unique(layer):
            m = layer == lay
            score[m] = self.fine[lay].lookup(q[m], self.fine_score[lay])
        return score

    def fine_eval(self, q_xy: NDArray[np.float64], layer: NDArray[np.int64]
                  ) -> tuple[F64, F64]:
        """(score (M,), raster distance (M,)) of each point in its layer's fine maps."""
        q = np.asarray(q_xy, dtype=np.float64).reshape(-1, 2)
        st = self._stack()
        if st is not None:
            return (_lookup_stack(st, st.score, q, layer),
                    _lookup_stack(st, st.distance, q, layer, distance=True))
        score = np.zeros(len(q))
        dist = np.full(len(q), np.inf)
        for lay in np.unique(layer):
            m = layer == lay
            score[m] = self.fine[lay].lookup(q[m], self.fine_score[lay])
            dist[m] = self.fine[lay].lookup(q[m])
        return score, dist


@dataclass(frozen=True)
class _Stack:
    """The fine rasters of a :class:`PlanMaps`, one grid for all layers: nearest segment row
    (L, H, W) int32 (-1 for an empty layer), distance and score (L, H, W)."""

    origin_xy: F64
    resolution_m: float
    nearest: NDArray[np.int32]
    distance: F32
    score: F32


def _lookup_stack(st: _Stack, images: F32, q_xy: NDArray[np.float64],
                  layer: NDArray[np.int64], distance: bool = False) -> F64:
    """:meth:`DistanceField.lookup` of each point (M, 2) in its layer's image of ``images``
    (L, H, W), the same arithmetic in one pass."""
    uv = ((np.asarray(q_xy, dtype=np.float64) - st.origin_xy) / st.resolution_m).reshape(-1, 2)
    _, h, w = images.shape
    lay = np.asarray(layer, np.int64)
    u = np.clip(uv[:, 0], 0.0, w - 1.000001)
    v = np.clip(uv[:, 1], 0.0, h - 1.000001)
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - u0, v - v0
    # The four corners by flat index (the same elements as ``images[lay, v, u]``), and each
    # weight computed once: the same products and sums, in the same order.
    flat = images.reshape(-1)
    at = (lay * h + v0) * w + u0
    gu, gv = 1 - fu, 1 - fv
    val: F64 = ((np.take(flat, at) * gu + np.take(flat, at + 1) * fu) * gv
                + (np.take(flat, at + w) * gu + np.take(flat, at + w + 1) * fu) * fv
                ).astype(np.float64)
    if distance:
        val = val + np.hypot(uv[:, 0] - u, uv[:, 1] - v) * st.resolution_m
    return val
