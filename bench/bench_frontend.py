"""Front-end benchmark at 1032×772 (ConSLAM's camera at half resolution), one CPU core.

Times are process CPU seconds of single-threaded calls (BLAS and pycolmap on one thread).

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--window", type=int, default=3)
    ap.add_argument("--pycolmap-matcher", action="store_true", help="also time pycolmap's matcher")
    args = ap.parse_args()
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
