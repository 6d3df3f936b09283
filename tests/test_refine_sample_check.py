"""Wrong-label samples (a window blob labelled wall, in front of the wall, inside the solver's
0.5 m association gate) turn a frame that little else holds; once the solve converged,
:func:`bimcap.registration.sample_check.inconsistent_samples` finds them and a second solve
without them returns near the truth (gen-small-s3 hard, frame 55)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from _solver_helpers import core
from bimcap.optimize import Problem, SolverOptions, solve
from bimcap.optimize.synthetic import pose_errors
from bimcap.pipeline.refine import sample_gate_for_noise
from bimcap.registration.plan_maps import free_normals
from bimcap.registration.sample_check import inconsistent_samples

ROOM = 4.0  # a square room, walls from 0 to ROOM in x and y, 2.6 m high
#: world_from_cam of a camera at the room's centre looking east (+x), optical axes: its x to
#: the south (-y), its y down (-z), its z east; TUM order.
POSE = np.array([2.0, 2.0, 1.5, *Rotation.from_matrix([[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
                 .as_quat()])


def _room_problem(blob: bool) -> tuple[Problem, np.ndarray]:
    """One frame in the room, its wall samples on three walls (1 cm of noise) and, with
    ``blob``, twelve wrong-label samples 0.3 m in front of the east wall, on one side."""
    rng = np.random.default_rng(3)
    walls = []
    for x0, y0, x1, y1 in ((0, 0, ROOM, 0), (ROOM, 0, ROOM, ROOM), (0, ROOM, ROOM, ROOM)):
        s = rng.uniform(0.1, 0.9, 12)
        walls.append(np.c_[x0 + s * (x1 - x0), y0 + s * (y1 - y0), rng.uniform(0.3, 2.3, 12)])
    p_world = np.concatenate(walls)
    p_world[:, :2] += rng.normal(0, 0.01, (len(p_world), 2))
    if blob:
        p_world = np.r_[p_world, np.c_[np.full(8, ROOM - 0.35), rng.uniform(2.6, 3.6, 8),
                                       rng.uniform(1.0, 2.0, 8)]]
    r = Rotation.from_quat(POSE[3:])
    p_cam = r.inv().apply(p_world - POSE[:3])
    seg = np.array([[0, 0, ROOM, 0], [ROOM, 0, ROOM, ROOM], [ROOM, ROOM, 0, ROOM],
                    [0, ROOM, 0, 0]], float)
    cls = np.ones(4, np.int32)
    init = POSE.copy()
    problem = Problem.from_arrays({
        "poses": init[None], "timestamps": np.zeros(1), "pose_fixed": np.zeros(1, np.int32),
        "cameras": np.array([[300.0, 300.0, 160.0, 120.0]]), "frame_camera": np.zeros(1, np.int32),
        "wall_frame": np.zeros(len(p_cam), np.int32), "wall_p_in_cam": p_cam,
        "segments": seg, "segment_class": cls, "segment_z": np.tile([0.0, 2.6], (4, 1)),
        "segment_normal": free_normals(seg, cls)})
    return problem, POSE[None]


def test_a_blob_of_wrong_wall_labels_is_dropped_and_the_frame_returns() -> None:
    core()
    opts = SolverOptions().with_terms("W")
    clean, gt = _room_problem(blob=False)
    with_blob, _ = _room_problem(blob=True)
    _, rot_clean = pose_errors(solve(clean, opts).poses, gt)
    pulled = solve(with_blob, opts)
    _, rot_pulled = pose_errors(pulled.poses, gt)
    assert rot_clean < 0.5
    assert rot_pulled > 1.0, "negative control: the blob should turn the frame"
    check = inconsistent_samples(with_blob.arrays(), pulled.poses, gate_m=0.24)
    keep = check.keep["wall"]
    assert check.dropped["wall"] >= 8 and not keep[:36].sum() < 35, check.to_dict()
    a = with_blob.arrays()
    again = solve(with_blob.replace(poses=pulled.poses, wall_frame=a["wall_frame"][keep],
                                    wall_p_in_cam=a["wall_p_in_cam"][keep]), opts)
    _, rot_again = pose_errors(again.poses, gt)
    assert rot_again < 0.5 and abs(rot_again - rot_clean) < 0.05


def test_a_misplaced_frame_keeps_its_samples() -> None:
    problem, gt = _room_problem(blob=True)
    far = gt.copy()
    far[0, :2] += 1.0  # every sample is now far from its wall: the frame is wrong, not them
    check = inconsistent_samples(problem.arrays(), far, gate_m=0.24)
    assert check.total_dropped == 0 and check.misplaced == [0]
    assert check.keep["wall"].all()
    assert inconsistent_samples(problem.arrays(), gt, gate_m=0.24).frames == [0]


def test_the_gate_follows_the_range_noise() -> None:
    assert sample_gate_for_noise(0.08) == pytest.approx(0.24)
    assert sample_gate_for_noise(0.03) == pytest.approx(0.09)
    assert sample_gate_for_noise(None) is None and sample_gate_for_noise(float("nan")) is None
    with pytest.raises(ValueError, match="gate_m"):
        inconsistent_samples(_room_problem(blob=False)[0].arrays(), POSE[None], gate_m=0.0)
