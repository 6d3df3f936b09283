"""Benchmark of the fusion and segmentation stages at 1032×772 on synthetic box-room frames.

Prints one table: per-frame CPU time (median over frames, one thread: OMP/BLAS, OpenCV and ONNX
Runtime all set to 1) and wall time, with accuracy beside it (depth MAE / RMSE / inlier ratio /
coverage against the ray-cast ground truth; per-class IoU for the segmenter). Rendering is not
timed. The ONNX rows use a stand-in network built with onnx.helper (a 9×9 normalised
convolution), not CompletionFormer: they time the adapter and show the plumbing, not a learned
model's accuracy.

Usage: PYTHONPATH=python python bench/bench_fusion.py [--frames 4] [--lidar-channels 32]
       PYTHONPATH=python python bench/bench_fusion.py --sequence SEQ_DIR [--frames 8]
With ``--sequence`` the frames come from a bimcap sequence directory (e.g. the simulator's):
raw images are undistorted (bilinear), ground-truth depth and labels (nearest), poses ``gt``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "python"))
sys.path.insert(0, str(REPO / "tests"))  # the onnx.helper model builders of the tests


def _timed(fn: Callable[[], Any], repeat: int = 1) -> tuple[Any, float, float]:
    """(result, cpu seconds, wall seconds) of the best of ``repeat`` calls."""
    best_cpu, best_wall, out = np.inf, np.inf, None
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn()
        best_cpu = min(best_cpu, time.process_time() - c0)
        best_wall = min(best_wall, time.perf_counter() - w0)
    return out, best_cpu, best_wall


def _sequence_frames(root: Path, n: int) -> list[Any]:
    """Up to ``n`` evenly spread frames of a sequence, in undistorted pinhole pixels."""
    from types import SimpleNamespace

    from bimcap.dataset import read_sequence
    from bimcap.fusion import undistort_image

    seq = read_sequence(root)
    gt = seq.trajectory("gt").poses
    raw = seq.camera
    out = []
    for i in np.unique(np.linspace(0, len(seq.frames) - 1, n).round().astype(int)):
        depth, labels = seq.load_depth(int(i)), seq.load_labels(int(i))
        if depth is None or labels is None:
            raise SystemExit(f"frame {i} has no ground-truth depth/labels")
        out.append(SimpleNamespace(
            image=undistort_image(seq.load_image(int(i)), raw),
            depth=undistort_image(np.asarray(depth, np.float32), raw, nearest=True),
            labels=undistort_image(np.asarray(labels, np.uint8), raw, nearest=True),
            points_in_lidar=np.asarray(seq.load_lidar(int(i)))[:, :3],
            cam_from_lidar=seq.cam_from_lidar,
            camera=raw.pinhole(),
            world_from_cam=gt[int(i)],
            lidar_model=getattr(seq.lidar, "model", "?"),
        ))
    return out


def main() -> None:
    import cv2

    from _fusion_onnx_models import completion_normalized_conv
    from bimcap.fusion import (
        ClassicalOptions,
        CompletionMethod,
        CompletionOptions,
        PlanarSmoothing,
        PlanarSmoothingOptions,
        complete_depth,
        depth_errors,
        fill_nearest,
        project_lidar,
        smooth_planar_regions,
    )
    from bimcap.fusion.onnx_completion import OnnxCompletionOptions
    from bimcap.fusion.synthetic import SpinningLidar, default_camera, render_default_frames
    from bimcap.labels import Label
    from bimcap.segmentation import iou_per_class
    from bimcap.segmentation.geometric import segment_geometric

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--lidar-channels", type=int, default=32)
    ap.add_argument("--lidar-vfov", type=float, default=25.0, help="± vertical FoV, degrees")
    ap.add_argument("--repeat", type=int, default=3, help="best of N per frame")
    ap.add_argument("--sequence", type=Path, default=None, help="a bimcap sequence directory")
    args = ap.parse_args()
    cv2.setNumThreads(1)

    if args.sequence is not None:
        frames = _sequence_frames(args.sequence, args.frames)
        cam = frames[0].camera
        where = f"sequence {args.sequence} (LiDAR {frames[0].lidar_model})"
    else:
        cam = default_camera(1032, 772)
        lidar = SpinningLidar(args.lidar_channels, (-args.lidar_vfov, args.lidar_vfov))
        frames = render_default_frames(args.frames, camera=cam, lidar=lidar, seed=0)
        where = f"box room, LiDAR {args.lidar_channels} rings ±{args.lidar_vfov:g}°, 0.2° azimuth"
    tmp = Path(tempfile.mkdtemp())
    nconv = completion_normalized_conv(tmp / "nconv.onnx", 9)

    rows: list[tuple[str, float, float, str]] = []

    def record(name: str, per_frame: list[tuple[float, float]], acc: str) -> None:
        cpu = float(np.median([c for c, _ in per_frame])) * 1e3
        wall = float(np.median([w for _, w in per_frame])) * 1e3
        rows.append((name, cpu, wall, acc))

    def depth_acc(preds: list[np.ndarray], valid: list[np.ndarray] | None = None) -> str:
        errs = [depth_errors(p, f.depth, None if valid is None else v) for p, f, v in
                zip(preds, frames, valid or [None] * len(preds), strict=True)]
        errs = [e for e in errs if e.n > 0]
        if not errs:
            return "no pixels"
        n = np.array([e.n for e in errs], float)
        mae = float(np.average([e.mae for e in errs], weights=n))
        rmse = float(np.sqrt(np.average([e.rmse**2 for e in errs], weights=n)))
        inl = float(np.average([e.inlier_ratio for e in errs], weights=n))
        cov = float(np.mean([e.coverage for e in errs]))
        return f"MAE {mae * 100:5.2f} cm  RMSE {rmse * 100:5.2f} cm  inl {inl:.3f}  cov {cov:.3f}"

    # projection
    sparse, t = [], []
    for f in frames:
        sp, c, w = _timed(lambda f=f: project_lidar(f.points_in_lidar, f.cam_from_lidar, f.camera),
                          args.repeat)
        sparse.append(sp)
        t.append((c, w))
    kept = np.mean([s.counts["kept"] for s in sparse])
    record("projection (z-buffer + parallax test)", t,
           f"{kept:.0f} returns kept / frame, " + depth_acc([s.depth for s in sparse]))

    methods: list[tuple[str, Callable[[Any, Any], np.ndarray]]] = [
        ("nearest-neighbour fill (baseline)", lambda sp, f: fill_nearest(sp)),
        ("LINEAR (Delaunay, 1/z)",
         lambda sp, f: complete_depth(sp, CompletionOptions(CompletionMethod.LINEAR))),
        ("CLASSICAL (Ku + ring interp., work ½)",
         lambda sp, f: complete_depth(sp, CompletionOptions(CompletionMethod.CLASSICAL))),
        ("CLASSICAL (work 1/1)",
         lambda sp, f: complete_depth(sp, CompletionOptions(
             CompletionMethod.CLASSICAL,
             classical=ClassicalOptions(work_scale=1.0, max_gap_px=80)))),
        ("CLASSICAL Ku only (work ½)",
         lambda sp, f: complete_depth(sp, CompletionOptions(
             CompletionMethod.CLASSICAL,
             classical=ClassicalOptions(vertical_interpolation=False)))),
        ("ONNX stand-in nconv9 (full res)",
         lambda sp, f: complete_depth(
             sp, CompletionOptions(CompletionMethod.ONNX, onnx=OnnxCompletionOptions(nconv)),
             f.image)),
        ("HYBRID LINEAR → stand-in nconv9",
         lambda sp, f: complete_depth(
             sp, CompletionOptions(CompletionMethod.HYBRID, onnx=OnnxCompletionOptions(nconv)),
             f.image)),
    ]
    dense: dict[str, list[np.ndarray]] = {}
    for name, fn in methods:
        outs, t = [], []
        for sp, f in zip(sparse, frames, strict=True):
            d, c, w = _timed(lambda sp=sp, f=f, fn=fn: fn(sp, f), args.repeat)
            outs.append(d)
            t.append((c, w))
        dense[name] = outs
        record(name, t, depth_acc(outs))
    # the baseline on exactly the pixels LINEAR covers (LINEAR leaves holes)
    lin = dense["LINEAR (Delaunay, 1/z)"]
    rows.append(("  nearest on LINEAR's pixels", float("nan"), float("nan"),
                 depth_acc(dense["nearest-neighbour fill (baseline)"], [d > 0 for d in lin])))

    # planar smoothing (GT labels; classical depth)
    cls = dense["CLASSICAL (Ku + ring interp., work ½)"]
    for mode in (PlanarSmoothing.PLANE_FIT, PlanarSmoothing.BLUR):
        outs, t = [], []
        for d, f in zip(cls, frames, strict=True):
            o, c, w = _timed(lambda d=d, f=f, mode=mode: smooth_planar_regions(
                d, f.labels, f.camera, PlanarSmoothingOptions(mode=mode)), args.repeat)
            outs.append(o)
            t.append((c, w))
        fl = [np.isin(f.labels, [int(Label.FLOOR), int(Label.CEILING)]) for f in frames]
        record(f"  smooth floor/ceiling {mode.value}", t,
               "floor+ceiling " + depth_acc(outs, fl).split("  inl")[0]
               + "  (before: " + depth_acc(cls, fl).split("  inl")[0] + ")")

    # segmentation
    def seg_rows(name: str, depths: list[np.ndarray]) -> list[np.ndarray]:
        outs, t = [], []
        for d, f in zip(depths, frames, strict=True):
            lab, c, w = _timed(lambda d=d, f=f: segment_geometric(d, f.camera, f.world_from_cam),
                               args.repeat)
            outs.append(lab)
            t.append((c, w))
        iou = iou_per_class(np.concatenate(outs), np.concatenate([f.labels for f in frames]))
        acc = "IoU " + " ".join(f"{k.name.lower()} {v:.3f}" for k, v in iou.items()
                                if k in (Label.FLOOR, Label.CEILING, Label.WALL, Label.COLUMN))
        record(name, t, acc)
        return outs

    seg_rows("no-weights segmenter on GT depth", [f.depth for f in frames])
    seg_rows("no-weights segmenter on CLASSICAL depth", cls)

    # the target chain: projection + classical completion + segmentation
    t = []
    for f in frames:
        def chain(f=f) -> np.ndarray:  # type: ignore[no-untyped-def]
            sp = project_lidar(f.points_in_lidar, f.cam_from_lidar, f.camera)
            d = complete_depth(sp, CompletionOptions(CompletionMethod.CLASSICAL))
            return segment_geometric(d, f.camera, f.world_from_cam)
        _, c, w = _timed(chain, args.repeat)
        t.append((c, w))
    record("CHAIN projection + CLASSICAL + segmenter", t, "")
    chain_cpu = rows[-1][1]

    print(f"bimcap fusion bench: {len(frames)} frames {cam.width}x{cam.height}, {where}; "
          f"one thread; best of {args.repeat} per frame, median over frames; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'step':44s} {'cpu ms':>8s} {'wall ms':>8s}  accuracy")
    for name, cpu, wall, acc in rows:
        print(f"{name:44s} {cpu:8.1f} {wall:8.1f}  {acc}")
    print(f"chain: {1000.0 / chain_cpu:.1f} frames/s per core (CPU time); target >= 10")


if __name__ == "__main__":
    main()
