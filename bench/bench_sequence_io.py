"""Sequence directory I/O throughput: write (per file kind) and lazy load, per frame.

Usage: PYTHONPATH=python python bench/bench_sequence_io.py [--frames 20] [--scale 0.5]

Frames are textured-looking noise at ConSLAM's resolution × scale with a VLP-16-sized scan
(~29 k points), labels and depth, i.e. what the simulator writes. Prints one row per PNG level.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from bimcap.dataset import SequenceWriter, read_sequence
from bimcap.dataset.conslam import CONSLAM_CAM_FROM_LIDAR, CONSLAM_CAMERA


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--scale", type=float, default=0.5)
    args = ap.parse_args()
    cam = CONSLAM_CAMERA.scaled(args.scale)
    rng = np.random.default_rng(0)
    h, w = cam.height, cam.width
    ramp = (np.indices((h, w)).sum(axis=0) % 256).astype(np.uint8)
    image = np.repeat(ramp[:, :, None], 3, axis=2) ^ rng.integers(0, 16, (h, w, 3), np.uint8)
    labels = (np.indices((h, w))[0] * 8 // h).astype(np.uint8)
    depth = rng.uniform(0.5, 20.0, (h, w)).astype(np.float32)
    scan = rng.normal(0.0, 5.0, (28_800, 4)).astype(np.float32)
    print(f"{args.frames} frames at {w}x{h}, scan {len(scan)} points")
    print(
        f"{'png level':>10} {'write ms/frame':>15} {'read_sequence ms':>17} {'load ms/frame':>14}"
    )
    for level in (None, 1, 3):
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp) / "seq"
            t0 = time.perf_counter()
            with SequenceWriter(root, cam, CONSLAM_CAM_FROM_LIDAR, png_compression=level) as wr:
                for i in range(args.frames):
                    wr.add_frame(0.1 * i, image, scan, labels, depth)
            t1 = time.perf_counter()
            seq = read_sequence(root)
            t2 = time.perf_counter()
            for i in range(len(seq)):
                seq.load_image(i), seq.load_lidar(i), seq.load_labels(i), seq.load_depth(i)
            t3 = time.perf_counter()
        name = "default" if level is None else str(level)
        print(
            f"{name:>10} {(t1 - t0) / args.frames * 1e3:15.1f} {(t2 - t1) * 1e3:17.1f} "
            f"{(t3 - t2) / args.frames * 1e3:14.1f}"
        )


if __name__ == "__main__":
    main()
