"""Correlative scan matching of planar points against a floor-plan score map.

For every yaw on a grid the window's points (projected to the floor plane) are rotated about the
pivot and rasterised into a binary occupancy template at the score map's resolution; one
``cv2.matchTemplate`` (cross-correlation, FFT-based for large templates) then gives the summed
score of *every* translation on the grid at once. Occupancy (not counts) equalises the weight
of dense near-range surfaces and far ones. Points are correlated against the map of their own
class and ray direction (:class:`bimcap.registration.plan_maps.PlanMaps`: same-class association,
no matching onto faces that cannot be seen), and the layers are added with a per-class weight.

The result is a score volume over (yaw, ty, tx); its local maxima, after non-maximum
suppression, are the hypotheses handed to ICP and to the trajectory-continuity chain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bimcap.registration.icp import rot2
from bimcap.registration.plan_maps import PlanMaps

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


@dataclass(frozen=True)
class Hypothesis:
    """One candidate planar correction ``q = R(yaw)(p - pivot) + pivot + t``.

    ``score`` is the weighted mean score per occupied cell, in [0, 1].
    """

    yaw: float
    t: F64
    score: float


def _crop(img: F32, r0: int, r1: int, c0: int, c1: int) -> F32:
    """``img[r0:r1, c0:c1]`` with zeros outside the image."""
    h, w = img.shape
    out = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
    rr0, rr1, cc0, cc1 = max(r0, 0), min(r1, h), max(c0, 0), min(c1, w)
    if rr0 < rr1 and cc0 < cc1:
        out[rr0 - r0:rr1 - r0, cc0 - c0:cc1 - c0] = img[rr0:rr1, cc0:cc1]
    return out


def score_volume(
    p_xy: NDArray[np.float64],
    p_class: NDArray[np.int32],
    view_xy: NDArray[np.float64],
    maps: PlanMaps,
    pivot: NDArray[np.float64],
    yaws: NDArray[np.float64],
    xy_range_m: float,
    column_weight: float = 1.0,
) -> tuple[F32, float, int]:
    """Score of every (yaw, ty, tx) on the coarse grid of ``maps``.

    Parameters
    ----------
    p_xy: (M, 2) world points before the correction; p_class: (M,) 1 wall / 4 column.
    view_xy: (M, 2) ray directions camera → point (any length), before the correction.
    maps: the plan's layered maps; points are rasterised per layer (class × ray direction
        after the yaw) into binary occupancy templates.
    pivot: (2,) the rotation centre; yaws: (Y,) radians; xy_range_m: half-width of the
        translation grid.

    Returns
    -------
    ``(volume (Y, 2n+1, 2n+1), res, n)``: ``volume[k, j, i]`` is the weighted mean score per
    occupied cell of ``yaw = yaws[k]``, ``t = ((i - n) res, (j - n) res)``.
    """
    import cv2

    res = maps.coarse[0].resolution_m
    origin = maps.coarse[0].origin_xy
    n = round(xy_range_m / res)
    vol = np.zeros((len(yaws), 2 * n + 1, 2 * n + 1), dtype=np.float32)
    if len(p_xy) == 0:
        return vol, res, n
    for k, yaw in enumerate(yaws):
        r = rot2(float(yaw))
        q = (p_xy - pivot) @ r.T + pivot
        layer = maps.layer_of(p_class, view_xy @ r.T)
        uv = np.round((q - origin) / res).astype(np.int64)
        total = np.zeros((2 * n + 1, 2 * n + 1), dtype=np.float32)
        count = 0.0
        for lay in np.unique(layer):
            weight = column_weight if lay >= maps.n_bins else 1.0
            if weight == 0:
                continue
            luv = uv[layer == lay]
            u0, v0 = luv.min(0)
            u1, v1 = luv.max(0)
            templ = np.zeros((v1 - v0 + 1, u1 - u0 + 1), dtype=np.float32)
            templ[luv[:, 1] - v0, luv[:, 0] - u0] = 1.0
            count += weight * float(templ.sum())
            if len(maps.rows[lay]) == 0:
                continue  # nothing of this class is visible this way: the points score 0
            img = _crop(maps.coarse_score[lay], v0 - n, v1 + n + 1, u0 - n, u1 + n + 1)
            total += weight * cv2.matchTemplate(img, templ, cv2.TM_CCORR)
        if count > 0:
            vol[k] = total / count
    return vol, res, n


def top_hypotheses(
    volume: F32,
    yaws: NDArray[np.float64],
    res: float,
    n: int,
    top_k: int,
    nms_xy_m: float,
    nms_yaw_rad: float,
    diverse_yaw_rad: float = np.deg2rad(10.0),
    min_score: float = 1e-6,
) -> list[Hypothesis]:
    """Up to ``top_k`` local maxima of ``volume`` after greedy non-maximum suppression.

    Two hypotheses are the same if both ``|Δt| < nms_xy_m`` and ``|Δyaw| < nms_yaw_rad``.
    Half of the places go first to the best peak of each distinct yaw mode (peaks at least
    ``diverse_yaw_rad`` apart), so that a scene that is ambiguous along one axis (a corridor)
    cannot fill the list with translated copies of one yaw and crowd out the yaw that a
    neighbouring window needs (a symmetric room's unflipped pose).
    """
    # The selection reads the peaks best first and stops when its list is full: find the peaks
    # among the ``m`` best cells only, and take more cells when the selection runs out of them
    # (the peaks >= the m-th best value are exactly the head of the full sorted list; a
    # maximum filter of the whole volume cost 0.4 s per search on a 50 x 36 m plan).
    flat = volume.ravel()
    m = min(flat.size, 1 << 14)
    while True:
        tau = float(np.partition(flat, flat.size - m)[flat.size - m]) if m < flat.size else -np.inf
        complete = tau <= min_score
        idx = np.flatnonzero((flat >= tau) & (flat > min_score))
        k, j, i = np.unravel_index(idx, volume.shape)
        s = flat[idx]
        peak = _local_max(volume, k, j, i, s)
        k, j, i, s = k[peak], j[peak], i[peak], s[peak]
        order = np.argsort(-s, kind="stable")
        yaw_all = yaws[k[order]]
        t_all = np.c_[(i[order] - n) * res, (j[order] - n) * res]
        s_all = s[order]
        chosen = _choose(yaw_all, t_all, top_k, nms_xy_m, nms_yaw_rad, diverse_yaw_rad, complete)
        if chosen is not None:
            break
        m = min(flat.size, 8 * m)
    chosen.sort(key=lambda o: -s_all[o])
    return [Hypothesis(float(yaw_all[o]), t_all[o].copy(), float(s_all[o])) for o in chosen]


def _local_max(volume: F32, k: NDArray[np.int64], j: NDArray[np.int64], i: NDArray[np.int64],
               s: F32) -> NDArray[np.bool_]:
    """(C,) whether each cell ``(k, j, i)`` of ``volume`` (value ``s``) is at least every
    neighbour of its 3 x 3 x 3 neighbourhood, indices clipped at the borders (as
    ``scipy.ndimage.maximum_filter(volume, 3, mode="nearest")``)."""
    shape = volume.shape
    out = np.ones(len(s), dtype=bool)
    for dk in (-1, 0, 1):
        k2 = np.clip(k + dk, 0, shape[0] - 1)
        for dj in (-1, 0, 1):
            j2 = np.clip(j + dj, 0, shape[1] - 1)
            for di in (-1, 0, 1):
                if dk or dj or di:
                    out &= s >= volume[k2, j2, np.clip(i + di, 0, shape[2] - 1)]
    return out


def _choose(yaw_all: NDArray[np.float64], t_all: NDArray[np.float64], top_k: int,
            nms_xy_m: float, nms_yaw_rad: float, diverse_yaw_rad: float, complete: bool
            ) -> list[int] | None:
    """The two passes of :func:`top_hypotheses` over peaks sorted best first (yaws (P,),
    translations (P, 2)); None when a pass runs out of peaks and the list is not ``complete``
    (more peaks, all worse, may follow)."""

    def wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.abs(np.arctan2(np.sin(a), np.cos(a)))

    chosen: list[int] = []
    need = max(top_k // 2, 1)
    for o in range(len(yaw_all)):  # pass 1: one per yaw mode
        if len(chosen) >= need:
            break
        if not chosen or wrap(yaw_all[chosen] - yaw_all[o]).min() >= diverse_yaw_rad:
            chosen.append(o)
    if len(chosen) < need and not complete:
        return None
    for o in range(len(yaw_all)):  # pass 2: fill with the best remaining distinct peaks
        if len(chosen) >= top_k:
            break
        if o in chosen:
            continue
        c = np.asarray(chosen, dtype=np.int64)
        same = ((wrap(yaw_all[c] - yaw_all[o]) < nms_yaw_rad)
                & (np.linalg.norm(t_all[c] - t_all[o], axis=1) < nms_xy_m))
        if not same.any():
            chosen.append(o)
    if len(chosen) < top_k and not complete:
        return None
    return chosen


# ------------------------------------------------------------------------------------------------
# Coarse-to-fine search: the same peaks as ``top_hypotheses(score_volume(...))``, with the fine
# volume computed only where a coarse upper bound says a selected peak can lie.


@dataclass(frozen=True)
class _Term:
    """One correlation of a yaw: integer pixels ``vu`` (P, 2) (row, column of the image at the
    translation ``n, n``, i.e. without the search offset), their weights (P,), and the index of
    the image it reads."""

    vu: NDArray[np.int64]
    weight: F64
    image: int


@dataclass(frozen=True)
class FreeFactor:
    """A multiplicative factor of the score volume: the share of the positions ``xy`` (N, 2,
    metres, before the correction) that fall on pixels of value 1 of ``image`` ((H, W), 0/1, on
    the grid of ``maps.coarse[0]``), as ``bimcap.registration.global_align._free_volume``."""

    xy: F64
    image: F32


def _pool_max(img: F32, block: int) -> F32:
    """Coarse upper-bound image: ``out[A, B] = max img[bA - b : bA + b - 1, bB - b : bB + b - 1]``
    (``b = block``, zeros outside ``img``; index ``A`` is coarse pixel ``A - 1``, so that the
    window of coarse pixel ``a`` is fine rows ``[b a, b a + 2 b - 1)``)."""
    from scipy.ndimage import maximum_filter

    b = block
    h, w = img.shape
    hc, wc = -(-h // b) + 2, -(-w // b) + 2
    pad = np.zeros((b * hc + 2 * b, b * wc + 2 * b), dtype=np.float32)
    pad[b:b + h, b:b + w] = img
    # Window [r, r + 2b - 1) of ``pad``, r = b (A - 1) + b = b A.
    m = maximum_filter(pad, size=2 * b - 1, mode="constant", cval=0.0,
                       origin=-(b - 1))
    return np.ascontiguousarray(m[0:b * hc:b, 0:b * wc:b])


def _coarse_corr(vu: NDArray[np.int64], weight: F64, pooled: F32, block: int, n: int,
                 n_blocks: int) -> F32:
    """(n_blocks, n_blocks) upper bound, per block of ``block`` x ``block`` translations, of
    ``sum_p weight_p img[v_p + j - n, u_p + i - n]`` (``pooled`` = :func:`_pool_max` of img)."""
    import cv2

    a = np.floor_divide(vu - n, block) + 1  # coarse pixel in ``pooled``'s indexing
    lo, hi = a.min(0), a.max(0)
    templ = np.zeros((hi[0] - lo[0] + 1, hi[1] - lo[1] + 1), dtype=np.float32)
    np.add.at(templ, (a[:, 0] - lo[0], a[:, 1] - lo[1]), weight.astype(np.float32))
    img = _crop(pooled, lo[0], hi[0] + n_blocks, lo[1], hi[1] + n_blocks)
    return np.asarray(cv2.matchTemplate(img, templ, cv2.TM_CCORR), dtype=np.float32)


def _exact_at(vu: NDArray[np.int64], weight: F64, img: F32, cells: NDArray[np.int64], n: int,
              chunk: int = 1 << 22) -> F64:
    """``sum_p weight_p img[v_p + j - n, u_p + i - n]`` (zero outside ``img``) at each cell
    ``(j, i)`` of ``cells`` (C, 2)."""
    out = np.zeros(len(cells))
    if not len(cells) or not len(vu):
        return out
    lo = vu.min(0) - n
    hi = vu.max(0) + n
    sub = _crop(img, int(lo[0]), int(hi[0]) + 1, int(lo[1]), int(hi[1]) + 1)
    flat = sub.ravel()
    w_sub = sub.shape[1]
    base = (vu[:, 0] - n - lo[0]) * w_sub + (vu[:, 1] - n - lo[1])  # (P,)
    off = cells[:, 0] * w_sub + cells[:, 1]  # (C,)
    step = max(1, chunk // len(vu))
    wt = weight.astype(np.float64)
    for k in range(0, len(cells), step):
        out[k:k + step] = flat[off[k:k + step, None] + base[None]] @ wt
    return out


def _yaw_terms(p_xy: F64, p_class: NDArray[np.int32], view_xy: F64, maps: PlanMaps, pivot: F64,
               yaw: float, column_weight: float) -> tuple[list[_Term], float]:
    """The occupancy templates of one yaw, as :func:`score_volume` builds them: one term per
    layer with a visible segment, and the weighted count of occupied cells."""
    res = maps.coarse[0].resolution_m
    origin = maps.coarse[0].origin_xy
    r = rot2(float(yaw))
    q = (p_xy - pivot) @ r.T + pivot
    layer = maps.layer_of(p_class, view_xy @ r.T)
    uv = np.round((q - origin) / res).astype(np.int64)
    terms = []
    count = 0.0
    for lay in np.unique(layer):
        weight = column_weight if lay >= maps.n_bins else 1.0
        if weight == 0:
            continue
        vu = np.unique(uv[layer == lay][:, ::-1], axis=0)
        count += weight * len(vu)
        if len(maps.rows[lay]) == 0:
            continue
        terms.append(_Term(vu, np.full(len(vu), weight), int(lay)))
    return terms, count


def _free_term(free: FreeFactor, maps: PlanMaps, pivot: F64, yaw: float) -> _Term:
    res = maps.coarse[0].resolution_m
    c = (free.xy - pivot) @ rot2(float(yaw)).T + pivot
    uv = np.round((c - maps.coarse[0].origin_xy) / res).astype(np.int64)
    vu, counts = np.unique(uv[:, ::-1], axis=0, return_counts=True)
    return _Term(vu, counts.astype(np.float64) / len(c), -1)


def search_peaks(
    p_xy: NDArray[np.float64],
    p_class: NDArray[np.int32],
    view_xy: NDArray[np.float64],
    maps: PlanMaps,
    pivot: NDArray[np.float64],
    yaws: NDArray[np.float64],
    xy_range_m: float,
    top_k: int,
    nms_xy_m: float,
    nms_yaw_rad: float,
    free: FreeFactor | None = None,
    block: int = 4,
    column_weight: float = 1.0,
    diverse_yaw_rad: float = np.deg2rad(10.0),
    min_score: float = 1e-6,
    stats: dict[str, float] | None = None,
) -> list[Hypothesis]:
    """The peaks :func:`top_hypotheses` picks from :func:`score_volume` (times the ``free``
    factor), found coarse-to-fine (Olson's multi-resolution correlative matching): for every
    yaw and every block of ``block`` x ``block`` translations, the template correlated with the
    score maps max-pooled over the block's reach (each point's window of ``2 block - 1``
    pixels) bounds the score of every translation in the block from above (and the free factor
    likewise). The fine score is then computed exactly (a sum over the template's pixels) in
    the blocks whose bound reaches a threshold ``tau``: every cell scoring ``>= tau`` is then
    known, and so is whether it is a local maximum (a neighbour not computed scores below
    ``tau``). The selection of :func:`top_hypotheses` runs on the peaks ``>= tau``; when both
    of its passes end before running out of them, the result is the exhaustive one (up to the
    float rounding of the sums); otherwise ``tau`` is lowered and more blocks are computed.

    Parameters as :func:`score_volume` and :func:`top_hypotheses`; ``free``: the optional
    multiplicative free-space factor; ``stats``: filled with ``blocks`` (total) and
    ``evaluated`` (blocks computed at full resolution).
    """
    res = maps.coarse[0].resolution_m
    n = round(xy_range_m / res)
    side = 2 * n + 1
    nb = -(-side // block)
    n_yaw = len(yaws)
    if len(p_xy) == 0 or n_yaw == 0:
        return []
    images = list(maps.coarse_score)
    pooled: dict[int, F32] = {}

    def pool(idx: int) -> F32:
        if idx not in pooled:
            pooled[idx] = _pool_max(free.image if idx < 0 and free is not None
                                    else images[idx], block)
        return pooled[idx]

    # Coarse bounds (Y, nb, nb).
    terms: list[list[_Term]] = []
    counts = np.zeros(n_yaw)
    bound = np.zeros((n_yaw, nb, nb), dtype=np.float64)
    for k, yaw in enumerate(yaws):
        t_k, c_k = _yaw_terms(p_xy, p_class, view_xy, maps, pivot, float(yaw), column_weight)
        counts[k] = c_k
        if free is not None:
            t_k.append(_free_term(free, maps, pivot, float(yaw)))
        terms.append(t_k)
        if c_k <= 0:
            continue
        total = np.zeros((nb, nb))
        for t in t_k:
            if t.image >= 0:
                total += _coarse_corr(t.vu, t.weight, pool(t.image), block, n, nb)
        total /= c_k
        if free is not None:
            total *= np.minimum(_coarse_corr(t_k[-1].vu, t_k[-1].weight, pool(-1), block, n,
                                             nb), 1.0)
        bound[k] = total
    bound += 1e-5 * (bound.max() + 1.0)  # float rounding of the correlations

    value = np.full((n_yaw, side, side), np.nan)  # exact scores, NaN where not computed
    done = np.zeros((n_yaw, nb, nb), dtype=bool)
    jj, ii = np.meshgrid(np.arange(block), np.arange(block), indexing="ij")
    in_block = np.c_[jj.ravel(), ii.ravel()]

    def evaluate(mask: NDArray[np.bool_]) -> None:
        for k in np.flatnonzero(mask.any((1, 2))):
            blocks = np.argwhere(mask[k])
            cells = (blocks[:, None, :] * block + in_block[None]).reshape(-1, 2)
            cells = cells[(cells < side).all(1)]
            score = np.zeros(len(cells))
            fac = np.ones(len(cells))
            for t in terms[k]:
                if t.image >= 0:
                    score += _exact_at(t.vu, t.weight, images[t.image], cells, n)
                else:
                    fac = _exact_at(t.vu, t.weight, free.image, cells, n)  # type: ignore[union-attr]
            score = score / counts[k] * fac if counts[k] > 0 else score * 0.0
            value[k, cells[:, 0], cells[:, 1]] = score
        done[mask] = True

    def wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.abs(np.arctan2(np.sin(a), np.cos(a)))

    # First threshold: each yaw's best blocks give a lower bound of its maximum.
    first = np.zeros_like(done)
    flat = bound.reshape(n_yaw, -1)
    top = np.argsort(-flat, axis=1)[:, :2]
    np.put_along_axis(first.reshape(n_yaw, -1), top, True, axis=1)
    evaluate(first)
    per_yaw = np.nanmax(value.reshape(n_yaw, -1), axis=1)
    order = np.argsort(-per_yaw, kind="stable")
    modes: list[int] = []
    for k in order:
        if not modes or wrap(yaws[modes] - yaws[k]).min() >= diverse_yaw_rad:
            modes.append(int(k))
    need = max(top_k // 2, 1)
    tau = float(per_yaw[modes[min(need, len(modes)) - 1]]) if modes else 0.0
    while True:
        tau = max(tau, min_score)
        evaluate((bound >= tau) & ~done)
        hyps = _select(value, yaws, res, n, top_k, nms_xy_m, nms_yaw_rad, diverse_yaw_rad,
                       min_score, tau)
        if hyps is not None:
            break
        tau = 0.8 * tau if tau > 0.05 else min_score
    if stats is not None:
        stats["blocks"] = float(done.size)
        stats["evaluated"] = float(done.sum())
    return hyps


def _select(value: F64, yaws: NDArray[np.float64], res: float, n: int, top_k: int,
            nms_xy_m: float, nms_yaw_rad: float, diverse_yaw_rad: float, min_score: float,
            tau: float) -> list[Hypothesis] | None:
    """:func:`top_hypotheses` on the computed cells of ``value`` (Y, S, S; NaN: not computed,
    then known to score below ``tau``); None when the selection would need a peak below
    ``tau`` (its list ran out before it was full) and ``tau > min_score`` (at ``min_score``
    every peak is known)."""
    n_yaw, side, _ = value.shape
    known = ~np.isnan(value)
    cand = np.argwhere(known & (value >= tau) & (value > min_score))
    complete = tau <= min_score
    if not len(cand):
        return [] if complete else None
    s = value[cand[:, 0], cand[:, 1], cand[:, 2]]
    # Local maxima over the 3 x 3 x 3 neighbourhood, indices clipped (``mode="nearest"``).
    is_peak = np.ones(len(cand), dtype=bool)
    for dk in (-1, 0, 1):
        for dj in (-1, 0, 1):
            for di in (-1, 0, 1):
                if not (dk or dj or di):
                    continue
                k2 = np.clip(cand[:, 0] + dk, 0, n_yaw - 1)
                j2 = np.clip(cand[:, 1] + dj, 0, side - 1)
                i2 = np.clip(cand[:, 2] + di, 0, side - 1)
                v2 = value[k2, j2, i2]
                # Not computed: below tau <= s (its block's bound is below tau).
                is_peak &= np.isnan(v2) | (s >= v2)
    cand, s = cand[is_peak], s[is_peak]
    order = np.lexsort((cand[:, 2], cand[:, 1], cand[:, 0], -s))
    cand, s = cand[order], s[order]
    yaw_all = yaws[cand[:, 0]]
    t_all = np.c_[(cand[:, 2] - n) * res, (cand[:, 1] - n) * res]

    def wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.abs(np.arctan2(np.sin(a), np.cos(a)))

    chosen: list[int] = []
    need = max(top_k // 2, 1)
    for o in range(len(s)):
        if len(chosen) >= need:
            break
        if not chosen or wrap(yaw_all[chosen] - yaw_all[o]).min() >= diverse_yaw_rad:
            chosen.append(o)
    if len(chosen) < need and not complete:
        return None
    for o in range(len(s)):
        if len(chosen) >= top_k:
            break
        if o in chosen:
            continue
        c = np.asarray(chosen, dtype=np.int64)
        same = ((wrap(yaw_all[c] - yaw_all[o]) < nms_yaw_rad)
                & (np.linalg.norm(t_all[c] - t_all[o], axis=1) < nms_xy_m))
        if not same.any():
            chosen.append(o)
    if len(chosen) < top_k and not complete:
        return None
    chosen.sort(key=lambda o: -s[o])
    return [Hypothesis(float(yaw_all[o]), t_all[o].copy(), float(s[o])) for o in chosen]
