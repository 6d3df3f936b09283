"""Front-end benchmark: per-stage CPU ms a frame on a generated world; SIFT and matching.

Times are process CPU seconds of single-threaded calls (BLAS, OpenCV and pycolmap on one thread,
and glibc's freed heap kept between frames, as inside the front end's jobs:
``bimcap.frontend.runner.job_settings``): on a machine
shared with other work, wall time also counts the time other processes held the core.

World part (``--world SEQ_DIR``): every stage of the front end as ``bimcap refine`` runs it
(``make_providers`` of ``RefineConfig()``: LiDAR projection, linear completion, geometric
segmentation, planar smoothing; SIFT, keypoint depths, the label orientation check, semantic
sampling, scan surface points; per pair matching and verification over ``--window`` frames),
frame by frame on the sequence's first ``--frames`` frames, with ms a frame per stage, frames/s
per core next to the goal (10 at 516×386, 3 at 1032×772), and, for each stage with a previous
implementation kept in ``tests/_frontend_reference.py``, that implementation's time on the
same inputs in the same process (the ratio) and a check that both give the same arrays bit for bit.
Two frames and one pair run first, untimed: what a worker process pays once (imports of OpenCV,
pycolmap and ONNX Runtime, first calls) is printed apart instead of spread over the frames.

    PYTHONPATH=python python bench/bench_frontend.py --world /tmp/gen/gen-demo-s0/seq_60_standard

Against another checkout (``--world SEQ_DIR --against TREE [--repeat N]``): the same per-stage
run of this script on this checkout's code and on TREE's (a checkout of another commit whose
``python/bimcap`` holds its built ``_core``, e.g. a ``git worktree``), alternating N times, each
stage's least ms a frame of each, and the ratio: the VM's speed swings by ±15 % within minutes,
which the least of alternating runs absorbs.

    PYTHONPATH=python python bench/bench_frontend.py --world /tmp/gen/gen-demo-s0/seq_60_standard \
        --frames 40 --against /tmp/base --repeat 4

Backends part (``--world SEQ_DIR --backends pycolmap,orb``): the features stages alone
(extraction, matching, verification) of each ``[features] backend`` on the same frames in the
same process, with keypoints and verified matches a pair.

Features part: per frame undistortion + SIFT (pycolmap, and OpenCV as the fallback), per pair
descriptor matching (numpy, and pycolmap's brute force with ``--pycolmap-matcher``) and geometric
verification, on frames ray-cast from the test room (tests/_frontend_scene.py), with accuracy
against the ground truth: the world distance between the two back-projections of each verified
match under the true poses. Prints a table; never collected by pytest.

    PYTHONPATH=python python bench/bench_frontend.py [--frames 6] [--window 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

if "--prepare" not in sys.argv:  # --prepare measures the library as it sets its threads itself
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))


def _camera():
    from bimcap.geometry.camera import Camera

    conslam = Camera(
        2064, 1544, 2351.85909, 2353.56734, 1017.24032, 788.70774,
        (-0.054366, 0.118389, 0.001781, -0.003908, 0.0),
    )
    return conslam.scaled(0.5)


def _timed(fn, *args, repeat: int = 1, **kwargs):
    """Result and the best process CPU time of ``repeat`` calls.

    Everything runs on one thread, so CPU time is the single-core cost even on a loaded machine
    (wall time there also counts the time other processes held the core).
    """
    best = np.inf
    out = None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn(*args, **kwargs)
        best = min(best, time.process_time() - t0)
    return out, best


def bench_features(frames: int, window: int, pycolmap_matcher: bool) -> list[tuple[str, str, str]]:
    """Rows ``(step, time per frame or pair, accuracy / count)``."""
    from _frontend_scene import SceneSequence, default_poses
    from bimcap.features import (
        MatcherBackend,
        MatchOptions,
        SiftBackend,
        SiftOptions,
        Verification,
        extract_sift,
        lookup_depth,
        match_descriptors,
        sequential_pairs,
        verify_matches,
    )
    from bimcap.frontend.runner import Undistorter
    from bimcap.geometry.poses import transform_points

    cam = _camera()
    pin = cam.pinhole()
    rows: list[tuple[str, str, str]] = []
    with tempfile.TemporaryDirectory() as tmp:
        seq = SceneSequence.write(Path(tmp), camera=cam, poses=default_poses(frames))
        raw = [seq.load_image(i) for i in range(frames)]
        und = Undistorter(cam)
        depth = [und.nearest(seq.load_depth(i)) for i in range(frames)]
        imgs = []
        t_und = []
        for r in raw:
            im, t = _timed(und.image, r, repeat=3)
            imgs.append(im)
            t_und.append(t)
        rows.append(("undistort image (remap)", f"{1e3 * np.mean(t_und):.1f} ms/frame", ""))

        feats = {}
        variants = [
            ("pycolmap", SiftOptions()),
            ("pycolmap first_octave -1 (COLMAP)", SiftOptions(first_octave=-1)),
            ("opencv", SiftOptions(backend=SiftBackend.OPENCV)),
        ]
        for name, opts in variants:
            res = [_timed(extract_sift, im, opts) for im in imgs]
            feats[name] = [f for f, _ in res]
            n = np.mean([len(f) for f, _ in res])
            rows.append(
                (f"SIFT {name} (max {opts.max_num_features})",
                 f"{1e3 * np.mean([t for _, t in res]):.0f} ms/frame", f"{n:.0f} keypoints")
            )

        f = feats["pycolmap"]
        kp_depth = [lookup_depth(d, ff.uv) for d, ff in zip(depth, f, strict=True)]
        pairs = sequential_pairs(frames, window)
        t_match, t_ver, t_fund, errs, n_put, n_inl = [], [], [], [], [], []
        for a, b in pairs:
            m, t = _timed(match_descriptors, f[a].descriptors, f[b].descriptors)
            t_match.append(t)
            n_put.append(len(m))
            (inl, _), t = _timed(verify_matches, f[a].uv, f[b].uv, m, pin)
            t_ver.append(t)
            n_inl.append(len(inl))
            _, t = _timed(
                verify_matches, f[a].uv, f[b].uv, m, pin,
                MatchOptions(verification=Verification.FUNDAMENTAL),
            )
            t_fund.append(t)
            da, db = kp_depth[a][inl[:, 0]], kp_depth[b][inl[:, 1]]
            ok = (da > 0) & (db > 0)
            pa = transform_points(seq.gt[a],
                                  pin.backproject(f[a].uv[inl[ok, 0]], da[ok], distorted=False))
            pb = transform_points(seq.gt[b],
                                  pin.backproject(f[b].uv[inl[ok, 1]], db[ok], distorted=False))
            errs.append(np.linalg.norm(pa - pb, axis=1))
        e = np.concatenate(errs)
        per_frame = window  # pairs per frame in steady state (fewer at the sequence's end)
        rows.append(
            ("match descriptors (numpy)", f"{1e3 * np.mean(t_match):.0f} ms/pair",
             f"{np.mean(n_put):.0f} putative")
        )
        rows.append(
            ("verify (two-view E/F/H)", f"{1e3 * np.mean(t_ver):.0f} ms/pair",
             f"{np.mean(n_inl):.0f} inliers ({100 * np.sum(n_inl) / np.sum(n_put):.1f} %)")
        )
        rows.append(("verify (fundamental only)", f"{1e3 * np.mean(t_fund):.0f} ms/pair", ""))
        rows.append(
            ("keypoints with valid depth", "",
             f"{100 * np.mean([np.mean(d > 0) for d in kp_depth]):.1f} %")
        )
        rows.append(
            ("match error vs GT (median / p95)", "",
             f"{100 * np.median(e):.2f} / {100 * np.percentile(e, 95):.2f} cm")
        )
        sift_t = float(rows[1][1].split()[0]) / 1e3
        pair_t = np.mean(t_match) + np.mean(t_ver)
        rows.append(
            (f"SIFT + matching, window {window}",
             f"{1e3 * (sift_t + per_frame * pair_t):.0f} ms/frame",
             f"{1.0 / (sift_t + per_frame * pair_t):.2f} frames/s/core")
        )
        from bimcap.frontend import (
            FrontendConfig,
            GroundTruthDepthProvider,
            GroundTruthLabelProvider,
            run_frontend,
        )

        res, t = _timed(
            run_frontend, seq, FrontendConfig(window=window), seq.gt, GroundTruthDepthProvider(),
            GroundTruthLabelProvider(), workers=1, progress=False,
        )
        rows.append(
            (f"run_frontend, GT depth/labels, window {window}", f"{1e3 * t / frames:.0f} ms/frame",
             f"{len(res.match_frames)} matches, {len(res.track_points)} tracks, "
             f"{sum(len(res.semantic_samples()[k][0]) for k in res.semantic_samples())} samples")
        )
        if pycolmap_matcher:
            opts = MatchOptions(backend=MatcherBackend.PYCOLMAP)
            _, t = _timed(match_descriptors, f[0].descriptors, f[1].descriptors, opts)
            rows.append(("match descriptors (pycolmap CPU)", f"{1e3 * t:.0f} ms/pair", "oracle"))
    return rows


#: The issue's goals: front-end frames per second per core, every stage included: 10 at
#: 516×386 and 3 at 1032×772 (images 1000 px wide or more).
GOAL_FPS = 10.0
GOAL_FPS_1032 = 3.0


def goal_fps(width: int) -> float:
    """The issue's frames/s per core goal for images ``width`` pixels wide."""
    return GOAL_FPS_1032 if width >= 1000 else GOAL_FPS


def _references() -> dict[str, Any]:
    """Previous implementations of the stages (``tests/_frontend_reference.py``), by stage name."""
    try:
        import _frontend_reference
    except ImportError:  # pragma: no cover - the tests folder is next to bench/
        return {}
    return dict(_frontend_reference.REFERENCES)


def _as_jobs() -> Any:
    """This process as the front end's jobs run it (``job_settings``: BLAS and OpenCV on one
    thread, the freed heap kept between frames); code before 2026-11-28's heap, e.g. a
    ``--against`` tree, has ``one_thread`` alone."""
    from bimcap.frontend import runner

    return getattr(runner, "job_settings", runner.one_thread)()


def _same(a: Any, b: Any) -> bool:
    """Bit-for-bit equality of two stage outputs (arrays, or dicts / tuples of them)."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if hasattr(a, "__dataclass_fields__"):
        return _same(vars(a), vars(b))
    return bool(np.array_equal(np.asarray(a), np.asarray(b)))


class _Stages:
    """CPU seconds per stage, and of the previous implementation where one is kept."""

    def __init__(self, previous: bool = True) -> None:
        self.t: dict[str, float] = {}
        self.prev: dict[str, float] = {}
        self.equal: dict[str, bool] = {}
        self.refs = _references() if previous else {}

    def run(self, stage: str, fn: Any, *args: Any, **kwargs: Any) -> Any:
        out, t = _timed(fn, *args, **kwargs)
        self.t[stage] = self.t.get(stage, 0.0) + t
        ref = self.refs.get(stage)
        if ref is not None:
            with ref():
                old, t_old = _timed(fn, *args, **kwargs)
            self.prev[stage] = self.prev.get(stage, 0.0) + t_old
            self.equal[stage] = self.equal.get(stage, True) and _same(out, old)
        return out


#: The front end's settings before 2026-11-28 (window 4, COLMAP's Sampson refinement in the
#: verification): ``--before-defaults`` times these beside the defaults (or other settings, e.g.
#: ``--window 2``) on the same inputs in the same process; their accuracy is in docs/speed.md,
#: "Cheaper defaults". A ``geometric`` table here would time the segmentation both ways too.
BEFORE_DEFAULTS: dict[str, Any] = {"window": 4, "matching": {"sampson_refinement": True}}


def bench_world(seq_dir: Path, frames: int, window: int | None, previous: bool = True,
                before_defaults: bool = False, features: dict[str, Any] | None = None,
                matching: dict[str, Any] | None = None,
                old_features: dict[str, Any] | None = None,
                old_matching: dict[str, Any] | None = None,
                linear: dict[str, Any] | None = None,
                ) -> tuple[list[tuple[str, ...]], float]:
    """Per-stage rows ``(stage, ms/frame, previous ms/frame, ratio, same result)`` and the total
    ms a frame, on the first ``frames`` frames of the sequence at ``seq_dir`` (``previous``:
    also time the previous code of the stages that have it; ``before_defaults``: instead, as
    "previous", the stages whose settings changed (matching, verification; segmentation with a
    ``geometric`` table) with :data:`BEFORE_DEFAULTS`, on the same inputs in the same process;
    window None: the config's;
    ``features``: a ``[features]`` table for the main column, and as "previous" the features
    stages (extraction, keypoint depths, matching, verification) with the default one, on the
    same images in the same process; ``matching``: a ``[matching]`` table for the main column's
    matching and verification, and as "previous" those two stages with the default one, on the
    same keypoints in the same process; ``old_features`` / ``old_matching``: the tables of the
    "previous" column instead of the defaults, e.g. the defaults before a change; with both
    a features and a matching table, "previous" is the features stages with the previous
    tables of both; ``linear``: ``LinearOptions`` fields of the depth provider's completion for
    the main column, and as "previous" the depth provider with the default ones, on the same
    scans in the same process)."""
    from bimcap.dataset import read_sequence
    from bimcap.features import extract_sift, lookup_depth, match_descriptors, verify_matches
    from bimcap.frontend.runner import FrameContext, _load_raw_image, _scan_points, get_undistorter
    from bimcap.frontend.semantic_map import (
        SampleSource,
        SemanticSamplingOptions,
        check_label_orientation,
        sample_semantic_points,
    )
    from bimcap.fusion import project_lidar
    from bimcap.geometry.trajectory import read_tum
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import make_providers, match_options, sift_options

    seq = read_sequence(seq_dir)
    n = min(frames, len(seq.frames))
    config = RefineConfig(workers=1)
    window = config.window if window is None else window
    depth_p, label_p, refiner = make_providers(config, seq)
    old_depth_p = None
    if linear:
        from dataclasses import replace as _replace

        from bimcap.fusion import LinearOptions

        previous = False
        old_depth_p = depth_p
        depth_p = _replace(depth_p, completion=_replace(depth_p.completion,
                                                        linear=LinearOptions(**linear)))
    old_label_p = None
    before_match = None
    if before_defaults:
        from dataclasses import replace

        previous = False
        if "geometric" in BEFORE_DEFAULTS:
            old_config = replace(config, geometric=dict(BEFORE_DEFAULTS["geometric"]))
            old_label_p = make_providers(old_config, seq)[1]
        before_match = match_options(RefineConfig(workers=1,
                                                  matching=BEFORE_DEFAULTS.get("matching", {})))
    sift = sift_options(config)
    old_sift = None
    if features is not None or old_features is not None:
        previous = False
        old_sift = sift_options(RefineConfig(workers=1, features=old_features or {}))
        sift = sift_options(RefineConfig(workers=1, features=features or {}))
    old_feats = []
    match_opts = old_match = None
    if matching is not None or old_matching is not None:
        previous = False
        old_match = match_options(RefineConfig(workers=1, matching=old_matching or {}))
        match_opts = match_options(RefineConfig(workers=1, matching=matching or {}))
    sampling = SemanticSamplingOptions(source=SampleSource(config.samples))
    from bimcap.frontend.runner import FrontendConfig

    scan_opts = FrontendConfig().scan
    depth_lookup = FrontendConfig().depth_lookup
    try:
        from bimcap.features.tracks import unsupported_depths
    except ImportError:  # code before the check (PYTHONPATH at an export)
        unsupported_depths = None
    poses = read_tum(seq.root / "poses" / "gt.tum").poses
    st = _Stages(previous)
    cam = seq.camera
    feats = []

    def one_frame(stages: _Stages, i: int) -> None:
        """Every per-frame stage of frame ``i``, timed into ``stages``."""
        und = get_undistorter(cam)
        raw = stages.run("load image", _load_raw_image, seq, i, cam)
        image = stages.run("undistort", und.image, raw)
        ctx = FrameContext(seq, i, cam, und.pinhole, image, und, poses[i])
        # read once for every stage (FrameContext.lidar); the code before it read it per stage
        scan = stages.run("load LiDAR", ctx.lidar if hasattr(ctx, "lidar") else seq.load_lidar,
                      *(() if hasattr(ctx, "lidar") else (i,)))
        stages.run("LiDAR projection", project_lidar, scan, seq.cam_from_lidar, cam,
               depth_p.projection, distort=False)
        if hasattr(ctx, "range_noise_m"):
            # measured once a frame for every stage that asks (FrameContext.range_noise_m): timed
            # on its own, not in whichever stage asks first (the segmentation, whose new and
            # previous code then compare the same work)
            stages.run("scan range noise", ctx.range_noise_m)
        depth = stages.run("depth provider", depth_p, ctx)
        if old_depth_p is not None:
            _, t_old = _timed(old_depth_p, ctx)
            stages.prev["depth provider"] = stages.prev.get("depth provider", 0.0) + t_old
            stages.equal["depth provider"] = False
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
        ctx.depth = depth
        labels = stages.run("geometric segmentation", label_p, ctx)
        if old_label_p is not None:
            _, t_old = _timed(old_label_p, ctx)
            seg = "geometric segmentation"
            stages.prev[seg] = stages.prev.get(seg, 0.0) + t_old
            stages.equal[seg] = False
        depth = stages.run("planar smoothing", refiner, ctx, labels)
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
        f = stages.run("SIFT", extract_sift, image, sift)
        feats.append(f)
        stages.run("keypoint depths", lookup_depth, depth, f.uv)
        # as the frame job: the keypoint depths the returns around them contradict
        measured = getattr(ctx, "measured_depth", None)
        if unsupported_depths is not None and measured is not None:
            noise = ctx.range_noise_m()
            if noise is not None:
                stages.run("keypoint depth support", unsupported_depths, depth, measured, f.uv,
                           noise, depth_lookup)
        if old_sift is not None:
            f_old, t_old = _timed(extract_sift, image, old_sift)
            old_feats.append(f_old)
            _, t_depth = _timed(lookup_depth, depth, f_old.uv)
            for stage, t in (("SIFT", t_old), ("keypoint depths", t_depth)):
                stages.prev[stage] = stages.prev.get(stage, 0.0) + t
                stages.equal[stage] = False
        # as the front end's frame job: the labels the depth contradicts dropped, then sampled
        checked, _ = stages.run("label orientation check", check_label_orientation, labels, depth,
                            und.pinhole, poses[i], sampling)
        stages.run("semantic sampling", sample_semantic_points, checked, depth, und.pinhole, i,
               sampling)
        if hasattr(ctx, "lidar"):
            stages.run("scan surface points", _scan_points, ctx, scan_opts)
        else:  # the code before the frame's scan was read once (PYTHONPATH at an export)
            stages.run("scan surface points", _scan_points, seq, i, und.pinhole, scan_opts)

    # One frame and one pair first, untimed: the imports and first calls that a worker pays once
    # (OpenCV, pycolmap, ONNX Runtime) are not a frame's cost; reported apart.
    t_warm = time.process_time()
    scratch = _Stages(False)
    for i in range(min(2, n)):
        one_frame(scratch, i)
    if len(feats) == 2:
        fa, fb = feats
        verify_matches(fa.uv, fb.uv, match_descriptors(fa.descriptors, fb.descriptors, match_opts),
                       cam.pinhole(), match_opts)
    warm_up_s = time.process_time() - t_warm
    feats.clear()
    old_feats.clear()
    for i in range(n):
        one_frame(st, i)
    pin = cam.pinhole()
    pairs = [(a, b) for a in range(n) for b in range(a + 1, min(n, a + window + 1))]
    if not before_defaults:
        for a, b in pairs:
            m = st.run("matching", match_descriptors, feats[a].descriptors, feats[b].descriptors,
                       match_opts)
            st.run("verification", verify_matches, feats[a].uv, feats[b].uv, m, pin, match_opts)
            if old_match is not None and old_sift is None:
                m, tm = _timed(match_descriptors, feats[a].descriptors, feats[b].descriptors,
                               old_match)
                _, tv = _timed(verify_matches, feats[a].uv, feats[b].uv, m, pin, old_match)
                for stage, t in (("matching", tm), ("verification", tv)):
                    st.prev[stage] = st.prev.get(stage, 0.0) + t
                    st.equal[stage] = False
            if old_sift is not None:
                fa, fb = old_feats[a], old_feats[b]
                prev_match = old_match if old_match is not None else match_opts
                m, tm = _timed(match_descriptors, fa.descriptors, fb.descriptors, prev_match)
                _, tv = _timed(verify_matches, fa.uv, fb.uv, m, pin, prev_match)
                for stage, t in (("matching", tm), ("verification", tv)):
                    st.prev[stage] = st.prev.get(stage, 0.0) + t
                    st.equal[stage] = False
    else:  # each pair timed once, counted in the windows that hold it
        # the matching options differ in the verification only (its Sampson refinement): each
        # pair matched once, verified with both where they differ
        old_window = int(BEFORE_DEFAULTS["window"])
        new_match = match_options(config)
        same_verification = before_match == new_match
        for a in range(n):
            for b in range(a + 1, min(n, a + max(window, old_window) + 1)):
                m, tm = _timed(match_descriptors, feats[a].descriptors, feats[b].descriptors,
                               new_match)
                _, tv = _timed(verify_matches, feats[a].uv, feats[b].uv, m, pin, new_match)
                tv_old = tv
                if not same_verification and b - a <= old_window:
                    _, tv_old = _timed(verify_matches, feats[a].uv, feats[b].uv, m, pin,
                                       before_match)
                for stage, t, t_old in (("matching", tm, tm), ("verification", tv, tv_old)):
                    if b - a <= window:
                        st.t[stage] = st.t.get(stage, 0.0) + t
                    if b - a <= old_window:
                        st.prev[stage] = st.prev.get(stage, 0.0) + t_old
                    st.equal[stage] = window == old_window and (
                        stage == "matching" or same_verification)
    # the provider's time includes its projection: report the completion alone
    st.t["completion + support radius"] = st.t.pop("depth provider") - st.t["LiDAR projection"]
    if "depth provider" in st.prev:
        st.prev["completion + support radius"] = (st.prev.pop("depth provider")
                                                  - st.t["LiDAR projection"])
        st.equal["completion + support radius"] = st.equal.pop("depth provider")
    rows = []
    for stage, t in st.t.items():
        ms = 1e3 * t / n
        if stage in st.prev:
            prev = 1e3 * st.prev[stage] / n
            same = ("yes" if st.equal[stage] else "settings"
                    if before_defaults or old_sift is not None or old_match is not None
                    or old_depth_p is not None else "NO")
            rows.append((stage, f"{ms:.1f}", f"{prev:.1f}", f"{prev / ms:.2f}×", same))
        else:
            rows.append((stage, f"{ms:.1f}", "", "", ""))
    total = 1e3 * sum(st.t.values()) / n
    prev_total = total + 1e3 * sum(st.prev[k] - st.t[k] for k in st.prev) / n
    rows.append(("total", f"{total:.1f}", f"{prev_total:.1f}", f"{prev_total / total:.2f}×", ""))
    rows.append((f"frames/s per core (goal {goal_fps(seq.camera.width):.0f})", f"{1e3 / total:.2f}",
                 f"{1e3 / prev_total:.2f}", "", ""))
    rows.append((f"pairs per frame (window {window})", f"{len(pairs) / n:.2f}", "", "", ""))
    rows.append(("once a process: 2 frames + 1 pair before timing (ms, not counted)",
                 f"{1e3 * warm_up_s:.0f}", "", "", ""))
    return rows, total


def bench_world_features(seq_dir: Path, frames: int, window: int | None,
                         backends: list[str]) -> list[tuple[str, ...]]:
    """Per feature backend (``[features] backend`` values, e.g. pycolmap, orb), on the same
    undistorted frames in the same process: rows ``(backend, extraction ms/frame, keypoints,
    matching ms/pair, verification ms/pair, verified matches/pair, pairs verified, features ms
    a frame, frames/s per core of the features alone, match error against the ground truth)``;
    "features ms a frame" is extraction plus the frame's pairs (``window`` of them) matched and
    verified; the match error (median / p95, cm) is the world distance between the two
    back-projections of each verified match through the ground-truth depth and poses (empty
    without ground-truth depth)."""
    from bimcap.dataset import read_sequence
    from bimcap.features import extract_sift, lookup_depth, match_descriptors, verify_matches
    from bimcap.frontend.runner import _load_raw_image, get_undistorter
    from bimcap.geometry.poses import transform_points
    from bimcap.geometry.trajectory import read_tum
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import sift_options

    seq = read_sequence(seq_dir)
    n = min(frames, len(seq.frames))
    config = RefineConfig(workers=1)
    window = config.window if window is None else window
    cam = seq.camera
    und = get_undistorter(cam)
    images = [und.image(_load_raw_image(seq, i, cam)) for i in range(n)]
    pairs = [(a, b) for a in range(n) for b in range(a + 1, min(n, a + window + 1))]
    pin = cam.pinhole()
    gt_depth = ([und.nearest(seq.load_depth(i)) for i in range(n)] if seq.has_depth else None)
    gt_poses = read_tum(seq.root / "poses" / "gt.tum").poses
    rows = []
    for backend in backends:
        # "orb:orb_max_num_features=1024": a backend with more [features] settings
        name, *settings = backend.split(":")
        table: dict[str, Any] = {"backend": name}
        for item in settings:
            key, _, value = item.partition("=")
            table[key] = _setting_value(value)
        opts = sift_options(RefineConfig(features=table))
        res = [_timed(extract_sift, im, opts) for im in images]
        feats = [f for f, _ in res]
        t_ext = float(np.mean([t for _, t in res]))
        t_m, t_v, n_inl, errs = [], [], [], [np.zeros(0)]
        for a, b in pairs:
            m, t = _timed(match_descriptors, feats[a].descriptors, feats[b].descriptors)
            t_m.append(t)
            (inl, _), t = _timed(verify_matches, feats[a].uv, feats[b].uv, m, pin)
            t_v.append(t)
            n_inl.append(len(inl))
            if gt_depth is not None:
                ends = []
                for k, col in ((a, 0), (b, 1)):
                    uv = feats[k].uv[inl[:, col]]
                    ends.append((uv, lookup_depth(gt_depth[k], uv)))
                ok = (ends[0][1] > 0) & (ends[1][1] > 0)
                pa, pb = (transform_points(gt_poses[k], pin.backproject(uv[ok], d[ok],
                                                                       distorted=False))
                          for k, (uv, d) in zip((a, b), ends, strict=True))
                errs.append(np.linalg.norm(pa - pb, axis=1))
        err = np.concatenate(errs)
        gt_err = (f"{100 * np.median(err):.2f} / {100 * np.percentile(err, 95):.2f}"
                  if len(err) else "")
        per_frame = t_ext + len(pairs) / n * (np.mean(t_m) + np.mean(t_v))
        rows.append((backend, f"{1e3 * t_ext:.1f}", f"{np.mean([len(f) for f in feats]):.0f}",
                     f"{1e3 * np.mean(t_m):.1f}", f"{1e3 * np.mean(t_v):.1f}",
                     f"{np.mean(n_inl):.0f}", f"{np.count_nonzero(n_inl)}/{len(pairs)}",
                     f"{1e3 * per_frame:.1f}", f"{1.0 / per_frame:.2f}", gt_err))
    return rows


def _setting_value(text: str) -> Any:
    """A ``[features]`` value from a ``--backends`` spec: int, float, bool or the string."""
    if text in ("true", "false"):
        return text == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def bench_prepare(seq_dir: Path, frames: int, work: Path,
                  tables: list[tuple[dict[str, Any], dict[str, Any]]] | None = None,
                  repeat: int = 1) -> tuple[list[float], int]:
    """CPU seconds of ``bimcap.pipeline.refine.prepare`` (``RefineConfig(workers=1)``, the
    sequence's ground truth as the initial poses, ``../as_built.ifc`` if there is one else the
    manifest's IFC, the BIM reference loaded before the timing) on
    the first ``frames`` frames, with a fresh ``work`` directory; and the frames run. BLAS and
    OpenCV keep the threads the library gives them. ``tables``: ``([features], [matching])``
    tables, one time each (default: one run with the defaults), the least of ``repeat`` runs
    taken in turn (A B A B), so that a change of load touches all of them alike."""
    import shutil
    from dataclasses import replace

    from bimcap.dataset import read_sequence
    from bimcap.geometry.trajectory import read_tum
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import prepare

    seq = read_sequence(seq_dir)
    n = min(frames, len(seq.frames))
    seq = replace(seq, frames=seq.frames[:n])
    gt = read_tum(seq_dir / "poses" / "gt.tum")
    init = replace(gt, timestamps=gt.timestamps[:n], poses=gt.poses[:n])
    as_built = seq_dir.parent / "as_built.ifc"  # generated worlds: the reference IFC
    ifc = as_built if as_built.is_file() else seq.ifc_path
    configs = [RefineConfig(workers=1, features=f, matching=m) for f, m in (tables or [({}, {})])]
    prepare(seq, ifc, init, configs[0], work / "warm", quiet=True)  # BIM cache
    best = [np.inf] * len(configs)
    for _ in range(repeat):
        for k, config in enumerate(configs):
            shutil.rmtree(work / "run", ignore_errors=True)
            t0 = time.process_time()
            prepare(seq, ifc, init, config, work / "run", quiet=True)
            best[k] = min(best[k], time.process_time() - t0)
    return best, n


def _stage_ms(output: str) -> dict[str, float]:
    """{stage: ms a frame} of a ``--world`` run's table (columns two spaces or more apart)."""
    import re

    out: dict[str, float] = {}
    rows = output.split("\nstage ", 1)[-1].splitlines()[1:]
    for line in rows:
        cells = re.split(r"\s{2,}", line.strip())
        if len(cells) >= 2 and not cells[0].startswith(("frames/s", "pairs per", "once a")):
            try:
                out[cells[0]] = float(cells[1])
            except ValueError:
                continue
    return out


def bench_against(world: Path, frames: int, tree: Path, repeat: int) -> list[list[str]]:
    """Rows (stage, this ms, TREE's ms, ratio) of the per-stage run on this checkout's code and
    on ``tree``'s, alternating ``repeat`` times, each the least over the runs."""
    import subprocess

    here = Path(__file__).resolve().parents[1]
    best: dict[str, dict[str, float]] = {"this": {}, "other": {}}
    order: list[str] = []
    for _ in range(repeat):
        for name, root in (("this", here), ("other", tree)):
            env = dict(os.environ, PYTHONPATH=str(root / "python"))
            run = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--world",
                                  str(world), "--frames", str(frames), "--no-previous"],
                                 cwd=root, env=env, capture_output=True, text=True)
            if run.returncode != 0:
                raise SystemExit(f"{root}: the bench failed:\n{run.stderr[-2000:]}")
            for stage, ms in _stage_ms(run.stdout).items():
                if stage not in order:
                    order.append(stage)
                best[name][stage] = min(best[name].get(stage, float("inf")), ms)
    rows = []
    for stage in order:
        a, b = best["this"].get(stage), best["other"].get(stage)
        ratio = f"{b / a:.2f}×" if a and b else ""
        rows.append([stage, f"{a:.1f}" if a is not None else "", f"{b:.1f}" if b is not None
                     else "", ratio])
    total_a, total_b = best["this"].get("total"), best["other"].get("total")
    if total_a and total_b:
        from bimcap.dataset import read_sequence

        goal = goal_fps(read_sequence(world).camera.width)
        rows.append([f"frames/s per core (goal {goal:g})", f"{1e3 / total_a:.2f}",
                     f"{1e3 / total_b:.2f}", f"{total_b / total_a:.2f}×"])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--window", type=int, default=None,
                    help="frames each frame is matched with (default: 3 for the features part, "
                         "the config's with --world)")
    ap.add_argument("--pycolmap-matcher", action="store_true", help="also time pycolmap's matcher")
    ap.add_argument("--world", type=Path, default=None,
                    help="a sequence directory (e.g. /tmp/gen/gen-demo-s0/seq_60_standard): "
                         "per-stage times of the whole front end on it, instead of the "
                         "features part")
    ap.add_argument("--no-previous", action="store_true",
                    help="with --world: do not time the previous code of the stages")
    ap.add_argument("--before-defaults", action="store_true",
                    help="with --world: as 'previous', matching and verification with the "
                         "settings before 2026-11-28 (window 4, Sampson refinement) beside the "
                         "defaults or --window N, on the same inputs in the same process")
    ap.add_argument("--features", action="append", default=[], metavar="KEY=VALUE",
                    help="with --world (per stage): a [features] setting for the main column; "
                         "'previous' is then the features stages with the default settings, "
                         "on the same images in the same process")
    ap.add_argument("--matching", action="append", default=[], metavar="KEY=VALUE",
                    help="with --world (per stage): a [matching] setting for the main column "
                         "(e.g. ransac_min_trials=30); 'previous' is then matching and "
                         "verification with the default settings, on the same keypoints in the "
                         "same process")
    ap.add_argument("--previous-features", action="append", default=[], metavar="KEY=VALUE",
                    help="with --world: a [features] setting of the 'previous' column (default: "
                         "the defaults), e.g. the defaults before a change; with --prepare, "
                         "prepare() is also timed with these settings")
    ap.add_argument("--previous-matching", action="append", default=[], metavar="KEY=VALUE",
                    help="with --world: a [matching] setting of the 'previous' column (default: "
                         "the defaults); with --prepare as --previous-features")
    ap.add_argument("--linear", action="append", default=[], metavar="KEY=VALUE",
                    help="with --world: a LinearOptions field of the linear completion for the "
                         "main column (e.g. pixel_owner=centre, triangulation=sweep); "
                         "'previous' is the completion with the defaults, same scans")
    ap.add_argument("--against", type=Path, default=None, metavar="TREE",
                    help="with --world: the per-stage run on this checkout and on TREE's code "
                         "(a checkout with its built _core), alternating --repeat times, the "
                         "least of each and the ratio")
    ap.add_argument("--repeat", type=int, default=1,
                    help="with --prepare: the least CPU time of this many runs of each setting")
    ap.add_argument("--prepare", action="store_true",
                    help="with --world: CPU time of the whole prepare() (front end, cache "
                         "writes, tracks) instead of the stages, BLAS threads as the library "
                         "sets them")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_frontend"),
                    help="with --prepare: scratch directory (its run/ is replaced)")
    ap.add_argument("--backends", default=None,
                    help="with --world: comma list of [features] backends (pycolmap, opencv, "
                         "orb; more settings after colons: orb:orb_max_num_features=1024): "
                         "extraction, matching and verification of each on the same "
                         "frames in the same process, instead of the stages")
    args = ap.parse_args()
    if args.world is not None and args.backends:
        frames = args.frames if args.frames != 6 else 20
        window = args.window
        print(f"# features per backend on {args.world}, first {frames} frames, window "
              f"{window or 'of the config'}, 1 thread, process CPU time, load average "
              f"{os.getloadavg()[0]:.1f}")
        head = ("backend", "extract ms/frame", "keypoints", "match ms/pair", "verify ms/pair",
                "verified/pair", "pairs verified", "features ms/frame", "frames/s/core",
                "GT match error median / p95 cm")
        print(" | ".join(head))
        with _as_jobs():  # BLAS, OpenCV and the heap as the front end's jobs run them
            for row in bench_world_features(args.world, frames, window,
                                            args.backends.split(",")):
                print(" | ".join(row), flush=True)
        return
    features, matching, old_features, old_matching, linear = (
        None if not items else
        {k: _setting_value(v) for k, _, v in (f.partition("=") for f in items)}
        for items in (args.features, args.matching, args.previous_features,
                      args.previous_matching, args.linear))
    if args.world is not None and args.prepare:
        frames = args.frames if args.frames != 6 else 60
        tables = [(features or {}, matching or {})]
        if any(t is not None for t in (features, matching, old_features, old_matching)):
            tables.append((old_features or {}, old_matching or {}))
        cpus, n = bench_prepare(args.world, frames, args.work, tables, args.repeat)
        from bimcap.dataset import read_sequence
        goal = goal_fps(read_sequence(args.world).camera.width)
        print(f"# prepare() on {args.world}, {n} frames, workers 1, process CPU time (least "
              f"of {args.repeat}), load average {os.getloadavg()[0]:.1f}")
        for (f, m), cpu in zip(tables, cpus, strict=True):
            print(f"[features] {f} [matching] {m}: {1e3 * cpu / n:.0f} ms a frame, "
                  f"{n / cpu:.2f} frames/s per core (goal {goal:.0f}; {cpu:.1f} CPU s)")
        if len(cpus) == 2:
            print(f"previous / this: {cpus[1] / cpus[0]:.2f}×")
        return
    if args.world is not None and args.against is not None:
        frames = args.frames if args.frames != 6 else 20
        print(f"# front end per stage on {args.world}, first {frames} frames, this checkout "
              f"against {args.against}, least of {args.repeat} alternating runs each, 1 thread, "
              f"process CPU ms a frame, load average {os.getloadavg()[0]:.1f}")
        rows = bench_against(args.world, frames, args.against, args.repeat)
        w = max(len(r[0]) for r in rows)
        print(f"{'stage':<{w}}  {'this':>9}  {'against':>9}  {'ratio':>7}")
        for stage, a, b, ratio in rows:
            print(f"{stage:<{w}}  {a:>9}  {b:>9}  {ratio:>7}")
        return
    if args.world is not None:
        frames = args.frames if args.frames != 6 else 20
        window = args.window
        print(f"# front end per stage on {args.world}, first {frames} frames, window "
              f"{window or 'of the config'}, 1 thread, process CPU ms a frame, load average "
              f"{os.getloadavg()[0]:.1f}"
              + (f"; 'previous' = the settings {BEFORE_DEFAULTS}" if args.before_defaults else "")
              + (f"; [features] {features or {}}, 'previous' = [features] {old_features or {}}"
                 if features or old_features else "")
              + (f"; [matching] {matching or {}}, 'previous' = [matching] {old_matching or {}}"
                 if matching or old_matching else "")
              + (f"; linear completion {linear}, 'previous' = its defaults" if linear else ""))
        with _as_jobs():  # BLAS, OpenCV and the heap as the front end's jobs run them
            rows, _ = bench_world(args.world, frames, window, not args.no_previous,
                                  args.before_defaults, features, matching, old_features,
                                  old_matching, linear)
        w = max(len(r[0]) for r in rows)
        print(f"{'stage':<{w}}  {'ms/frame':>9}  {'previous':>9}  {'ratio':>7}  same result")
        for stage, ms, prev, ratio, same in rows:
            print(f"{stage:<{w}}  {ms:>9}  {prev:>9}  {ratio:>7}  {same}")
        return
    if args.window is None:
        args.window = 3
    cam = _camera()
    print(f"# front-end features benchmark: {cam.width}x{cam.height}, {args.frames} frames, "
          f"window {args.window}, 1 thread, CPU time, load average {os.getloadavg()[0]:.1f}")
    rows = bench_features(args.frames, args.window, args.pycolmap_matcher)
    w = max(len(r[0]) for r in rows)
    print(f"{'step':<{w}}  {'time':>16}  result")
    for step, t, acc in rows:
        print(f"{step:<{w}}  {t:>16}  {acc}")


if __name__ == "__main__":
    main()
