"""Time the evaluation metrics on synthetic data; prints a table. Not collected by pytest.

Run: ``PYTHONPATH=python python bench/bench_evaluation.py``
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from bimcap.evaluation.map_metrics import map_metrics, nearest_neighbour_distance
from bimcap.evaluation.metrics import AlignMode, trajectory_metrics


def _room(n: int, rng: np.random.Generator) -> np.ndarray:
    """n points on the six faces of a 10 x 8 x 3 m box, 1 cm noise."""
    pts = rng.uniform([0, 0, 0], [10, 8, 3], (n, 3))
    face = rng.integers(0, 6, n)
    axis, side = face % 3, face // 3
    pts[np.arange(n), axis] = np.choose(axis, [side * 10.0, side * 8.0, side * 3.0])
    return pts + rng.normal(0.0, 0.01, pts.shape)


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"{'case':<40}{'seconds':>10}")
    for n in (1_000, 10_000):
        gt = np.hstack([rng.normal(size=(n, 3)), Rotation.random(n, random_state=1).as_quat()])
        est = gt + np.hstack([rng.normal(0, 0.05, (n, 3)), np.zeros((n, 4))])
        for mode in AlignMode:
            t = time.perf_counter()
            trajectory_metrics(est, gt, mode)
            print(f"{f'ATE {mode.value}, {n} poses':<40}{time.perf_counter() - t:>10.3f}")
    for n, radius in ((50_000, 0.2), (200_000, 0.2), (50_000, 1.0)):
        pts = _room(n, rng)
        t = time.perf_counter()
        m = map_metrics(pts, radius)
        dt = time.perf_counter() - t
        print(f"{f'MME/MPV {n} pts, r={radius} m':<40}{dt:>10.3f}   (MME {m.mme:.3f})")
    pts = _room(200_000, rng)
    t = time.perf_counter()
    nearest_neighbour_distance(pts + 0.02, pts)
    print(f"{'NND 200k vs 200k points':<40}{time.perf_counter() - t:>10.3f}")


if __name__ == "__main__":
    main()
