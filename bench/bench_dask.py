"""Front-end frames/s: the local process pool vs a Dask LocalCluster, same machine, same run.

The pipeline's own per-frame path (LiDAR projection + linear completion, the geometric
segmenter, planar depth refinement, SIFT, matching within the window) on frames ray-cast from
the test room (tests/_frontend_scene.py) at 1032×772 (ConSLAM's camera at half resolution), no
cache, so that every frame and pair is computed. Four ways, interleaved, best of ``--repeat``
wall times:

- serial: ``workers=1`` (this process; the reference for the speed-ups);
- local pool: ``workers=N`` spawn processes (``bimcap refine --workers N``);
- Dask, own cluster: ``ExecutorOptions(kind=DASK, dask_workers=N)``, the run starts a
  LocalCluster of N processes and closes it (``bimcap refine --dask --dask-workers N``);
- Dask, running cluster: the same LocalCluster started once, passed as a ``Client`` (what
  ``--dask-scheduler`` gives: the cluster's start is not paid by the run).

Two figures per way: wall frames/s (what a user waits for; on a shared, loaded machine it moves
with the other jobs' load) and CPU seconds per frame of this process and all its worker
processes (what the way costs; less moved by other jobs' load than wall time, though a loaded
machine inflates it too, so it is the figure the goal is checked on). Every run's arrays are
checked to be equal to the serial run's, bit for bit. Prints each figure next to its goal and
the ratio measured in this run; never collected by pytest.

    PYTHONPATH=python python bench/bench_dask.py [--frames 12] [--workers 2] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

#: Goal: on one machine the Dask path costs at most 10 % more CPU per frame than the local pool
#: (the jobs are the same; Dask adds a scheduler round trip per job, serialisation of the
#: arrays and the workers' event loops).
GOAL_CPU_RATIO = 1.1


def _cpu_s() -> float:
    """CPU seconds (user + system) of this process, its exited children (waited for) and its
    live descendants: the difference over a run is what the run cost, wherever it ran."""
    import psutil

    t = os.times()
    total = t.user + t.system + t.children_user + t.children_system
    for proc in psutil.Process().children(recursive=True):
        try:
            c = proc.cpu_times()
        except psutil.NoSuchProcess:  # exited between the listing and the read
            continue
        total += c.user + c.system
    return total


def _camera() -> Any:
    from bimcap.geometry.camera import Camera

    conslam = Camera(
        2064, 1544, 2351.85909, 2353.56734, 1017.24032, 788.70774,
        (-0.054366, 0.118389, 0.001781, -0.003908, 0.0),
    )
    return conslam.scaled(0.5)


def _providers() -> dict[str, Any]:
    from bimcap.frontend.providers import (
        LidarDepthProvider,
        PlanarDepthRefiner,
        SegmenterLabelProvider,
    )
    from bimcap.segmentation.geometric import GeometricSegmenter

    return {"depth_provider": LidarDepthProvider(),
            "label_provider": SegmenterLabelProvider(GeometricSegmenter(), uses_pose=True),
            "depth_refiner": PlanarDepthRefiner()}


def _poses(n: int) -> Any:
    """(n, 7) the tests' short walk along x (tests/_frontend_scene.py), repeated every 16."""
    from _frontend_scene import default_poses

    walk = default_poses(16)
    return walk[np.arange(n) % 16]


def main() -> None:
    from distributed import Client, LocalCluster

    from _frontend_scene import SceneSequence
    from bimcap.frontend import ExecutorOptions, FrontendConfig, run_frontend
    from bimcap.frontend.runner import OBSERVATION_ARRAYS
    from bimcap.methods import ExecutorKind

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--window", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2, help="processes of the pool / cluster")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each way (best is kept)")
    args = ap.parse_args()
    cam = _camera()
    cfg = FrontendConfig(window=args.window)
    n = args.workers
    print(f"# front end, local pool vs Dask LocalCluster: {cam.width}x{cam.height}, "
          f"{args.frames} frames, window {args.window}, {n} workers x 1 thread, "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start")
    with tempfile.TemporaryDirectory() as tmp:
        seq = SceneSequence.write(Path(tmp), camera=cam, poses=_poses(args.frames), lidar=True)

        def run(**kwargs: Any) -> Any:
            return run_frontend(seq, cfg, seq.gt, **_providers(), progress=False, **kwargs)

        t0 = time.perf_counter()
        with (LocalCluster(n_workers=n,  # type: ignore[no-untyped-call]
                           threads_per_worker=1, processes=True,
                           dashboard_address="127.0.0.1:0") as cluster,
              Client(cluster, set_as_default=False) as client):  # type: ignore[no-untyped-call]
            t_start = time.perf_counter() - t0
            ways: dict[str, Callable[[], Any]] = {
                "serial (workers=1)": lambda: run(workers=1),
                f"local pool (workers={n})": lambda: run(workers=n),
                f"Dask, own LocalCluster ({n})": lambda: run(
                    executor=ExecutorOptions(kind=ExecutorKind.DASK, dask_workers=n)),
                f"Dask, running LocalCluster ({n})": lambda: run(executor=client),
            }
            best = dict.fromkeys(ways, np.inf)
            cpu = dict.fromkeys(ways, np.inf)
            results: dict[str, Any] = {}
            for _ in range(args.repeat):
                for name, fn in ways.items():
                    c0, t0 = _cpu_s(), time.perf_counter()
                    results[name] = fn()
                    best[name] = min(best[name], time.perf_counter() - t0)
                    cpu[name] = min(cpu[name], _cpu_s() - c0)
        ref = results["serial (workers=1)"]
        for name, res in results.items():
            same = all(np.array_equal(getattr(res, a), getattr(ref, a))
                       for a in OBSERVATION_ARRAYS)
            assert same, f"{name}: arrays differ from the serial run"
    pool_name = f"local pool (workers={n})"
    pool, pool_cpu = best[pool_name], cpu[pool_name]
    serial = best["serial (workers=1)"]
    print(f"{'way':<32} {'wall s':>7} {'frames/s':>9} {'vs serial':>9} {'vs pool':>8} "
          f"{'CPU s/frame':>12} {'vs pool':>8}  goal: CPU <= {GOAL_CPU_RATIO:.1f}x pool")
    for name, t in best.items():
        goal = ""
        if name.startswith("Dask, running"):
            goal = "met" if cpu[name] / pool_cpu <= GOAL_CPU_RATIO else "NOT met"
        elif name.startswith("Dask"):
            goal = "(pays the cluster's start)"
        print(f"{name:<32} {t:7.2f} {args.frames / t:9.2f} {serial / t:8.2f}x {pool / t:7.2f}x "
              f"{cpu[name] / args.frames:12.2f} {cpu[name] / pool_cpu:7.2f}x  {goal}")
    print(f"LocalCluster start ({n} workers): {t_start:.2f} s; every run's arrays equal the "
          f"serial run's bit for bit; load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
