"""The front end's jobs keep glibc's freed heap between frames (bimcap.frontend.heap)."""

from __future__ import annotations

import platform
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import bimcap

#: The bimcap under test (the source tree with its built ``_core``, or an installed package) and
#: the tests' helpers: the sub-processes import the same ones.
SOURCES = Path(bimcap.__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


_FAULTS = """
    import resource, sys
    import numpy as np
    if sys.argv[-1] == "keep":
        from bimcap.frontend.heap import keep_freed_heap
        assert keep_freed_heap()

    def job():  # a frame's worth of 3.2 MB arrays, touched, then freed together
        arrays = [np.ones(400_000) for _ in range(6)]
        del arrays

    for _ in range(3):
        job()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(30):
        job()
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not GLIBC, reason="mallopt's thresholds are glibc's")
def test_kept_heap_is_not_faulted_in_again(tmp_path: Path) -> None:
    """With glibc's defaults, arrays freed together are trimmed off the heap top and the next
    job faults them in again (~4,600 pages a job here); with the thresholds set, none."""
    script = tmp_path / "faults.py"
    script.write_text(textwrap.dedent(_FAULTS))
    env = {"PYTHONPATH": str(SOURCES), "PATH": "/usr/bin:/bin"}
    faults = {}
    for mode in ("default", "keep"):
        out = subprocess.run([sys.executable, str(script), mode], capture_output=True, text=True,
                             env=env, timeout=120, check=True).stdout
        faults[mode] = int(out.split()[-1])
    assert faults["default"] > 30 * 1000, faults
    assert faults["keep"] < 30 * 20, faults


def test_keep_freed_heap_once_a_process_and_never_raises(monkeypatch: pytest.MonkeyPatch) -> None:
    from bimcap.frontend import heap

    calls: list[int] = []
    monkeypatch.setattr(heap, "_APPLIED", None)
    monkeypatch.setattr(heap, "_mallopt_thresholds", lambda: calls.append(1) or True)
    # a front end run from this process: its jobs here leave the heap alone, nothing tried
    with heap.callers_heap():
        assert heap.keep_freed_heap() is False
    assert calls == [] and heap._CALLERS == 0
    assert heap.keep_freed_heap() and heap.keep_freed_heap()
    assert calls == [1]
    with heap.callers_heap():  # already set (a worker that runs a front end of its own)
        assert heap.keep_freed_heap()
    # another C library (musl, macOS): nothing set, nothing raised
    monkeypatch.undo()
    monkeypatch.setattr(heap, "_APPLIED", None)
    monkeypatch.setattr(platform, "libc_ver", lambda *a, **k: ("", ""))
    assert heap.keep_freed_heap() is False


def test_jobs_in_the_calling_process_leave_its_heap(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Each frame and pair job asks for the thresholds; with one worker they run in the process
    that called run_frontend, whose heap they leave alone."""
    from _frontend_scene import SceneSequence, default_poses
    from bimcap.features import SiftOptions
    from bimcap.frontend import FrontendConfig, heap, run_frontend, runner
    from bimcap.frontend.providers import LidarDepthProvider

    monkeypatch.setattr(heap, "_APPLIED", None)
    answers: list[bool] = []
    monkeypatch.setattr(runner, "keep_freed_heap",
                        lambda: answers.append(heap.keep_freed_heap()) or answers[-1])
    seq = SceneSequence.write(tmp_path / "seq", poses=default_poses(3), lidar=True)
    run_frontend(seq, FrontendConfig(sift=SiftOptions(max_num_features=1500), window=2), seq.gt,
                 LidarDepthProvider(), _AllWalls(), workers=1, progress=False)
    assert answers == [False] * 6  # 3 frames, 3 pairs (window 2)
    assert heap._APPLIED is None


class _AllWalls:
    """Every pixel a wall (the labels do not matter here)."""

    def __call__(self, ctx: object) -> np.ndarray:
        cam = ctx.camera  # type: ignore[attr-defined]
        return np.full((cam.height, cam.width), 1, np.uint8)


_FRONT_END = """
    import sys
    from pathlib import Path
    import numpy as np
    from _frontend_scene import SceneSequence, default_poses
    from bimcap.features import SiftOptions
    from bimcap.frontend import FrontendConfig, heap, run_frontend
    from bimcap.frontend.providers import (
        LidarDepthProvider, PlanarDepthRefiner, SegmenterLabelProvider)
    from bimcap.segmentation.geometric import GeometricSegmenter

    root, mode = Path(sys.argv[1]), sys.argv[2]
    if mode == "keep":  # as in a worker process, before any job
        assert heap.keep_freed_heap()
    seq = SceneSequence.write(root / "seq", poses=default_poses(3), lidar=True)
    res = run_frontend(seq, FrontendConfig(sift=SiftOptions(max_num_features=1500), window=2),
                       seq.gt, LidarDepthProvider(),
                       SegmenterLabelProvider(GeometricSegmenter(), uses_pose=True),
                       depth_refiner=PlanarDepthRefiner(), workers=1, progress=False)
    arrays = {k: v for k, v in vars(res).items() if isinstance(v, np.ndarray)}
    assert len(arrays["match_frames"]) > 0
    np.savez(root / f"{mode}.npz", **arrays)
"""


def test_kept_heap_computes_the_same(tmp_path: Path) -> None:
    """The whole front end (LiDAR, completion, geometric labels, smoothing, SIFT, matching)
    gives the same arrays bit for bit with the thresholds set as with glibc's own, each in a
    fresh process."""
    script = tmp_path / "front_end.py"
    script.write_text(textwrap.dedent(_FRONT_END))
    env = {"PYTHONPATH": f"{SOURCES}:{TESTS}", "PATH": "/usr/bin:/bin", "BIMCAP_CACHE_DIR": "off"}
    for mode in ("default", "keep"):
        (tmp_path / mode).mkdir()
        proc = subprocess.run([sys.executable, str(script), str(tmp_path / mode), mode],
                              capture_output=True, text=True, env=env, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
    with np.load(tmp_path / "default" / "default.npz") as a, \
            np.load(tmp_path / "keep" / "keep.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            assert np.array_equal(a[k], b[k]), k
