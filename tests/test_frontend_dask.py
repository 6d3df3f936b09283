"""The front end on Dask: a LocalCluster of 2 worker processes gives the local pool's result bit
for bit (depth and label maps, features, matches, the solver's arrays), the frame cache works
from either, a cluster the run starts is closed on every exit path, and a scheduler address that
cannot be reached is one clear error naming it, raised before any work.

Warnings: pytest turns warnings into errors. The one ``distributed`` raised here came from the
scheduler's HTTP server: with ``dashboard_address=None`` it still listens on the default port
8787, and a second scheduler in the same process (this module's cluster and the one a run
starts) fails to bind it and leaves a ``ResourceWarning: unclosed <socket ...>`` before it
falls back to a random port. Both clusters therefore listen on ``127.0.0.1:0`` (the executor
does the same), and no warning is filtered.
"""

from __future__ import annotations

import multiprocessing
import os
import shutil
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from _frontend_scene import SceneSequence, default_poses
from bimcap.features import SiftOptions
from bimcap.frontend import (
    ExecutorOptions,
    FrontendConfig,
    FrontendError,
    FrontendInputError,
    FrontendResult,
    GroundTruthLabelProvider,
    SchedulerUnreachableError,
    run_frontend,
)
from bimcap.frontend.cache import ResultCache
from bimcap.frontend.providers import LidarDepthProvider, PlanarDepthRefiner, SegmenterLabelProvider
from bimcap.frontend.runner import OBSERVATION_ARRAYS, map_paths
from bimcap.geometry.poses import transform_points
from bimcap.methods import ExecutorKind

NUM_FRAMES = 4
CONFIG = FrontendConfig(sift=SiftOptions(max_num_features=1500), window=2)
DASK = ExecutorOptions(kind=ExecutorKind.DASK, dask_workers=2)


def _providers() -> dict[str, Any]:
    """The pipeline's own path: LiDAR → linear completion → geometric labels (uses the pose)
    → planar depth refinement; computed maps, not copied ground truth."""
    from bimcap.segmentation.geometric import GeometricSegmenter

    return {"depth_provider": LidarDepthProvider(),
            "label_provider": SegmenterLabelProvider(GeometricSegmenter(), uses_pose=True),
            "depth_refiner": PlanarDepthRefiner()}


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> SceneSequence:
    return SceneSequence.write(tmp_path_factory.mktemp("seq"), poses=default_poses(NUM_FRAMES),
                               lidar=True)


@pytest.fixture(scope="module")
def client() -> Iterator[Any]:
    """A LocalCluster of 2 worker processes, 1 thread each, random local ports."""
    from distributed import Client, LocalCluster

    with (LocalCluster(n_workers=2,  # type: ignore[no-untyped-call]
                       threads_per_worker=1, processes=True,
                       dashboard_address="127.0.0.1:0") as cluster,
          Client(cluster, set_as_default=False) as c):  # type: ignore[no-untyped-call]
        yield c


def _run(seq: SceneSequence, root: Path, **kwargs: Any) -> FrontendResult:
    return run_frontend(seq, CONFIG, seq.gt, **_providers(), cache_dir=root / "cache",
                        maps_dir=root / "maps", progress=False, **kwargs)


@pytest.fixture(scope="module")
def local(seq: SceneSequence, tmp_path_factory: pytest.TempPathFactory
          ) -> tuple[FrontendResult, Path]:
    """The reference: the local pool of 2 processes."""
    root = tmp_path_factory.mktemp("local")
    return _run(seq, root, workers=2), root


@pytest.fixture(scope="module")
def on_dask(seq: SceneSequence, client: Any, tmp_path_factory: pytest.TempPathFactory
            ) -> tuple[FrontendResult, Path]:
    root = tmp_path_factory.mktemp("dask")
    return _run(seq, root, executor=client), root


def _entries(root: Path, kind: str) -> dict[str, dict[str, np.ndarray]]:
    cache = ResultCache(root / "cache")
    out = {}
    for path in sorted((root / "cache" / kind).glob("*/*.npz")):
        arrays = cache.get(kind, path.stem)
        assert arrays is not None, path
        out[path.stem] = arrays
    return out


def test_dask_equals_the_local_pool_bit_for_bit(
        seq: SceneSequence, local: tuple[FrontendResult, Path],
        on_dask: tuple[FrontendResult, Path]) -> None:
    (ref, ref_root), (res, root) = local, on_dask
    assert (res.run.executor, res.run.workers) == ("dask", 2)
    assert (ref.run.executor, ref.run.workers) == ("local", 2)
    # the solver's arrays
    ref_arrays, arrays = ref.to_problem_arrays(), res.to_problem_arrays()
    assert set(arrays) == set(ref_arrays)
    for name, arr in ref_arrays.items():
        assert arr.dtype == arrays[name].dtype and np.array_equal(arr, arrays[name]), name
    # depth and label maps, byte for byte
    for i in range(NUM_FRAMES):
        for ref_path, path in zip(map_paths(ref_root / "maps", i), map_paths(root / "maps", i),
                                  strict=True):
            assert path.read_bytes() == ref_path.read_bytes(), path
    # features (SIFT), per-frame results and matches: the cache entries each run wrote
    for kind, count in (("features", NUM_FRAMES), ("frame", NUM_FRAMES),
                        ("pair", len(ref.pair_stats))):
        ref_entries, entries = _entries(ref_root, kind), _entries(root, kind)
        assert len(entries) == count and set(entries) == set(ref_entries), kind
        for key, ref_entry in ref_entries.items():
            assert set(entries[key]) == set(ref_entry), (kind, key)
            for name, arr in ref_entry.items():
                if name.endswith("time_s"):
                    continue  # wall-clock timings
                assert np.array_equal(arr, entries[key][name]), (kind, name)
    # not equal by being empty: matches agree with the ground truth, and the computed depth
    # (LiDAR, completed, refined) is the scene's
    m = res.match_frames
    pa = transform_points(seq.gt[m[:, 0]], res.camera.backproject(
        res.match_uv[:, :2], res.match_depth[:, 0], distorted=False))
    pb = transform_points(seq.gt[m[:, 1]], res.camera.backproject(
        res.match_uv[:, 2:], res.match_depth[:, 1], distorted=False))
    assert len(m) > 300 and np.median(np.linalg.norm(pa - pb, axis=1)) < 0.05
    from bimcap.frontend import Undistorter

    und = Undistorter(seq.camera)
    depth = np.load(map_paths(root / "maps", 2)[0])
    truth = und.nearest(seq.load_depth(2))
    both = (depth > 0) & (truth > 0)
    assert both.mean() > 0.5
    assert np.median(np.abs(depth[both] - truth[both]) / truth[both]) < 0.02


def test_the_cache_serves_dask_runs(seq: SceneSequence, client: Any,
                                    on_dask: tuple[FrontendResult, Path],
                                    tmp_path: Path) -> None:
    """A second Dask run over the first one's cache computes nothing; the local pool reads the
    entries the Dask run wrote (same keys) and gives the same arrays; a frame whose entry is
    gone is recomputed on the running cluster, reached by its scheduler's address (as
    ``--dask-scheduler`` does), which is left running."""
    res, root = on_dask
    again = _run(seq, root, executor=client)
    assert (again.run.features_computed, again.run.frames_computed,
            again.run.pairs_computed) == (0, 0, 0)
    shutil.copytree(root / "cache", tmp_path / "cache")
    shutil.copytree(root / "maps", tmp_path / "maps")
    pool = _run(seq, tmp_path, workers=2)
    assert (pool.run.frames_computed, pool.run.pairs_computed) == (0, 0)
    for name in OBSERVATION_ARRAYS:
        assert np.array_equal(getattr(pool, name), getattr(res, name)), name
    next((tmp_path / "cache" / "frame").glob("*/*.npz")).unlink()
    address = client.scheduler.address
    assert address.startswith("tcp://127.0.0.1:")
    by_address = _run(seq, tmp_path, executor=ExecutorOptions(kind=ExecutorKind.DASK,
                                                              scheduler=address))
    assert (by_address.run.frames_computed, by_address.run.pairs_computed) == (1, 0)
    assert (by_address.run.executor, by_address.run.workers) == ("dask", 2)
    for name in OBSERVATION_ARRAYS:
        assert np.array_equal(getattr(by_address, name), getattr(res, name)), name
    assert len(client.nthreads()) == 2  # still running


def _children() -> set[int]:
    return {p.pid for p in multiprocessing.active_children() if p.pid is not None}


def test_a_local_cluster_is_closed_after_an_error(seq: SceneSequence, tmp_path: Path) -> None:
    """``ExecutorOptions(kind=DASK)`` without a scheduler: the run starts its own LocalCluster
    and closes it when a worker's job raises (the error comes back as the job raised it)."""
    before = _children()
    bad = SceneSequence(tmp_path / "bad", seq.camera, list(seq.frames), seq.gt)
    shutil.copytree(seq.root, bad.root)
    (bad.root / bad.frames[2].image).unlink()
    with pytest.raises(FrontendInputError,
                       match=r"frames\[2\]\.image: cannot load image of frame 2") as info:
        run_frontend(bad, CONFIG, bad.gt, **_providers(), progress=False, executor=DASK)
    assert info.value.field == "frames[2].image"
    assert _children() <= before  # no worker process left behind


@pytest.mark.slow
def test_a_local_cluster_is_closed_after_a_run(
        seq: SceneSequence, on_dask: tuple[FrontendResult, Path]) -> None:
    """The run's own LocalCluster gives the same arrays, and is gone afterwards."""
    before = _children()
    res = run_frontend(seq, CONFIG, seq.gt, **_providers(), progress=False, executor=DASK)
    assert (res.run.executor, res.run.workers) == ("dask", 2)
    for name in OBSERVATION_ARRAYS:
        assert np.array_equal(getattr(res, name), getattr(on_dask[0], name)), name
    assert _children() <= before


class _Dies:
    """A depth provider whose worker process dies (as one killed for memory would)."""

    def __call__(self, ctx: Any) -> np.ndarray:  # pragma: no cover - runs in a Dask worker
        os._exit(3)


def test_a_dead_worker_is_a_clear_error(seq: SceneSequence) -> None:
    """Workers that die running a job (no retry here: allowed-failures 0) end the run with a
    FrontendError naming the job, and the run's LocalCluster is closed."""
    import dask

    before = _children()
    with (dask.config.set({"distributed.scheduler.allowed-failures": 0}),
          pytest.raises(FrontendError, match=r"Dask workers died while computing frame \d")):
        run_frontend(seq, CONFIG, seq.gt, _Dies(), GroundTruthLabelProvider(), progress=False,
                     executor=DASK)
    assert _children() <= before


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Counting:
    """A depth provider that must not be called (the run fails before any work)."""

    def __call__(self, ctx: Any) -> np.ndarray:  # pragma: no cover - must not run
        raise AssertionError("the front end ran a job")


def test_unreachable_scheduler_is_a_clear_error(seq: SceneSequence) -> None:
    address = f"tcp://127.0.0.1:{_free_port()}"
    opts = ExecutorOptions(kind=ExecutorKind.DASK, scheduler=address, connect_timeout_s=2.0)
    t0 = time.perf_counter()
    with pytest.raises(SchedulerUnreachableError, match=f"Dask scheduler at {address}") as info:
        run_frontend(seq, CONFIG, seq.gt, _Counting(), GroundTruthLabelProvider(),
                     progress=False, executor=opts)
    assert info.value.field == "dask.scheduler"
    assert time.perf_counter() - t0 < 5.0
    for bad in ("not an address", "tcp://host-without-port", "tcp://:8786"):
        with pytest.raises(SchedulerUnreachableError, match="not a scheduler address"):
            ExecutorOptions(kind=ExecutorKind.DASK, scheduler=bad)


def test_refine_settings_and_flags(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``executor`` + ``[dask]`` in a settings file, the --dask flags, their checks; a bad
    scheduler stops ``bimcap refine`` with exit 2 before it reads anything else."""
    from bimcap.cli import main
    from bimcap.cli.refine import add_config_arguments, config_from_args
    from bimcap.pipeline.config import ConfigError, RefineConfig
    from bimcap.pipeline.refine import executor_options

    toml = tmp_path / "run.toml"
    toml.write_text('executor = "dask"\n[dask]\nscheduler = "tcp://10.1.2.3:8786"\n'
                    'threads_per_worker = 2\n')
    cfg = RefineConfig.from_toml(toml)
    opts = executor_options(cfg)
    assert (opts.kind, opts.scheduler, opts.threads_per_worker) == (
        ExecutorKind.DASK, "tcp://10.1.2.3:8786", 2)
    assert executor_options(RefineConfig()).kind is ExecutorKind.LOCAL

    import argparse

    parser = argparse.ArgumentParser()
    add_config_arguments(parser)
    flags = config_from_args(parser.parse_args(["--config", str(toml), "--dask-workers", "3"]))
    assert flags.executor is ExecutorKind.DASK
    assert flags.dask == {"scheduler": "tcp://10.1.2.3:8786", "threads_per_worker": 2,
                          "workers": 3}
    assert config_from_args(parser.parse_args(["--dask"])).executor is ExecutorKind.DASK
    assert config_from_args(parser.parse_args([])).executor is ExecutorKind.LOCAL

    with pytest.raises(ConfigError, match=r"dask\.colour"):
        executor_options(RefineConfig(executor=ExecutorKind.DASK, dask={"colour": 1}))
    with pytest.raises(ConfigError, match=r"dask\.workers: must be an integer >= 1"):
        executor_options(RefineConfig(executor=ExecutorKind.DASK, dask={"workers": 0}))
    with pytest.raises(ConfigError, match="executor is local"):
        executor_options(RefineConfig(dask={"scheduler": "tcp://10.1.2.3:8786"}))
    with pytest.raises(ConfigError, match="executor"):
        RefineConfig(executor="spark")  # type: ignore[arg-type]

    address = f"tcp://127.0.0.1:{_free_port()}"
    assert main(["refine", str(tmp_path / "no-such-seq"), "-o", str(tmp_path / "out"),
                 "--dask-scheduler", address]) == 2
    err = capsys.readouterr().err
    assert f"cannot reach the Dask scheduler at {address}" in err and "Traceback" not in err


@pytest.mark.slow
def test_refine_on_dask_equals_refine_on_the_local_pool(
        tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """``bimcap refine --dask`` end to end on the tiny simulated building (a relative sequence
    path, which the run resolves for the workers): the refined trajectory is the local pool's,
    byte for byte, and result.json records the executor."""
    import json

    pytest.importorskip("bimcap._core", reason="the C++ core is not built")
    from bimcap.cli import main
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.demo import DemoOptions, make_sequence, make_world

    root = tmp_path_factory.mktemp("world")
    opts = DemoOptions(preset="tiny", frames=8, scale=0.125, fps=2.0,
                       config=RefineConfig(workers=1))
    design, built = make_world(root, opts, quiet=True)
    seq = make_sequence(root, design, built, opts, quiet=True)
    monkeypatch.chdir(seq.parent)
    fast = ["-q", "--no-coarse", "--terms", "G+F+W", "--no-report"]
    assert main(["refine", seq.name, "-o", str(root / "pool"), "--workers", "2", *fast]) == 0
    assert main(["refine", seq.name, "-o", str(root / "dask"), "--dask", "--dask-workers", "2",
                 *fast]) == 0
    refined = (root / "dask" / "refined.tum").read_bytes()
    assert refined == (root / "pool" / "refined.tum").read_bytes()
    assert len(refined.splitlines()) >= 8
    doc = json.loads((root / "dask" / "result.json").read_text())
    assert doc["config"]["executor"] == "dask"
    assert doc["config"]["dask"] == {"workers": 2}
