"""The global alignment's pruned steps give what the exhaustive ones give (issue 15, speed):
the peak search among the best cells only against a maximum filter of the whole volume, the lazy
free-space order against a full sort, and the culled ray / distance tests against every
segment. The steps rewritten for speed give the bits of the code they replace (kept here as
the oracles): the occupancy subsample, the free-space rays, the parity rays and face pairs of
the plan maps, and the correlation volume."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.ndimage import maximum_filter

from bimcap.registration._coarse_steps import _subsample
from bimcap.registration.correlative import Hypothesis, score_volume, top_hypotheses
from bimcap.registration.global_align import (
    GlobalAlignOptions,
    _by_key,
    _distance_within,
    _free_volume,
    _scan,
    _storey_maps,
    _storeys,
    free_space_fraction,
    see_through_fraction,
)
from bimcap.registration.icp import point_segment_distance, rot2
from bimcap.registration.plan_maps import _crossings_many, _paired_face_normals
from bimcap.registration.synthetic import demo_scene, demo_tour, poses_along, scan_sequence

pytest.importorskip("cv2")


def _exhaustive(volume: np.ndarray, yaws: np.ndarray, res: float, n: int, top_k: int,
                nms_xy_m: float, nms_yaw_rad: float) -> list[Hypothesis]:
    """The selection of top_hypotheses on every local maximum of the whole volume (the code
    before the pruning, kept here as the oracle)."""
    peak = (volume >= maximum_filter(volume, size=(3, 3, 3), mode="nearest")) & (volume > 1e-6)
    k, j, i = np.nonzero(peak)
    s = volume[k, j, i]
    order = np.argsort(-s, kind="stable")
    yaw_all, s_all = yaws[k[order]], s[order]
    t_all = np.c_[(i[order] - n) * res, (j[order] - n) * res]

    def wrap(a: np.ndarray) -> np.ndarray:
        return np.abs(np.arctan2(np.sin(a), np.cos(a)))

    chosen: list[int] = []
    for o in range(len(order)):
        if len(chosen) >= max(top_k // 2, 1):
            break
        if not chosen or wrap(yaw_all[chosen] - yaw_all[o]).min() >= np.deg2rad(10.0):
            chosen.append(o)
    for o in range(len(order)):
        if len(chosen) >= top_k:
            break
        if o in chosen:
            continue
        c = np.asarray(chosen)
        same = ((wrap(yaw_all[c] - yaw_all[o]) < nms_yaw_rad)
                & (np.linalg.norm(t_all[c] - t_all[o], axis=1) < nms_xy_m))
        if not same.any():
            chosen.append(o)
    chosen.sort(key=lambda o: -s_all[o])
    return [Hypothesis(float(yaw_all[o]), t_all[o], float(s_all[o])) for o in chosen]


def _demo_walk(first: int, stop: int) -> tuple[Any, Any]:
    """Frames ``first:stop`` of the demo plan's walk (0.25 m apart) ray-cast with 5 % clutter:
    its scan (``_scan``) and the maps of the plan's only storey (``_storey_maps``), default
    options."""
    scene = demo_scene(seed=0)
    gt = poses_along(demo_tour(seed=0), 0.25)[first:stop]
    samples = scan_sequence(gt, scene, seed=1, clutter_fraction=0.05)
    plan = scene.floor_plan()
    opt = GlobalAlignOptions()
    sm = _storey_maps(_storeys(plan, opt.plan_cut_height_m)[0], plan, opt)
    return _scan(gt, samples), sm


@pytest.fixture(scope="module")
def demo_volume() -> tuple[np.ndarray, np.ndarray, float, int]:
    """The global search's volume (score x free share) of a 60-frame walk on the demo plan, in
    the BIM frame (the walk's true placement is the translation 0, yaw 0)."""
    scan, sm = _demo_walk(224, 284)
    yaws = np.arange(-np.pi, np.pi, np.deg2rad(GlobalAlignOptions().yaw_step_deg))
    pivot = scan.cams[:, :2].mean(0)
    vol, res, n = score_volume(scan.xy, scan.cls, scan.view, sm.maps, pivot, yaws, 4.0)
    vol *= _free_volume(scan.cams[:, :2], sm.free_map, sm.maps.coarse[0].origin_xy, res,
                        pivot, yaws, n)
    return vol, yaws, res, n


@pytest.mark.parametrize("first_cells", [1, 50, 1 << 14, 10 ** 9])
@pytest.mark.parametrize("top_k", [1, 10, 30])
def test_peaks_among_the_best_cells_are_those_of_the_whole_volume(demo_volume, first_cells: int,
                                                                  top_k: int) -> None:
    vol, yaws, res, n = demo_volume
    want = _exhaustive(vol, yaws, res, n, top_k, 1.0, np.deg2rad(10.0))
    got = top_hypotheses(vol, yaws, res, n, top_k, 1.0, np.deg2rad(10.0),
                         first_cells=first_cells)
    assert len(got) == len(want) == top_k
    for a, b in zip(got, want, strict=True):
        assert (a.yaw, a.score) == (b.yaw, b.score)
        np.testing.assert_array_equal(a.t, b.t)
    # The best is the truth: the walk sits where it was scanned.
    assert abs(got[0].yaw) < 1e-9 and np.abs(got[0].t).max() <= 2 * res
    if top_k > 1:  # the search had to widen: the first pass's yaw modes lie far down
        assert (vol >= got[-1].score).sum() > 50


def test_peaks_on_plateaus_and_few_peaks() -> None:
    rng = np.random.default_rng(3)
    yaws = np.arange(-np.pi, np.pi, np.deg2rad(2.0))
    for trial in range(6):
        vol = (np.round(rng.random((len(yaws), 21, 21)) * 8) / 8).astype(np.float32)
        if trial % 2:
            vol[:] = 0.0
            vol[rng.integers(0, len(yaws), 7), rng.integers(0, 21, 7), rng.integers(0, 21, 7)] = 1
        for top_k in (1, 6, 30):
            want = _exhaustive(vol, yaws, 0.2, 10, top_k, 1.0, np.deg2rad(10.0))
            got = top_hypotheses(vol, yaws, 0.2, 10, top_k, 1.0, np.deg2rad(10.0), first_cells=8)
            assert [(h.yaw, h.score, *h.t) for h in got] == [(h.yaw, h.score, *h.t) for h in want]


def _lazy_head(bound: np.ndarray, share: np.ndarray, head: int) -> tuple[list[int], int]:
    """The first ``head`` items of the lazy order, and how many items it completed."""
    computed: list[int] = []

    def complete(i: int) -> int:
        computed.append(i)
        return i

    got = []
    for i in _by_key(list(range(len(bound))), lambda i: float(bound[i]), complete,
                     lambda i: float(bound[i] * share[i])):
        got.append(i)
        if len(got) == head:
            break
    return got, len(computed)


def test_lazy_order_is_the_sorted_order() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        bound = np.round(rng.random(30), 1)  # ties
        share = np.round(rng.random(30), 1)
        want = sorted(range(30), key=lambda i, b=bound, s=share: -b[i] * s[i])
        got, computed = _lazy_head(bound, share, 4)
        assert got == want[:4]
        assert computed < 30  # only what came up


def test_culled_ray_and_distance_tests_equal_the_full_ones() -> None:
    rng = np.random.default_rng(1)
    seg = rng.uniform(0, 30, (300, 4))
    seg[::3, 2] = seg[::3, 0]  # axis-parallel segments: boxes of zero width
    seg[1::3, 3] = seg[1::3, 1]
    cam = np.repeat(rng.uniform(0, 30, (40, 2)), 60, axis=0)
    pts = cam + rng.normal(0, 4, cam.shape)
    frac, crossed = see_through_fraction(cam, pts, seg, 0.3)
    # Brute force: every ray (without its first and last 0.3 m) against every segment.
    ray = pts - cam
    length = np.linalg.norm(ray, axis=1)
    want = np.zeros(len(pts), dtype=bool)
    for m in np.flatnonzero(length > 0.6):
        u = ray[m] / length[m]
        a, d = cam[m] + 0.3 * u, ray[m] - 0.6 * u
        for x1, y1, x2, y2 in seg:
            e = np.array([x2 - x1, y2 - y1])
            den = d[0] * e[1] - d[1] * e[0]
            if abs(den) <= 1e-12:
                continue
            w = np.array([x1, y1]) - a
            s = (w[0] * e[1] - w[1] * e[0]) / den
            t = (w[0] * d[1] - w[1] * d[0]) / den
            if 0 <= s <= 1 and 0 <= t <= 1:
                want[m] = True
                break
    np.testing.assert_array_equal(crossed, want)
    assert 0.1 < frac < 0.9
    full = point_segment_distance(pts, seg)[0]
    part = _distance_within(pts, seg, 0.17)
    np.testing.assert_array_equal(part[full <= 0.17], full[full <= 0.17])
    assert (part[full > 0.17] > 0.17).all() and (full <= 0.17).sum() > 20


# ------------------------------------------------------------------------------------------------
# Rewritten for speed, same bits: the code before the rewrite is the oracle.


def _subsample_before(p_xy: np.ndarray, p_class: np.ndarray, cell: float | None, cap: int,
                      rng: np.random.Generator) -> np.ndarray:
    keep = np.arange(len(p_xy))
    if len(p_xy) and cell is not None:
        key = np.c_[np.floor(p_xy / cell).astype(np.int64), p_class.astype(np.int64)]
        _, keep = np.unique(key, axis=0, return_index=True)
        keep = np.sort(keep)
    if len(keep) > cap:
        keep = np.sort(rng.choice(keep, cap, replace=False))
    return keep


@pytest.mark.parametrize("cap", [10 ** 9, 300])
def test_subsample_keeps_the_same_points(cap: int) -> None:
    rng = np.random.default_rng(3)
    p = rng.normal(0, 5, (5000, 2)) - 40.0  # negative cells; many points per cell
    cls = rng.choice([1, 4], len(p)).astype(np.int32)
    got = _subsample(p, cls, 0.1, cap, np.random.default_rng(7))
    want = _subsample_before(p, cls, 0.1, cap, np.random.default_rng(7))
    np.testing.assert_array_equal(got, want)
    assert 300 <= len(got) < len(p)
    one = _subsample(p, np.full(len(p), 1, np.int32), 0.1, cap, np.random.default_rng(7))
    np.testing.assert_array_equal(one, _subsample_before(
        p, np.full(len(p), 1, np.int32), 0.1, cap, np.random.default_rng(7)))


def _segments_with_degenerates(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    seg = rng.uniform(0, 20, (n, 4))
    seg[::5, 2] = seg[::5, 0]  # vertical, horizontal, zero length: den 0 for some rays
    seg[1::5, 3] = seg[1::5, 1]
    seg[2::5, 2:] = seg[2::5, :2]
    return seg


def test_free_space_rays_give_the_same_flags() -> None:
    rng = np.random.default_rng(4)
    seg = _segments_with_degenerates(rng)
    cam = rng.uniform(-5, 25, (80, 2))
    for n_rays, hits_min in ((16, 10), (8, 7), (4, 2)):
        frac, free = free_space_fraction(cam, seg, clearance_m=0.15, n_rays=n_rays,
                                         min_hits=hits_min)
        # Before: every ray direction against every segment, the masked division included.
        from bimcap.registration.distance_field import DistanceField
        clear = DistanceField.from_segments(seg, 0.1).lookup(cam) >= 0.15
        a, e = seg[:, :2], seg[:, 2:] - seg[:, :2]
        hits = np.zeros(len(cam), dtype=np.int64)
        for k in range(n_rays):
            ang = 2 * np.pi * (k + 0.5) / n_rays
            d = np.array([np.cos(ang), np.sin(ang)])
            den = d[0] * e[:, 1] - d[1] * e[:, 0]
            w = a[None] - cam[:, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                s = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den[None]
                u = (w[..., 0] * d[1] - w[..., 1] * d[0]) / den[None]
            hit = ((np.abs(den)[None] > 1e-12) & (s > 0) & (s < 60.0) & (u >= 0) & (u <= 1))
            hits += hit.any(1)
        want = clear & (hits >= hits_min)
        np.testing.assert_array_equal(free, want)
        assert frac == float(want.mean()) and 0 < want.sum() < len(cam)


@pytest.mark.parametrize("chunk", [1, 7, 64, 10 ** 6])
def test_parity_rays_count_the_same_crossings(chunk: int) -> None:
    rng = np.random.default_rng(5)
    seg = _segments_with_degenerates(rng)
    # Points anywhere, and on the segments' own ends and middles (rays that start on a
    # segment or graze its end: the culling's margins must keep those).
    p = np.r_[rng.uniform(0, 20, (300, 2)), seg[:, :2], 0.5 * (seg[:, :2] + seg[:, 2:])]
    dirs = (np.array([0.8944, 0.4472]), np.array([-0.3162, 0.9487]), np.array([1.0, 0.0]))
    got = _crossings_many(p, dirs, seg, chunk=chunk)
    for d, g in zip(dirs, got, strict=True):
        a, e = seg[:, :2], seg[:, 2:] - seg[:, :2]
        den = d[0] * e[:, 1] - d[1] * e[:, 0]
        w = a[None] - p[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den[None]
            u = (w[..., 0] * d[1] - w[..., 1] * d[0]) / den[None]
        want = ((np.abs(den)[None] > 1e-12) & (s > 0) & (u >= 0) & (u < 1)).sum(1)
        np.testing.assert_array_equal(g, want)
        assert want.max() > 2


def _paired_before(s: np.ndarray, min_gap_m: float, max_gap_m: float, max_angle_deg: float,
                   chunk: int) -> np.ndarray:
    a, b = s[:, :2], s[:, 2:]
    length = np.linalg.norm(b - a, axis=1)
    u = (b - a) / np.maximum(length, 1e-12)[:, None]
    n = np.c_[-u[:, 1], u[:, 0]]
    mid = 0.5 * (a + b)
    cos_max = np.cos(np.radians(max_angle_deg))
    out = np.zeros((len(s), 2))
    for k in range(0, len(s), chunk):
        r = slice(k, min(k + chunk, len(s)))
        a0, u0, n0 = a[r, None, :], u[r, None, :], n[r, None, :]
        off = ((mid[None] - a0) * n0).sum(-1)
        ta, tb = ((a[None] - a0) * u0).sum(-1), ((b[None] - a0) * u0).sum(-1)
        overlap = (np.minimum(np.maximum(ta, tb), length[r, None])
                   - np.maximum(np.minimum(ta, tb), 0.0))
        partner = ((np.abs(u[r] @ u.T) >= cos_max) & (np.abs(off) >= min_gap_m)
                   & (np.abs(off) <= max_gap_m) & (overlap > 0.05) & (length[r, None] > 1e-9))
        partner[np.arange(r.stop - r.start), np.arange(r.start, r.stop)] = False
        plus, minus = (partner & (off > 0)).any(1), (partner & (off < 0)).any(1)
        out[r][plus & ~minus] = -n[r][plus & ~minus]
        out[r][minus & ~plus] = n[r][minus & ~plus]
    return out


@pytest.mark.parametrize("chunk", [7, 512])
def test_face_pairs_give_the_same_normals(chunk: int) -> None:
    rng = np.random.default_rng(6)
    walls = []
    for _ in range(120):  # walls of two faces 0.1-0.3 m apart, some turned by a few degrees
        a = rng.uniform(0, 30, 2)
        ang = rng.choice([0.0, np.pi / 2]) + rng.normal(0, 0.03)
        d = np.array([np.cos(ang), np.sin(ang)]) * rng.uniform(0.5, 5)
        nrm = np.array([-d[1], d[0]]) / np.linalg.norm(d) * rng.uniform(0.1, 0.3)
        walls += [np.r_[a, a + d], np.r_[a + nrm + 0.1 * d, a + nrm + 1.2 * d]]
    seg = np.array([*walls, np.r_[1.0, 1.0, 1.0, 1.0]])  # and a zero-length one
    got = _paired_face_normals(seg, 0.02, 0.6, 3.0, chunk)
    want = _paired_before(seg, 0.02, 0.6, 3.0, chunk)
    np.testing.assert_array_equal(got, want)
    assert 0.3 < (np.abs(got).sum(1) > 0).mean() < 1.0


def _score_volume_before(p_xy, p_class, view_xy, maps, pivot, yaws, xy_range_m):
    import cv2

    res, origin = maps.coarse[0].resolution_m, maps.coarse[0].origin_xy
    n = round(xy_range_m / res)
    vol = np.zeros((len(yaws), 2 * n + 1, 2 * n + 1), dtype=np.float32)
    for k, yaw in enumerate(yaws):
        r = rot2(float(yaw))
        q = (p_xy - pivot) @ r.T + pivot
        layer = maps.layer_of(p_class, view_xy @ r.T)
        uv = np.round((q - origin) / res).astype(np.int64)
        total = np.zeros((2 * n + 1, 2 * n + 1), dtype=np.float32)
        count = 0.0
        for lay in np.unique(layer):
            luv = uv[layer == lay]
            u0, v0 = luv.min(0)
            u1, v1 = luv.max(0)
            templ = np.zeros((v1 - v0 + 1, u1 - u0 + 1), dtype=np.float32)
            templ[luv[:, 1] - v0, luv[:, 0] - u0] = 1.0
            count += float(templ.sum())
            if len(maps.rows[lay]) == 0:
                continue
            img = np.zeros((v1 - v0 + 2 * n + 1, u1 - u0 + 2 * n + 1), dtype=np.float32)
            src = maps.coarse_score[lay]
            h, w = src.shape
            r0, c0 = v0 - n, u0 - n
            rr0, rr1 = max(r0, 0), min(v1 + n + 1, h)
            cc0, cc1 = max(c0, 0), min(u1 + n + 1, w)
            img[rr0 - r0:rr1 - r0, cc0 - c0:cc1 - c0] = src[rr0:rr1, cc0:cc1]
            total += 1.0 * cv2.matchTemplate(img, templ, cv2.TM_CCORR)
        if count > 0:
            vol[k] = total / count
    return vol


@pytest.mark.parametrize("xy_range_m", [1.0, 12.0])
def test_score_volume_has_the_bits_of_the_copying_loop(xy_range_m: float) -> None:
    """Crops inside the map are views now (``1.0``: inside; ``12.0``: past its edges)."""
    scan, sm = _demo_walk(224, 254)
    yaws = np.deg2rad(np.arange(-180.0, 180.0, 15.0))
    pivot = scan.cams[:, :2].mean(0)
    got, _, _ = score_volume(scan.xy, scan.cls, scan.view, sm.maps, pivot, yaws, xy_range_m)
    want = _score_volume_before(scan.xy, scan.cls, scan.view, sm.maps, pivot, yaws, xy_range_m)
    np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))
    assert got.max() > 0.3


def test_a_search_grid_as_long_as_the_box_is_the_square_grids_middle_rows() -> None:
    """The global search's translations cover the storey's box and 1 m around it along each
    axis, not the square of its longer side (``score_volume(..., y_range_m=)``,
    ``_free_volume(..., m)``): the rectangular volume holds the square one's middle rows (the
    same correlation of a smaller crop: equal to float rounding), and ``_storey_maps`` gives
    each axis its own half-width."""
    scan, sm = _demo_walk(224, 254)
    lo_x, lo_y, hi_x, hi_y = sm.bounds
    assert sm.half == pytest.approx(0.5 * (hi_x - lo_x) + 1.0)
    assert sm.half_y == pytest.approx(0.5 * (hi_y - lo_y) + 1.0)
    assert sm.half_y < sm.half  # the demo plan is longer than it is deep
    yaws = np.deg2rad(np.arange(-180.0, 180.0, 15.0))
    pivot = scan.cams[:, :2].mean(0)
    square, res, n = score_volume(scan.xy, scan.cls, scan.view, sm.maps, pivot, yaws, 6.0)
    rect, res_r, n_r = score_volume(scan.xy, scan.cls, scan.view, sm.maps, pivot, yaws, 6.0,
                                    y_range_m=2.0)
    m = round(2.0 / res)
    assert (res_r, n_r) == (res, n) and rect.shape == (len(yaws), 2 * m + 1, 2 * n + 1)
    np.testing.assert_allclose(rect, square[:, n - m:n + m + 1], rtol=0, atol=1e-6)
    free_sq = _free_volume(scan.cams[:, :2], sm.free_map, sm.maps.coarse[0].origin_xy, res,
                           pivot, yaws, n)
    free_r = _free_volume(scan.cams[:, :2], sm.free_map, sm.maps.coarse[0].origin_xy, res,
                          pivot, yaws, n, m)
    np.testing.assert_allclose(free_r, free_sq[:, n - m:n + m + 1], rtol=0, atol=1e-6)
    assert rect.max() > 0.3 and free_r.max() > 0.5


@pytest.mark.parametrize("top_k", [1, 10, 30])
def test_peaks_of_a_rectangular_volume_are_placed_by_its_own_rows(demo_volume, top_k: int
                                                                    ) -> None:
    """``top_hypotheses`` reads the y half-width of a rectangular volume from its shape: its
    peaks are those of the square volume with the rows outside it zeroed (at its edge a cell's
    missing neighbour counts as itself, as a zero neighbour does for a score >= 0)."""
    vol, yaws, res, n = demo_volume
    m = n // 2
    rect = np.ascontiguousarray(vol[:, n - m:n + m + 1])
    zeroed = np.zeros_like(vol)
    zeroed[:, n - m:n + m + 1] = rect
    want = top_hypotheses(zeroed, yaws, res, n, top_k, 1.0, np.deg2rad(10.0))
    got = top_hypotheses(rect, yaws, res, n, top_k, 1.0, np.deg2rad(10.0))
    assert len(got) == len(want) == top_k
    for a, b in zip(got, want, strict=True):
        assert (a.yaw, a.score) == (b.yaw, b.score)
        np.testing.assert_array_equal(a.t, b.t)


def test_mth_largest_is_the_full_partitions() -> None:
    from bimcap.registration.correlative import _mth_largest

    rng = np.random.default_rng(8)
    for trial in range(200):
        a = rng.random(int(rng.integers(1, 4000))).astype(np.float32)
        if trial % 3 == 0:
            a = np.round(a * 4).astype(np.float32)  # many ties
        for m in {1, 2, int(rng.integers(1, a.size + 1)), a.size}:
            for every in (0, 1, 2, 7, 50):
                want = float(np.partition(a, a.size - m)[a.size - m])
                assert _mth_largest(a, m, every) == want


def test_score_map_has_the_bits_of_the_full_exponential() -> None:
    from bimcap.registration.distance_field import DistanceField

    seg = demo_scene(seed=0).floor_plan().segments
    for res, sigma in ((0.2, 0.3), (0.05, 0.1)):
        field_ = DistanceField.from_segments(seg, res, None, 3.0)
        d = field_.distance_m.astype(np.float64)
        want = np.exp(-0.5 * (d / sigma) ** 2)
        want[d > 3.0 * sigma] = 0.0
        got = field_.score_map(sigma, 3.0)
        assert got.tobytes() == want.astype(np.float32).tobytes()
        assert 0 < (got > 0).mean() < 1


def test_stacked_fine_maps_have_the_bits_of_the_per_layer_fields() -> None:
    """The stacked look-ups (one flat index per corner, int32 nearest rows) against each
    layer's own :class:`DistanceField` (the loops used when the layers' grids differ)."""
    from bimcap.registration.plan_maps import _Stack

    scan, sm = _demo_walk(224, 284)
    maps = sm.maps
    assert isinstance(maps._stack(), _Stack)
    rng = np.random.default_rng(9)
    lo, hi = np.array(sm.bounds[:2]) - 4.0, np.array(sm.bounds[2:]) + 4.0  # some outside
    q = np.r_[scan.xy, rng.uniform(lo, hi, (3000, 2))]
    layer = maps.layer_of(np.r_[scan.cls, np.full(3000, scan.cls[0])],
                          rng.normal(size=(len(q), 2)))
    got = (maps.fine_score_at(q, layer), *maps.fine_eval(q, layer), *maps.nearest(q, layer))
    maps.__dict__["_stacked"] = None  # the per-layer loops
    want = (maps.fine_score_at(q, layer), *maps.fine_eval(q, layer), *maps.nearest(q, layer))
    for g, w in zip(got, want, strict=True):
        assert g.tobytes() == w.tobytes()
    assert (want[0] > 0).mean() > 0.3 and np.isfinite(want[3]).mean() > 0.9


@pytest.mark.parametrize("radius_end_m", [0.12, 0.05])
def test_icp_in_lock_step_has_the_bits_of_one_run_per_init(radius_end_m: float) -> None:
    from bimcap.registration.icp import Correction2D, icp_2d, icp_2d_many

    scan, sm = _demo_walk(224, 284)
    maps = sm.maps
    keep = np.linspace(0, len(scan.xy) - 1, 1500).astype(np.int64)
    xy, cls, view = scan.xy[keep], scan.cls[keep], scan.view[keep]

    def associate(q: np.ndarray, q_class: np.ndarray, v: np.ndarray) -> Any:
        return maps.nearest(q, maps.layer_of(q_class, v))

    rng = np.random.default_rng(10)
    pivot = scan.cams[:, :2].mean(0)
    # Near the truth (converge early), a little off (run every radius), far off (too few
    # pairs: stop at once).
    inits = ([Correction2D(rng.normal(0, 0.03), rng.normal(0, 0.2, 2), pivot) for _ in range(6)]
             + [Correction2D(rng.uniform(-3, 3), rng.uniform(-8, 8, 2), pivot) for _ in range(6)]
             + [Correction2D(0.0, np.array([500.0, 0.0]), pivot)])
    got = icp_2d_many(xy, cls, associate, inits, view, 0.8, radius_end_m, 15, 0.05, 0.15)
    want = [icp_2d(xy, cls, associate, f, view, 0.8, radius_end_m, 15, 0.05, 0.15)
            for f in inits]
    assert len({w.iterations for w in want}) >= 2  # runs that stop at different iterations
    for g, w in zip(got, want, strict=True):
        assert g.correction.yaw == w.correction.yaw
        assert g.correction.t.tobytes() == w.correction.t.tobytes()
        assert g.iterations == w.iterations and g.inlier_ratio == w.inlier_ratio
        assert np.array_equal([g.rms_m, g.constraint], [w.rms_m, w.constraint], equal_nan=True)
    assert icp_2d_many(xy, cls, associate, [], view) == []


def test_distance_to_segments_has_the_bits_of_the_row_wise_code() -> None:
    from bimcap.registration.distance_field import distance_to_segments

    rng = np.random.default_rng(11)
    seg = _segments_with_degenerates(rng)
    idx = rng.integers(0, len(seg), 5000)
    p = rng.uniform(-5, 25, (5000, 2))
    p[::7] = seg[idx[::7], :2]  # on a segment's end
    p[1::7] = 0.5 * (seg[idx[1::7], :2] + seg[idx[1::7], 2:])  # on its middle
    a, b = seg[idx, :2], seg[idx, 2:]
    ab = b - a
    u = np.clip(((p - a) * ab).sum(1) / np.maximum((ab ** 2).sum(1), 1e-18), 0.0, 1.0)
    c = a + u[:, None] * ab
    dist, closest = distance_to_segments(p, seg, idx)
    assert dist.tobytes() == np.linalg.norm(p - c, axis=1).tobytes()
    assert closest.tobytes() == c.tobytes()
    assert (dist == 0).sum() > 100 and dist.max() > 1

