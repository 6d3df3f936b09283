"""The scan noise-scale solve holds the frames ``_StageSolver.held`` names (lone, unanchored)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import bimcap.optimize as optimize
import bimcap.pipeline.refine as refine
from bimcap.optimize.problem import Problem
from bimcap.pipeline.config import RefineConfig


def test_held_frames_are_fixed_in_every_later_solve(monkeypatch: pytest.MonkeyPatch) -> None:
    poses = np.tile([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 1.0], (4, 1))
    seen: list[np.ndarray] = []

    def build(prepared, init_poses, *args, **kwargs):
        return Problem(init_poses, cameras=[[100.0, 100.0, 50.0, 50.0]]), SimpleNamespace(
            brief=dict)

    def solve(problem, opts, check=True):
        seen.append(np.asarray(problem.pose_fixed).copy())
        return SimpleNamespace(summary=SimpleNamespace(success=True), poses=problem.poses)

    monkeypatch.setattr(refine, "build_problem", build)
    monkeypatch.setattr(optimize, "solve", solve)
    solver = refine._StageSolver(prepared=None, config=RefineConfig(),  # type: ignore[arg-type]
                                 max_dist=None, normals=None)
    stage = SimpleNamespace(name="all")
    opts = optimize.SolverOptions()
    solver.run(stage, opts, poses, None)
    solver.held = frozenset({2})
    solver.run(stage, opts, poses, None)
    solver.run(stage, opts, poses, None)
    assert seen[0].tolist() == [0, 0, 0, 0]
    assert seen[1].tolist() == [0, 0, 1, 0] and seen[2].tolist() == [0, 0, 1, 0]
