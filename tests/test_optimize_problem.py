"""Problem and SolverOptions: validation names the field, normalisation, option round trips."""

from __future__ import annotations

import numpy as np
import pytest

from _solver_helpers import core
from bimcap.optimize import GeometricMode, Loss, Problem, SolverInputError, SolverOptions, Weighting
from bimcap.optimize.synthetic import make_synthetic_problem


@pytest.fixture(scope="module")
def arrays() -> dict[str, np.ndarray]:
    return make_synthetic_problem(num_frames=8, seed=3).problem.arrays()


def test_normalises_dtype_and_defaults() -> None:
    poses = np.array([[0, 0, 0, 0, 0, 0, 1], [1, 0, 0, 0, 0, 0, 1]], dtype=np.float32)
    p = Problem(poses=poses, cameras=[[500, 500, 320, 240]])
    assert p.poses.dtype == np.float64 and p.poses.flags.c_contiguous
    assert p.timestamps.tolist() == [0.0, 1.0]
    assert p.pose_fixed.dtype == np.int32 and p.pose_fixed.tolist() == [0, 0]
    assert p.wall_p_in_cam.shape == (0, 3)


@pytest.mark.parametrize(
    ("name", "mutate", "message"),
    [
        ("poses", lambda a: a["poses"].__setitem__((2, 0), np.nan), "row 2 is not finite"),
        ("poses", lambda a: a["poses"].__setitem__((1, 6), 3.0), "quaternion"),
        ("floor_plane", lambda a: a["floor_plane"].__setitem__(0, 7), "out of range"),
        ("wall_frame", lambda a: a["wall_frame"].__setitem__(0, -1), "out of range"),
        ("segment_class", lambda a: a["segment_class"].__setitem__(0, 2), "neither 1"),
        ("cameras", lambda a: a["cameras"].__setitem__((0, 0), -1.0), "focal"),
        ("match_frames", lambda a: a["match_frames"].__setitem__(0, [1, 1]), "with itself"),
    ],
)
def test_bad_values_name_the_field(arrays: dict[str, np.ndarray], name: str, mutate,
                                   message: str) -> None:
    a = {k: v.copy() for k, v in arrays.items()}
    mutate(a)
    with pytest.raises(SolverInputError, match=message) as info:
        Problem(**a)
    assert info.value.field == name


def test_bad_shapes_and_dtypes(arrays: dict[str, np.ndarray]) -> None:
    a = dict(arrays)
    with pytest.raises(SolverInputError, match="expected shape") as info:
        Problem(**{**a, "wall_p_in_cam": a["wall_p_in_cam"][:, :2]})
    assert info.value.field == "wall_p_in_cam"
    with pytest.raises(SolverInputError, match="integer") as info:
        Problem(**{**a, "floor_frame": a["floor_frame"].astype(np.float64)})
    assert info.value.field == "floor_frame"
    with pytest.raises(SolverInputError, match="expected shape") as info:
        Problem(**{**a, "floor_plane": a["floor_plane"][:-1]})
    assert info.value.field == "floor_plane"
    with pytest.raises(SolverInputError, match="unknown"):
        Problem.from_arrays({**a, "bogus": np.zeros(3)})


def test_options_flat_round_trip_and_keys_match_the_core() -> None:
    o = SolverOptions.paper(geometric_mode=GeometricMode.LANDMARK).with_terms("G+F+W")
    o.floor.loss = Loss.CAUCHY
    o.association_gate = 0.25
    back = SolverOptions.from_flat(o.to_flat())
    assert back == o
    assert back.weighting is Weighting.PAPER and not back.ceiling.enabled and back.depth.enabled
    _core = core()
    assert sorted(o.to_flat()) == sorted(_core.option_keys())
    # The C++ core parses what Python writes, identically.
    assert SolverOptions.from_flat(_core.check_options(o.to_flat())) == o
    assert SolverOptions.from_flat(_core.default_options()) == SolverOptions()


@pytest.mark.parametrize(
    ("change", "field"),
    [({"association_gate": -1.0}, "association_gate"),
     ({"outer_iterations": 0}, "outer_iterations"),
     ({"num_threads": 0}, "num_threads")],
)
def test_bad_options(change: dict[str, object], field: str) -> None:
    o = SolverOptions(**change)  # type: ignore[arg-type]
    with pytest.raises(SolverInputError) as info:
        o.check()
    assert info.value.field == field
    with pytest.raises(SolverInputError, match="unknown option"):
        SolverOptions.from_flat({"no_such": "1"})
    with pytest.raises(SolverInputError, match="unknown term"):
        SolverOptions().with_terms("G+X")
