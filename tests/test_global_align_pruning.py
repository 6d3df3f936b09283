"""The global alignment's pruned steps give what the exhaustive ones give (issue 15, speed):
the peak search among the best cells only against a maximum filter of the whole volume, the lazy
free-space order against a full sort, and the culled ray / distance tests against every
segment."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import maximum_filter

from bimcap.registration.correlative import Hypothesis, score_volume, top_hypotheses
from bimcap.registration.global_align import (
    GlobalAlignOptions,
    _by_key,
    _distance_within,
    _free_volume,
    _scan,
    _storey_maps,
    _storeys,
    see_through_fraction,
)
from bimcap.registration.icp import point_segment_distance
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


@pytest.fixture(scope="module")
def demo_volume() -> tuple[np.ndarray, np.ndarray, float, int]:
    """The global search's volume (score x free share) of a 60-frame walk on the demo plan, in
    the BIM frame (the walk's true placement is the translation 0, yaw 0)."""
    scene = demo_scene(seed=0)
    gt = poses_along(demo_tour(seed=0), 0.25)[224:284]
    samples = scan_sequence(gt, scene, seed=1, clutter_fraction=0.05)
    plan = scene.floor_plan()
    opt = GlobalAlignOptions()
    storey = _storeys(plan, opt.plan_cut_height_m)[0]
    sm = _storey_maps(storey, plan, opt)
    scan = _scan(gt, samples)
    yaws = np.arange(-np.pi, np.pi, np.deg2rad(opt.yaw_step_deg))
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
