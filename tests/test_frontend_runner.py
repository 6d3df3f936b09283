"""The front-end runner end to end on a ray-cast room: accuracy against ground truth, the
solver's array contract, the cache, parallel = serial, and clear errors for bad input."""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from _frontend_scene import TEST_CAMERA, Room, SceneSequence, default_poses
from bimcap.features import MatchFilterOptions, MatchOptions, SiftOptions
from bimcap.frontend import (
    FrameContext,
    FrontendConfig,
    FrontendInputError,
    FrontendResult,
    GroundTruthDepthProvider,
    GroundTruthLabelProvider,
    SemanticSamplingOptions,
    Undistorter,
    run_frontend,
)
from bimcap.frontend.runner import OBSERVATION_ARRAYS
from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import invert, transform_points

NUM_FRAMES = 4
CONFIG = FrontendConfig(sift=SiftOptions(max_num_features=1500), window=2)
DEPTH = GroundTruthDepthProvider()
LABELS = GroundTruthLabelProvider()


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> SceneSequence:
    return SceneSequence.write(tmp_path_factory.mktemp("seq"), poses=default_poses(NUM_FRAMES))


@pytest.fixture(scope="module")
def result(seq: SceneSequence) -> FrontendResult:
    return run_frontend(seq, CONFIG, seq.gt, DEPTH, LABELS, workers=1, progress=False)


def _backproject(res: FrontendResult, poses: np.ndarray, frames: np.ndarray, uv: np.ndarray,
                 depth: np.ndarray) -> np.ndarray:
    return transform_points(poses[frames], res.camera.backproject(uv, depth, distorted=False))


def test_matches_agree_with_ground_truth(seq: SceneSequence, result: FrontendResult) -> None:
    """Both back-projections of a match land on the same world point under the true poses."""
    m = result.match_frames
    assert len(m) > 1000
    pa = _backproject(result, seq.gt, m[:, 0], result.match_uv[:, :2], result.match_depth[:, 0])
    pb = _backproject(result, seq.gt, m[:, 1], result.match_uv[:, 2:], result.match_depth[:, 1])
    err = np.linalg.norm(pa - pb, axis=1)
    assert np.median(err) < 0.03
    assert np.percentile(err, 95) < 0.05
    assert (result.match_depth > 0).all()  # RequireDepth.BOTH by default
    assert (np.abs(m[:, 1] - m[:, 0]) <= CONFIG.window).all()


def test_tracks_agree_with_ground_truth(seq: SceneSequence, result: FrontendResult) -> None:
    """Every track is one world point: observations back-project onto the track point, and the
    track point (initialised from the true poses here) reprojects onto each observation."""
    f, p = result.track_obs_frame, result.track_obs_point
    assert result.track_points.shape[0] == p.max() + 1 > 300
    # no track has two observations in one frame
    assert len(np.unique(p.astype(np.int64) * NUM_FRAMES + f)) == len(p)
    has = result.track_obs_depth > 0
    back = _backproject(result, seq.gt, f[has], result.track_obs_uv[has],
                        result.track_obs_depth[has])
    assert np.median(np.linalg.norm(back - result.track_points[p[has]], axis=1)) < 0.03
    p_cam = transform_points(invert(seq.gt)[f], result.track_points[p])
    uv, _ = result.camera.project(p_cam)
    assert np.median(np.linalg.norm(uv - result.track_obs_uv, axis=1)) < 1.0


def test_semantic_samples_under_ground_truth(seq: SceneSequence, result: FrontendResult) -> None:
    floor = transform_points(seq.gt[result.floor_frame], result.floor_p_in_cam)
    assert len(floor) > 200 and np.abs(floor[:, 2]).max() < 0.02
    assert set(np.unique(result.wall_frame)) == set(range(NUM_FRAMES))


def test_solver_array_contract(result: FrontendResult, tmp_path: Path) -> None:
    arrays = result.to_problem_arrays()
    prefixes = ("floor", "ceiling", "wall", "column")
    expected = {
        "match_frames", "match_uv", "match_depth", "track_obs_frame", "track_obs_point",
        "track_obs_uv", "track_obs_depth", "track_points", "cameras", "frame_camera",
        *(f"{p}_frame" for p in prefixes), *(f"{p}_p_in_cam" for p in prefixes),
    }
    assert set(arrays) == expected
    m, k = len(arrays["match_frames"]), len(arrays["track_obs_frame"])
    shapes = {
        "match_frames": (m, 2), "match_uv": (m, 4), "match_depth": (m, 2), "track_obs_uv": (k, 2),
        "track_obs_depth": (k,), "track_obs_point": (k,), "cameras": (1, 4),
        "frame_camera": (NUM_FRAMES,),
    }
    for name, shape in shapes.items():
        assert arrays[name].shape == shape, name
    for name, arr in arrays.items():
        assert arr.flags.c_contiguous, name
        int_named = name.endswith(("_frame", "_point", "frames", "_camera"))
        assert arr.dtype == (np.int32 if int_named else np.float64), name
    assert np.array_equal(arrays["cameras"][0], TEST_CAMERA.intrinsics)
    # save / load round trip
    path = tmp_path / "frontend.npz"
    result.save(path)
    back = FrontendResult.load(path)
    for name in OBSERVATION_ARRAYS:
        assert np.array_equal(getattr(back, name), getattr(result, name)), name
    assert back.camera == result.camera and back.frame_stats == result.frame_stats
    assert back.to_dict() == result.to_dict()
    np.savez(tmp_path / "bad.npz", x=np.zeros(3))
    with pytest.raises(FrontendInputError, match="meta_json"):
        FrontendResult.load(tmp_path / "bad.npz")


def test_undistortion_matches_a_pinhole_render(seq: SceneSequence) -> None:
    """GT depth of the distorted image, undistorted, equals a direct render of the pinhole
    camera."""
    room = Room()
    direct = room.render(TEST_CAMERA.pinhole(), seq.gt[1]).depth
    und = Undistorter(TEST_CAMERA).nearest(seq.load_depth(1))
    both = (direct > 0) & (und > 0)
    assert both.mean() > 0.9
    rel = np.abs(und[both] - direct[both]) / direct[both]
    assert np.median(rel) < 0.005 and np.percentile(rel, 99) < 0.05


@pytest.mark.slow
def test_cache_reuses_and_invalidates(seq: SceneSequence, result: FrontendResult,
                                      tmp_path: Path) -> None:
    cache = tmp_path / "cache"

    def run(cfg: FrontendConfig) -> FrontendResult:
        return run_frontend(seq, cfg, seq.gt, DEPTH, LABELS, cache_dir=cache, workers=1,
                            progress=False)

    def counts(r: FrontendResult) -> tuple[int, int, int]:
        return r.run.features_computed, r.run.frames_computed, r.run.pairs_computed

    first = run(CONFIG)
    n_pairs = len(first.pair_stats)
    assert counts(first) == (NUM_FRAMES, NUM_FRAMES, n_pairs)
    second = run(CONFIG)
    assert counts(second) == (0, 0, 0)
    assert all(s.cached for s in second.frame_stats)
    for name in OBSERVATION_ARRAYS:
        assert np.array_equal(getattr(second, name), getattr(first, name)), name
        assert np.array_equal(getattr(first, name), getattr(result, name)), name
    # a matching setting: frames reused, every pair redone
    cfg_m = dataclasses.replace(CONFIG, match=MatchOptions(max_ratio=0.75))
    r = run(cfg_m)
    assert counts(r) == (0, 0, n_pairs)
    # a sampling setting: depth/labels/samples redone, SIFT and pairs reused
    cfg_d = dataclasses.replace(CONFIG, sampling=SemanticSamplingOptions(wall_density=10.0))
    r = run(cfg_d)
    assert counts(r) == (0, NUM_FRAMES, 0)
    assert len(r.wall_frame) < len(first.wall_frame)
    assert all(s.sift_time_s == 0.0 for s in r.frame_stats)
    # a filter applies after the cache: nothing recomputed, fewer matches
    cfg_f = dataclasses.replace(CONFIG, filters=MatchFilterOptions(max_initial_distance_m=0.001))
    r = run(cfg_f)
    assert counts(r) == (0, 0, 0)
    assert len(r.match_frames) < len(first.match_frames)
    # an extraction setting: everything redone
    cfg_s = dataclasses.replace(CONFIG, sift=SiftOptions(max_num_features=1400))
    r = run(cfg_s)
    assert counts(r) == (NUM_FRAMES, NUM_FRAMES, n_pairs)
    # one changed input file: that frame and its pairs only
    img = seq.root / seq.frames[2].image
    st = img.stat()
    os.utime(img, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    r = run(CONFIG)
    pairs_with_2 = sum(2 in (p.frame_a, p.frame_b) for p in first.pair_stats)
    assert counts(r) == (1, 1, pairs_with_2)
    # another depth file: that frame's depth-dependent part only
    dep = seq.root / str(seq.frames[1].depth)
    st = dep.stat()
    os.utime(dep, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert counts(run(CONFIG)) == (0, 1, 0)


def test_cache_entries_torn_by_a_power_loss_read_as_misses(seq: SceneSequence,
                                                           result: FrontendResult,
                                                           tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Cache entries are renamed into place without an fsync (a rebuildable cache); an entry
    that a power loss left cut short or zeroed is a miss (get: None), recomputed by the next
    run with the same result, never an error."""
    import bimcap.io.atomic as atomic
    from bimcap.frontend import ResultCache

    def no_fsync(fd: int) -> None:
        raise AssertionError("a cache entry was flushed")

    cache_dir = tmp_path / "cache"
    monkeypatch.setattr(atomic.os, "fsync", no_fsync)
    first = run_frontend(seq, CONFIG, seq.gt, DEPTH, LABELS, cache_dir=cache_dir, workers=1,
                         progress=False)
    monkeypatch.undo()
    assert not list(cache_dir.rglob("*.tmp"))  # renamed into place, nothing left behind
    cache = ResultCache(cache_dir)
    arrays = {"uv": np.linspace(0.0, 1.0, 40).reshape(20, 2), "n": np.array(3)}
    cache.put("t", "ab" + "0" * 62, arrays)
    path = cache_dir / "t" / "ab" / ("ab" + "0" * 62 + ".npz")
    whole = path.read_bytes()
    for cut in range(len(whole)):
        path.write_bytes(whole[:cut])
        assert cache.get("t", "ab" + "0" * 62) is None, cut
    path.write_bytes(bytes(len(whole)))
    assert cache.get("t", "ab" + "0" * 62) is None
    # torn entries of a real run: the next run recomputes them and gives the same arrays
    entries = [*sorted(cache_dir.glob("frame/*/*.npz"))[:2],
               *sorted(cache_dir.glob("pair/*/*.npz"))[:2]]
    for k, entry in enumerate(entries):
        data = entry.read_bytes()
        entry.write_bytes(data[: len(data) // (k + 2)])
    again = run_frontend(seq, CONFIG, seq.gt, DEPTH, LABELS, cache_dir=cache_dir, workers=1,
                         progress=False)
    assert again.run.frames_computed == 2 and again.run.pairs_computed == 2
    for name in OBSERVATION_ARRAYS:
        assert np.array_equal(getattr(again, name), getattr(first, name)), name
        assert np.array_equal(getattr(first, name), getattr(result, name)), name


@dataclasses.dataclass(frozen=True)
class _PoseLabels:
    """A label provider that declares that it uses the initial pose (as the geometric one does)."""

    uses_pose = True

    def __call__(self, ctx: FrameContext) -> np.ndarray:
        return LABELS(ctx)


def test_pose_dependent_provider_recomputes_on_new_poses(seq: SceneSequence,
                                                         tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    poses = seq.gt.copy()
    r = run_frontend(seq, CONFIG, poses, DEPTH, _PoseLabels(), cache_dir=cache, workers=1,
                     progress=False)
    assert r.run.frames_computed == NUM_FRAMES
    poses[1, 2] += 0.05
    r = run_frontend(seq, CONFIG, poses, DEPTH, _PoseLabels(), cache_dir=cache, workers=1,
                     progress=False)
    assert (r.run.features_computed, r.run.frames_computed, r.run.pairs_computed) == (0, 1, 0)
    # a provider that does not use the pose ignores pose changes, unless the label check (which
    # takes gravity from the pose) is on: then the changed frame is redone
    off = dataclasses.replace(CONFIG, sampling=SemanticSamplingOptions(orientation_check_deg=None))
    r0 = run_frontend(seq, off, seq.gt, DEPTH, LABELS, cache_dir=cache, workers=1, progress=False)
    r1 = run_frontend(seq, off, poses, DEPTH, LABELS, cache_dir=cache, workers=1, progress=False)
    assert r0.run.frames_computed == NUM_FRAMES and r1.run.frames_computed == 0
    r2 = run_frontend(seq, CONFIG, seq.gt, DEPTH, LABELS, cache_dir=cache, workers=1,
                      progress=False)
    r3 = run_frontend(seq, CONFIG, poses, DEPTH, LABELS, cache_dir=cache, workers=1,
                      progress=False)
    assert r2.run.frames_computed == NUM_FRAMES and r3.run.frames_computed == 1


@pytest.mark.slow
def test_parallel_equals_serial(seq: SceneSequence, result: FrontendResult) -> None:
    par = run_frontend(seq, CONFIG, seq.gt, DEPTH, LABELS, workers=2, progress=False)
    assert par.run.workers == 2
    for name in OBSERVATION_ARRAYS:
        assert np.array_equal(getattr(par, name), getattr(result, name)), name


@pytest.mark.slow
def test_distance_filter_uses_initial_poses(seq: SceneSequence, result: FrontendResult,
                                            tmp_path: Path) -> None:
    """Frame 3 displaced by 1 m in the initial poses: the 0.4 m filter drops all its matches."""
    init = seq.gt.copy()
    init[3, 0] += 1.0
    cache = tmp_path / "c"
    r = run_frontend(seq, CONFIG, init, DEPTH, LABELS, cache_dir=cache, workers=1, progress=False)
    assert len(r.match_frames) > 0 and not (r.match_frames == 3).any()
    assert (result.match_frames == 3).any()
    # tracks: frame 3's observations with depth are dropped too (the track median is elsewhere)
    f3 = r.track_obs_frame == 3
    assert (result.track_obs_frame == 3).sum() > 100 and not (r.track_obs_depth[f3] > 0).any()
    assert len(r.track_points) > 0.8 * len(result.track_points)
    off = dataclasses.replace(CONFIG, filters=MatchFilterOptions(max_initial_distance_m=None))
    r = run_frontend(seq, off, init, DEPTH, LABELS, cache_dir=cache, workers=1, progress=False)
    assert len(r.match_frames) == len(result.match_frames)


def _copy_seq(seq: SceneSequence, dest: Path, camera: Camera | None = None) -> SceneSequence:
    shutil.copytree(seq.root, dest)
    return SceneSequence(dest, camera or seq.camera, list(seq.frames), seq.gt)


def test_missing_frame_is_a_clear_error(seq: SceneSequence, tmp_path: Path) -> None:
    bad = _copy_seq(seq, tmp_path / "s")
    (bad.root / bad.frames[2].image).unlink()
    with pytest.raises(FrontendInputError, match=r"frame 2") as info:
        run_frontend(bad, CONFIG, bad.gt, DEPTH, LABELS, workers=1, progress=False)
    assert info.value.field == "frames[2].image"
    # the same error comes back from a worker process
    with pytest.raises(FrontendInputError,
                       match=r"frames\[2\]\.image: cannot load image of frame 2"):
        run_frontend(bad, CONFIG, bad.gt, DEPTH, LABELS, workers=2, progress=False)


def test_image_size_mismatch_is_a_clear_error(seq: SceneSequence, tmp_path: Path) -> None:
    wrong = Camera(640, 480, *TEST_CAMERA.intrinsics, TEST_CAMERA.dist)
    bad = _copy_seq(seq, tmp_path / "s", camera=wrong)
    with pytest.raises(FrontendInputError, match=r"image is 320x240, the camera is 640x480"):
        run_frontend(bad, CONFIG, bad.gt, DEPTH, LABELS, workers=1, progress=False)


def _half_depth(ctx: FrameContext) -> np.ndarray:
    return np.ones((ctx.pinhole.height // 2, ctx.pinhole.width), np.float32)


def test_provider_size_and_pose_count_errors(seq: SceneSequence) -> None:
    with pytest.raises(FrontendInputError,
                       match=r"depth \(from the depth provider\) has shape \(120, 320\)"):
        run_frontend(seq, CONFIG, seq.gt, _half_depth, LABELS, workers=1, progress=False)
    with pytest.raises(FrontendInputError, match="3 initial poses for 4 frames"):
        run_frontend(seq, CONFIG, seq.gt[:3], DEPTH, LABELS, workers=1, progress=False)


def test_with_a_bimcap_dataset_sequence(seq: SceneSequence, tmp_path: Path) -> None:
    """The real sequence reader (bimcap.dataset) drives the runner the same way."""
    from bimcap.dataset import SequenceWriter, read_sequence

    root = tmp_path / "ds"
    with SequenceWriter(root, seq.camera, [0.0, 0, 0, 0, 0, 0, 1]) as w:
        for i in range(3):
            w.add_frame(
                seq.frames[i].timestamp, seq.load_image(i), np.zeros((0, 4), np.float32),
                labels=seq.load_labels(i), depth=seq.load_depth(i),
            )
        w.add_trajectory("gt", seq.gt[:3])
    real = read_sequence(root)
    gt = real.trajectory("gt")
    cache = tmp_path / "cache"
    res = run_frontend(real, CONFIG, gt, DEPTH, LABELS, cache_dir=cache, workers=1, progress=False)
    m = res.match_frames
    pa = _backproject(res, gt.poses, m[:, 0], res.match_uv[:, :2], res.match_depth[:, 0])
    pb = _backproject(res, gt.poses, m[:, 1], res.match_uv[:, 2:], res.match_depth[:, 1])
    assert len(m) > 500 and np.median(np.linalg.norm(pa - pb, axis=1)) < 0.03
    again = run_frontend(real, CONFIG, gt, DEPTH, LABELS, cache_dir=cache, workers=1,
                         progress=False)
    assert (again.run.frames_computed, again.run.pairs_computed) == (0, 0)


def test_maps_are_written(seq: SceneSequence, result: FrontendResult, tmp_path: Path) -> None:
    import cv2

    from bimcap.frontend.runner import map_paths

    maps = tmp_path / "maps"
    cache = tmp_path / "cache"
    r = run_frontend(seq, CONFIG, seq.gt, DEPTH, LABELS, cache_dir=cache, workers=1,
                     progress=False, maps_dir=maps)
    und = Undistorter(TEST_CAMERA)
    for i in range(NUM_FRAMES):
        d_path, l_path = map_paths(maps, i)
        assert np.array_equal(np.load(d_path), und.nearest(seq.load_depth(i)))
        assert np.array_equal(cv2.imread(str(l_path), cv2.IMREAD_UNCHANGED),
                              und.nearest(seq.load_labels(i)))
    map_paths(maps, 1)[1].unlink()
    r = run_frontend(seq, CONFIG, seq.gt, DEPTH, LABELS, cache_dir=cache, workers=1,
                     progress=False, maps_dir=maps)
    assert (r.run.features_computed, r.run.frames_computed, r.run.pairs_computed) == (0, 1, 0)
    assert map_paths(maps, 1)[1].is_file()


def test_on_a_simulated_sequence(tmp_path: Path) -> None:
    """The simulator's sequence: matches agree with its ground truth."""
    from bimcap.dataset import read_sequence
    from bimcap.sim.simulator import SimulatorConfig, corridor_building, simulate_world

    parts, polys, doors = corridor_building(rooms_per_side=2)
    out = tmp_path / "sim"
    simulate_world(parts, out, SimulatorConfig.small(frames=4), seed=3, free_polygons=polys,
                   doors_xy=doors)
    seq = read_sequence(out)
    gt = seq.trajectory("gt")
    res = run_frontend(seq, CONFIG, gt, DEPTH, LABELS, workers=1, progress=False)
    m = res.match_frames
    assert len(m) > 100
    pa = _backproject(res, gt.poses, m[:, 0], res.match_uv[:, :2], res.match_depth[:, 0])
    pb = _backproject(res, gt.poses, m[:, 1], res.match_uv[:, 2:], res.match_depth[:, 1])
    assert np.median(np.linalg.norm(pa - pb, axis=1)) < 0.03
    floor = transform_points(gt.poses[res.floor_frame], res.floor_p_in_cam)
    assert len(floor) > 0


def test_arrays_pass_the_solvers_validation(seq: SceneSequence, result: FrontendResult) -> None:
    """Oracle: bimcap.optimize.Problem (the solver side's own checks) accepts the arrays."""
    from bimcap.optimize import Problem

    arrays = result.to_problem_arrays()
    n = result.num_frames
    arrays.update(
        poses=seq.gt,
        timestamps=np.arange(n, dtype=np.float64),
        pose_fixed=np.zeros(n, np.int32),
        floor_plane=np.zeros(len(result.floor_frame), np.int32),
        ceiling_plane=np.zeros(len(result.ceiling_frame), np.int32),
        planes=np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, -1.0, 2.8]]),
    )
    problem = Problem.from_arrays(arrays)
    assert np.array_equal(problem.match_uv, result.match_uv)
    assert np.array_equal(problem.track_obs_point, result.track_obs_point)


def test_a_blank_frame_gives_no_features_and_no_error(seq: SceneSequence, tmp_path: Path) -> None:
    import cv2

    bad = _copy_seq(seq, tmp_path / "s")
    cv2.imwrite(str(bad.root / bad.frames[1].image), np.zeros((240, 320, 3), np.uint8))
    r = run_frontend(bad, CONFIG, bad.gt, DEPTH, LABELS, workers=1, progress=False)
    assert r.frame_stats[1].num_keypoints == 0
    assert not (r.match_frames == 1).any() and not (r.track_obs_frame == 1).any()
    assert (r.match_frames == 2).any()
    assert (r.wall_frame == 1).any()  # depth and labels still give semantic samples
