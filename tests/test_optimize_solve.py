"""The binding and the CLI: round trip, recovery, errors, the pycolmap oracle, GIL release."""

from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from _solver_helpers import bimcap_solve_binary, core
from bimcap.geometry.trajectory import read_tum
from bimcap.optimize import (
    GeometricMode,
    SolverInputError,
    SolverOptions,
    solve,
    write_problem,
)
from bimcap.optimize.synthetic import make_synthetic_problem, pose_errors


@pytest.fixture(scope="module")
def synthetic():
    core()
    return make_synthetic_problem(
        num_frames=40, seed=11, drift_translation_sigma=0.03, drift_yaw_sigma_deg=0.4
    )


def test_solve_recovers_the_truth(synthetic) -> None:
    t0, r0 = pose_errors(synthetic.problem.poses, synthetic.gt_poses)
    result = solve(synthetic.problem, SolverOptions())
    t1, r1 = pose_errors(result.poses, synthetic.gt_poses)
    assert t0 > 0.1 and r0 > 1.0  # the drift is real
    assert t1 < 0.02 and r1 < 0.2
    s = result.summary
    assert s.success and s.final_cost < s.initial_cost
    # The paper's terms, plus the pose prior that ROBUST weighting adds by default.
    assert {t.name for t in s.terms if t.active} == {"G", "F", "Ce", "W", "Co", "prior", "odometry"}
    assert s.term("W").num_residual_blocks == len(synthetic.problem.wall_frame)
    np.testing.assert_allclose(np.linalg.norm(result.poses[:, 3:], axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(result.poses[0], synthetic.problem.poses[0])  # fixed
    assert json.loads(s.to_json())["terms"][0]["name"] == "G"


def test_paper_objective_matches_numpy(synthetic) -> None:
    p = synthetic.problem
    result = solve(p, SolverOptions.paper().with_terms("G+F+Ce"))
    poses = result.poses
    k = p.cameras[0]

    def world(frames: np.ndarray, p_in_cam: np.ndarray) -> np.ndarray:
        return Rotation.from_quat(poses[frames, 3:]).apply(p_in_cam) + poses[frames, :3]

    def back(uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        return np.column_stack([(uv[:, 0] - k[2]) / k[0] * depth,
                                (uv[:, 1] - k[3]) / k[1] * depth, depth])

    ga = world(p.match_frames[:, 0], back(p.match_uv[:, :2], p.match_depth[:, 0]))
    gb = world(p.match_frames[:, 1], back(p.match_uv[:, 2:], p.match_depth[:, 1]))
    g = np.mean(np.sum((ga - gb) ** 2, axis=1))
    f = np.mean((world(p.floor_frame, p.floor_p_in_cam)[:, 2] - 0.0) ** 2)
    ce = np.mean((world(p.ceiling_frame, p.ceiling_p_in_cam)[:, 2] - 3.0) ** 2)
    expected = 1.0 * g + 0.02 * f + 0.02 * ce
    assert result.summary.final_paper_objective == pytest.approx(expected, rel=1e-9)
    assert result.summary.final_cost == pytest.approx(0.5 * expected, rel=1e-9)


def test_binding_rejects_bad_arrays(synthetic) -> None:
    _core = core()
    arrays = synthetic.problem.arrays()
    flat = SolverOptions().to_flat()
    with pytest.raises(TypeError, match="poses: expected dtype float64"):
        _core.solve({**arrays, "poses": arrays["poses"].astype(np.float32)}, flat)
    with pytest.raises(TypeError, match="floor_frame: expected dtype int32"):
        _core.solve({**arrays, "floor_frame": arrays["floor_frame"].astype(np.int64)}, flat)
    with pytest.raises(TypeError, match="numpy array"):
        _core.solve({**arrays, "poses": arrays["poses"].tolist()}, flat)
    with pytest.raises(ValueError, match="C-contiguous"):
        _core.solve({**arrays, "poses": np.asfortranarray(arrays["poses"])}, flat)
    with pytest.raises(ValueError, match=r"wall_p_in_cam: expected shape \(n, 3\)"):
        _core.solve({**arrays, "wall_p_in_cam": np.zeros((4, 2))}, flat)
    with pytest.raises(ValueError, match="required array missing"):
        _core.solve({k: v for k, v in arrays.items() if k != "cameras"}, flat)
    with pytest.raises(ValueError, match="unknown problem array"):
        _core.solve({**arrays, "extra": np.zeros(1)}, flat)
    bad = arrays["wall_frame"].copy()
    bad[3] = 10_000
    with pytest.raises(_core.InputError, match="wall_frame: row 3"):
        _core.solve({**arrays, "wall_frame": bad}, flat)
    with pytest.raises(ValueError, match="association_gate"):
        _core.solve(arrays, {**flat, "association_gate": "-2"})


def test_binding_takes_a_problem_without_some_terms(synthetic) -> None:
    """A term's arrays may be left out (``_core.solve``'s docstring): the term is empty. Leaving
    out a term's arrays solves exactly as giving them with the term disabled."""
    _core = core()
    arrays = synthetic.problem.arrays()
    required = {name: req for name, _dtype, _cols, req, _term in _core.problem_fields()}
    optional = [k for k in arrays if k.startswith(("column_", "ceiling_")) and not required[k]]
    assert optional
    part = {k: v for k, v in arrays.items() if k not in optional}
    flat = {**SolverOptions().to_flat(), "num_threads": "1"}
    off = {**flat, "column.enabled": "0", "ceiling.enabled": "0"}
    left_out = _core.solve(part, flat)
    disabled = _core.solve(arrays, off)
    assert left_out["summary"]["success"]
    np.testing.assert_array_equal(left_out["poses"], disabled["poses"])


def test_solve_names_the_bad_field(synthetic) -> None:
    arrays = synthetic.problem.arrays()
    broken = {**arrays, "floor_plane": np.full_like(arrays["floor_plane"], 5)}
    with pytest.raises(SolverInputError) as info:
        solve(type(synthetic.problem).from_arrays(broken))
    assert info.value.field == "floor_plane"


def test_cli_matches_the_binding(tmp_path: Path, synthetic) -> None:
    exe = bimcap_solve_binary()
    options = SolverOptions(max_iterations=50)
    path = tmp_path / "problem.bimcap"
    write_problem(path, synthetic.problem, options)
    out = tmp_path / "out"
    run = subprocess.run([str(exe), str(path), "-o", str(out)], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    traj = read_tum(out / "refined.tum")
    result = solve(synthetic.problem, options)
    np.testing.assert_allclose(traj.timestamps, synthetic.problem.timestamps, rtol=0, atol=0)
    np.testing.assert_allclose(traj.poses, result.poses, rtol=0, atol=1e-9)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["iterations"] == result.summary.iterations
    assert summary["final_cost"] == pytest.approx(result.summary.final_cost, rel=1e-9)
    info = subprocess.run([str(exe), str(path), "--info"], capture_output=True, text=True,
                          timeout=60)
    assert info.returncode == 0 and "version 1" in info.stdout and "wall_p_in_cam" in info.stdout


def test_cli_exit_codes(tmp_path: Path) -> None:
    exe = bimcap_solve_binary()
    bad = tmp_path / "bad.bimcap"
    bad.write_bytes(b"BIMCAPPF" + b"\0" * 100)
    run = subprocess.run([str(exe), str(bad), "-o", str(tmp_path / "o")], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and "version" in run.stderr
    run = subprocess.run([str(exe), str(tmp_path / "missing"), "-o", str(tmp_path / "o")],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "cannot open" in run.stderr
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 1 and "usage" in run.stderr
    assert subprocess.run([str(exe), "--help"], capture_output=True, timeout=60).returncode == 0


def test_reprojection_agrees_with_pycolmap() -> None:
    """Residual and Jacobian of the two-frame reprojection functor against pycolmap.

    pycolmap.Camera.img_from_cam projects (PINHOLE); the Jacobian with respect to the world
    point is the one of pycolmap's ``ReprojErrorCost`` (checked directly when pyceres is
    installed, else by central differences of pycolmap's projection).
    """
    pycolmap = pytest.importorskip("pycolmap")
    _core = core()
    rng = np.random.default_rng(7)
    for _ in range(20):
        k = np.array([rng.uniform(300, 900), rng.uniform(300, 900), rng.uniform(200, 400),
                      rng.uniform(150, 300)])
        camera = pycolmap.Camera(model="PINHOLE", width=640, height=480, params=k)
        world_from_a = np.r_[rng.normal(size=3),
                             Rotation.random(random_state=rng.integers(1 << 30)).as_quat()]
        p_a = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(2, 5)])
        p_world = Rotation.from_quat(world_from_a[3:]).apply(p_a) + world_from_a[:3]
        # Camera b 2-6 m in front of the point, random orientation.
        q_b = Rotation.random(random_state=rng.integers(1 << 30))
        t_b = p_world - q_b.apply([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5),
                                   rng.uniform(2, 6)])
        world_from_b = np.r_[t_b, q_b.as_quat()]
        uv_b = rng.uniform([0, 0], [640, 480])
        residual, (jac_a, jac_b) = _core.evaluate_reprojection(world_from_a, world_from_b, p_a,
                                                               uv_b, k)

        b_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(q_b.inv().as_quat()),
                                        -q_b.inv().apply(t_b))

        def project(x: np.ndarray, camera: Any = camera,
                    b_from_world: Any = b_from_world) -> np.ndarray:
            return camera.img_from_cam((b_from_world * x)[None])[0]

        np.testing.assert_allclose(residual, project(p_world) - uv_b, rtol=1e-10, atol=1e-8)
        # d residual / d p_world: the translation columns of frame a's block.
        numeric = np.column_stack([(project(p_world + h) - project(p_world - h)) / 2e-6
                                   for h in np.eye(3) * 1e-6])
        np.testing.assert_allclose(jac_a[:, :3], numeric, rtol=1e-6, atol=1e-6)
        # Moving camera b by +d moves the point by −d in b's frame.
        np.testing.assert_allclose(jac_b[:, :3], -numeric, rtol=1e-6, atol=1e-6)
        _check_against_reproj_error_cost(pycolmap, k, uv_b, b_from_world, p_world, residual,
                                         jac_a[:, :3])


def _check_against_reproj_error_cost(pycolmap, k, uv_b, b_from_world, p_world, residual,
                                     jac_point) -> None:
    try:
        import pyceres  # noqa: F401  (registers ceres::CostFunction for pycolmap)
    except ImportError:
        return
    cost = pycolmap.cost_functions.ReprojErrorCost(pycolmap.CameraModelId.PINHOLE, uv_b,
                                                   b_from_world)
    r, jacobians = cost.evaluate(p_world, k)
    np.testing.assert_allclose(r, residual, rtol=1e-10, atol=1e-8)
    np.testing.assert_allclose(np.asarray(jacobians[0]).reshape(2, 3), jac_point,
                               rtol=1e-8, atol=1e-8)


def test_gil_is_released_while_solving() -> None:
    big = make_synthetic_problem(num_frames=150, seed=2)
    ticks = 0
    done = threading.Event()

    def run() -> None:
        # Solves for at least 0.5 s (one solve of this problem takes ~0.1 s since the compressed
        # batches), so that the count below does not depend on how fast one solve is.
        start = time.perf_counter()
        while time.perf_counter() - start < 0.5:
            solve(big.problem, SolverOptions(num_threads=1))
        done.set()

    worker = threading.Thread(target=run)
    worker.start()
    time.sleep(0.05)  # let the worker enter the solve
    while not done.is_set():
        ticks += 1
        time.sleep(0.001)
    worker.join()
    assert ticks > 20, "the main thread did not run while the solver worked"


def test_landmark_mode_and_covariance(synthetic) -> None:
    options = SolverOptions(geometric_mode=GeometricMode.LANDMARK, compute_covariance=True)
    result = solve(synthetic.problem, options)
    t, r = pose_errors(result.poses, synthetic.gt_poses)
    assert t < 0.03 and r < 0.3
    assert result.summary.linear_solver == "SPARSE_SCHUR"
    assert result.covariance is not None and result.covariance.shape == (40, 6, 6)
    assert np.all(np.linalg.eigvalsh(result.covariance[1:]) > 0)
    err = np.linalg.norm(result.track_points - synthetic.gt_track_points, axis=1)
    assert np.median(err) < 0.05


def test_solve_demo_command(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    core()
    from bimcap.cli import main

    assert main(["solve-demo", "--frames", "20", "--terms", "G,F,W", "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "pose error (RMSE vs ground truth): before" in out
    assert (tmp_path / "refined.tum").is_file() and (tmp_path / "problem.bimcap").is_file()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert {t["name"] for t in summary["terms"] if t["active"]} == {"G", "F", "W", "prior",
                                                                     "odometry"}
