"""Floor / ceiling planes of split levels and basements, and which plane each sample is on.

The oracle is the ray caster: samples are the floor and ceiling pixels a camera sees in the
split-level house (``tests/_split_level.py``), and the true height of each is where its ray hit
the world, not anything the plane code computed.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from _split_level import CEILINGS, FLOORS, build_split_level
from bimcap.bim.plane_choice import (
    PlaneChoiceOptions,
    Rejection,
    choose_planes,
    plane_residual_check,
)
from bimcap.bim.planes import extract_planes, plane_under
from bimcap.geometry.poses import rotmat_to_quat, transform_points
from bimcap.labels import Label
from bimcap.sim.clutter import box_mesh
from bimcap.sim.render import MeshPart, World
from bimcap.sim.simulator import model_parts
from bimcap.sim.walk import camera_rotation


@pytest.fixture(scope="module")
def house(tmp_path_factory: pytest.TempPathFactory):
    from bimcap.bim import load_model

    model = load_model(build_split_level(tmp_path_factory.mktemp("split") / "split.ifc"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        planes = extract_planes(model)
    # the world as seen: without door leaves, with a table (0.75 m, labelled floor: the
    # segmenter's classic mistake) in the left room
    table_v, table_f = box_mesh(np.array([1.0, 3.5, 0.72]), np.array([2.2, 4.5, 0.77]))
    parts = [p for p in model_parts(model) if p.label != Label.DOOR]
    parts.append(MeshPart("table", Label.FLOOR, table_v, table_f))
    return model, planes, World.from_parts(parts)


def test_visible_planes_of_split_level_and_basement(house) -> None:
    """Exactly the surfaces one sees: not the slab top under the finish floor (0.00), not the
    covering's top (2.62), not the roof's underside above the covering (2.80 on the left)."""
    _, planes, _ = house
    got = {(p.kind, p.storey, round(p.height, 3)) for p in planes}
    want = ({(Label.FLOOR, s, h) for s, h in FLOORS}
            | {(Label.CEILING, s, h) for s, h in CEILINGS})
    assert got == want
    right = [p for p in planes if p.kind == Label.CEILING and round(p.height, 2) == 2.8]
    assert right[0].polygon[:, 0].min() > 4.0  # the roof underside only over the right room


def _views(world: World, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """Camera poses in both ground rooms and the basement, looking down 25°, and the floor /
    ceiling samples each sees (p_in_cam, the true world z of the hit, frame)."""
    spots = [(1.5, 1.5, 1.5), (2.5, 2.5, 1.5), (3.0, 4.0, 1.5), (5.5, 1.5, 1.35), (6.5, 3.0, 1.35),
             (5.0, 4.5, 1.35), (2.0, 2.0, -1.5), (6.0, 4.0, -1.5)]
    poses, samples = [], {Label.FLOOR: [], Label.CEILING: []}
    fx, w, h = 120.0, 160, 120
    v, u = np.mgrid[4:h:8, 4:w:8]
    rays = np.stack([(u.ravel() - w / 2) / fx, (v.ravel() - h / 2) / fx, np.ones(u.size)], 1)
    for x, y, z in spots:
        for yaw in rng.uniform(0, 2 * np.pi, 3):
            for pitch in (-25.0, 20.0):
                rot = camera_rotation(yaw, np.deg2rad(pitch), 0.0)[0]
                pose = np.r_[x, y, z, rotmat_to_quat(rot[None])[0]]
                hit = world.cast(np.tile([x, y, z], (len(rays), 1)), rays @ rot.T)
                t = hit["t_hit"]
                ok = np.isfinite(t)
                lab = world.tri_label[np.where(ok, hit["primitive_ids"], 0).astype(np.int64)]
                for kind in (Label.FLOOR, Label.CEILING):
                    sel = ok & (lab == kind)
                    p_cam = rays[sel] * t[sel, None]
                    z_true = transform_points(np.tile(pose, (sel.sum(), 1)), p_cam)[:, 2]
                    samples[kind].append((np.full(sel.sum(), len(poses)), p_cam, z_true))
                poses.append(pose)
    out = {k: tuple(np.concatenate([s[i] for s in v]) for i in range(3))
           for k, v in samples.items()}
    return np.array(poses), out


def _drift(poses: np.ndarray, rng: np.random.Generator, dz: float, tilt_deg: float,
           dxy: float = 0.2, yaw_deg: float = 5.0) -> np.ndarray:
    """Per-frame pose errors: height dz ± 0.05, a tilt of ``tilt_deg`` about a random horizontal
    axis through the camera, yaw, xy."""
    from scipy.spatial.transform import Rotation

    out = poses.copy()
    for i in range(len(poses)):
        axis = np.r_[rng.normal(size=2), 0.0]
        err = Rotation.from_rotvec(np.deg2rad(tilt_deg) * axis / np.linalg.norm(axis)) * \
            Rotation.from_euler("z", rng.uniform(-yaw_deg, yaw_deg), degrees=True)
        out[i, 3:] = (err * Rotation.from_quat(poses[i, 3:])).as_quat()
        out[i, :2] += rng.uniform(-dxy, dxy, 2)
        out[i, 2] += dz + rng.uniform(-0.05, 0.05)
    return out


def _score(planes, planes_arr, choice, samples) -> dict[str, float]:
    """Share of the samples that lie on a plane (true height within 3 cm of a plane over them)
    given that plane, and the share given a wrong one."""
    out = {}
    heights = np.array([p.height for p in planes])
    for kind in (Label.FLOOR, Label.CEILING):
        _frame, _p_cam, z_true = samples[kind]
        idx = choice.choices[kind].plane
        on_plane = np.min(np.abs(z_true[:, None] - heights[None, :]), axis=1) < 0.03
        right = (idx >= 0) & (np.abs(heights[np.maximum(idx, 0)] - z_true) < 0.03)
        wrong = (idx >= 0) & ~right
        out[f"{kind.name.lower()}_right"] = float(right[on_plane].mean())
        out[f"{kind.name.lower()}_wrong"] = float(wrong.mean())
        out[f"{kind.name.lower()}_garbage_kept"] = float((idx[~on_plane] >= 0).mean()
                                                         if (~on_plane).any() else 0.0)
    return out


def test_choice_from_ground_truth_and_from_drift(house) -> None:
    _, planes, world = house
    arr = np.stack([p.plane for p in planes])
    rng = np.random.default_rng(5)
    poses, samples = _views(world, rng)
    inp = {k: (v[0], v[1]) for k, v in samples.items()}
    assert (np.abs(samples[Label.FLOOR][2] - 0.745) < 0.03).sum() > 20  # the table is seen
    # at the true poses, trusting them: every sample on a plane gets it, the table top none (the
    # few wrong ones are hits on the vertical face of the step, which the renderer calls floor)
    truth = choose_planes(planes, arr, inp, poses, PlaneChoiceOptions(frame_model=False))
    s = _score(planes, arr, truth, samples)
    assert s["floor_right"] > 0.97 and s["ceiling_right"] > 0.97, s
    assert s["floor_wrong"] < 0.005 and s["ceiling_wrong"] < 0.005, s
    assert s["floor_garbage_kept"] < 0.05, s
    # drifted poses: 0.5 m too low (below the ground floor, over the basement), 6° of tilt
    for dz in (-0.5, 0.4):
        drifted = _drift(poses, rng, dz, 6.0)
        got = choose_planes(planes, arr, inp, drifted)
        s = _score(planes, arr, got, samples)
        assert s["floor_right"] > 0.85 and s["ceiling_right"] > 0.8, (dz, s)
        assert s["floor_wrong"] < 0.02 and s["ceiling_wrong"] < 0.02, (dz, s)
        counts = got.choices[Label.FLOOR].counts()
        assert counts["assigned"] + counts["no_plane"] + counts["rejected_height"] == \
            counts["samples"]
    # what the nearest-plane rule does with a camera 0.6 m too low: the floor samples sit below
    # the ground floor, so the basement floor 3 m down is "the plane under them"
    drifted = _drift(poses, np.random.default_rng(1), -0.6, 0.0, dxy=0.0, yaw_deg=0.0)
    fl = samples[Label.FLOOR]
    old = plane_under(planes, arr, transform_points(drifted[fl[0]], fl[1]), Label.FLOOR)
    heights = np.array([p.height for p in planes])
    ground = fl[0] < 36  # the first six spots are on the ground storey
    assert np.mean(heights[old[ground & (old >= 0)]] < -2.0) > 0.8
    got = choose_planes(planes, arr, inp, drifted).choices[Label.FLOOR].plane
    assert np.mean(heights[got[ground & (got >= 0)]] < -2.0) == 0.0


def test_residual_check_flags_a_wrong_plane(house) -> None:
    _, planes, world = house
    arr = np.stack([p.plane for p in planes])
    poses, samples = _views(world, np.random.default_rng(2))
    frame, p_cam, z_true = samples[Label.FLOOR]
    heights = np.array([p.height for p in planes])
    floor_q = [i for i, p in enumerate(planes) if p.kind == Label.FLOOR]
    right = np.array([floor_q[int(np.argmin(np.abs(heights[floor_q] - z)))] for z in z_true])
    on = np.abs(heights[right] - z_true) < 0.03
    ok = plane_residual_check("F", frame[on], p_cam[on], right[on], arr, poses)
    assert not ok.failed and ok.median_abs_m < 0.005 and ok.far == 0
    # the sunken floor's samples deliberately given the finish floor 0.17 m above them
    wrong = right.copy()
    sunken = int(np.argmin(np.abs(heights - (-0.15))))
    finish = int(np.argmin(np.abs(heights - 0.02)))
    wrong[wrong == sunken] = finish
    bad = plane_residual_check("F", frame[on], p_cam[on], wrong[on], arr, poses)
    # most of the term is still right (the basement, the finish floor): the term's median is
    # small, but the plane the sunken floor's samples were put on fails
    assert bad.failed and bad.failed_planes == [finish], bad
    assert bad.worst_planes[0]["plane"] == finish and "FAILED" in bad.message()


def test_rejection_reasons_and_bad_input(house) -> None:
    _, planes, _ = house
    arr = np.stack([p.plane for p in planes])
    pose = np.array([[6.0, 3.0, 1.35, 1.0, 0.0, 0.0, 0.0]])  # optical axis straight down
    # straight below the camera: the sunken floor (1.5 m), a table top (0.6 m), and a point
    # outside the house
    p_cam = np.array([[0.0, 0.0, 1.5], [0.1, 0.0, 0.6], [9.0, 0.0, 1.5]])
    got = choose_planes(planes, arr, {Label.FLOOR: (np.zeros(3, int), p_cam)}, pose,
                        PlaneChoiceOptions(frame_model=False))
    c = got.choices[Label.FLOOR]
    assert planes[c.plane[0]].height == pytest.approx(-0.15)
    assert list(c.rejection) == [Rejection.NONE, Rejection.HEIGHT, Rejection.NO_PLANE]
    with pytest.raises(ValueError, match=re.escape("floor sample frames outside 0..0")):
        choose_planes(planes, arr, {Label.FLOOR: (np.array([1]), p_cam[:1])}, pose)


@pytest.mark.slow
@pytest.mark.needs_shared
def test_real_revit_surfaces(ifc_dir: Path) -> None:
    """Duplex: the finish floors (0.013 / 0.019 m) are the floor, not the slab under them
    (0.000); the coverings' undersides (2.600 m) are the ceiling, not their tops (2.657 m),
    which this exporter winds like undersides."""
    from bimcap.bim import load_model

    model = load_model(ifc_dir / "Duplex_A_20110907.ifc", include_furniture=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        planes = extract_planes(model)
    l1_floor = {round(p.height, 3) for p in planes
                if p.kind == Label.FLOOR and p.storey == "Level 1"}
    l1_ceil = {round(p.height, 3) for p in planes
               if p.kind == Label.CEILING and p.storey == "Level 1"}
    assert l1_floor and all(0.012 <= h <= 0.02 for h in l1_floor), l1_floor
    assert l1_ceil == {2.6}, l1_ceil
