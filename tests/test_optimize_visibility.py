"""Visibility in the W/Co association: with free-side normals (``segment_normal``) a wall point
is never associated with the far face of its wall. Without them, a trajectory that starts within
a wall thickness of the truth settles on the outer faces (the local minimum that kept a stretch
of the demo world's Exp 1 0.19 m off)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _solver_helpers import core
from bimcap.optimize import (
    Problem,
    SolverInputError,
    SolverOptions,
    read_problem,
    solve,
    write_problem,
)
from bimcap.optimize.synthetic import make_synthetic_problem, pose_errors
from bimcap.registration.plan_maps import free_normals

WALL_THICKNESS = 0.2


@pytest.fixture(scope="module")
def thick_walled():
    """The synthetic room with its walls given their outer faces too, and the faces' normals."""
    core()
    sp = make_synthetic_problem(num_frames=30, seed=1, drift_translation_sigma=0.0,
                                drift_yaw_sigma_deg=0.0, drift_pitch_sigma_deg=0.0,
                                fix_first=False)
    p, t = sp.problem, WALL_THICKNESS
    lx, ly = sp.config.size
    outer = np.array([[-t, -t, lx + t, -t], [lx + t, -t, lx + t, ly + t],
                      [lx + t, ly + t, -t, ly + t], [-t, ly + t, -t, -t]])
    seg = np.r_[p.segments, outer]
    cls = np.r_[p.segment_class, np.full(4, 1, np.int32)]
    z = np.r_[p.segment_z, np.tile([0.0, sp.config.height], (4, 1))]
    normals = free_normals(seg, cls)
    return sp, p.replace(segments=seg, segment_class=cls, segment_z=z), normals


def test_free_normals_of_the_room(thick_walled) -> None:
    sp, p, normals = thick_walled
    lx, ly = sp.config.size
    centre = np.array([lx / 2, ly / 2])
    walls = np.flatnonzero(p.segment_class == 1)
    mid = 0.5 * (p.segments[walls, :2] + p.segments[walls, 2:])
    toward = np.einsum("ij,ij->i", normals[walls], centre - mid)
    inner, outer = walls[:4], walls[4:]
    assert (toward[:4] > 0).all(), "inner faces must face the room"
    assert (toward[4:] < 0).all(), "outer faces must face away from it"
    assert len(inner) == len(outer) == 4


def test_far_faces_are_not_a_minimum_with_normals(thick_walled) -> None:
    sp, p, normals = thick_walled
    init = sp.gt_poses.copy()
    init[:, 0] -= 0.17  # the west wall's points land 3 cm from its outer face
    opts = SolverOptions().with_terms("G+F+W")
    without = solve(p.replace(poses=init), opts)
    with_normals = solve(p.replace(poses=init, segment_normal=normals), opts)
    err_without, _ = pose_errors(without.poses, sp.gt_poses)
    err_with, rot_with = pose_errors(with_normals.poses, sp.gt_poses)
    assert err_without > 0.08, "negative control: without normals the alias should hold"
    assert err_with < 0.015 and rot_with < 0.2
    # Every wall point still finds a face: visibility removes aliases, not observations.
    assoc = {a.name: a for a in with_normals.summary.association}
    assert assoc["W"].final.num_associated >= 0.95 * assoc["W"].final.num_points


def test_segment_normal_round_trips_and_is_validated(tmp_path: Path, thick_walled) -> None:
    _, p, normals = thick_walled
    q = p.replace(segment_normal=normals)
    path = tmp_path / "vis.bimcap"
    write_problem(path, q, SolverOptions())
    back, _ = read_problem(path)
    np.testing.assert_array_equal(back.segment_normal, normals)
    c_arrays, _ = core().read_problem_file(str(path))
    np.testing.assert_array_equal(c_arrays["segment_normal"], normals)
    bad = normals.copy()
    bad[2] = [0.5, 0.0]
    with pytest.raises(SolverInputError, match="segment_normal"):
        Problem.from_arrays({**q.arrays(), "segment_normal": bad})
    with pytest.raises(SolverInputError, match="segment_normal"):
        Problem.from_arrays({**q.arrays(), "segment_normal": normals[:-1]})
