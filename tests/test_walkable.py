"""The simulator walks any IFC: storeys, split levels, narrow doors, missing floor slabs.

A split-level house over a basement (``tests/_split_level.py``: floors at 0.02 and −0.15 joined
by a 0.76 m door, a basement at −3.0) and, when ``../shared`` is there, the four real models.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from _split_level import DOOR_X, DOOR_Y, build_split_level
from bimcap.labels import Label
from bimcap.sim.render import SimError, World
from bimcap.sim.simulator import missing_floor_parts, model_parts
from bimcap.sim.walk import WalkConfig, plan_walk
from bimcap.sim.walkable import Level, choose_free_space, door_footprints


@pytest.fixture(scope="module")
def split_level(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object, World, list]:
    from bimcap.bim import load_model

    path = build_split_level(tmp_path_factory.mktemp("split") / "split.ifc")
    model = load_model(path)
    parts = model_parts(model)
    doors = door_footprints([p for p in parts if p.label == Label.DOOR])
    world = World.from_parts([p for p in parts if p.label != Label.DOOR])
    return path, model, world, doors


def _levels(model: object) -> list[Level]:
    return [Level(s.name, s.elevation_m) for s in model.storeys]  # type: ignore[attr-defined]


def test_split_level_storey_walks_both_floor_heights_through_a_narrow_door(split_level) -> None:
    _, model, world, doors = split_level
    choice = choose_free_space(world, _levels(model), storey="Ground", door_polygons=doors)
    free = choice.free
    assert choice.level.name == "Ground" and free.storey == "Ground"
    comp, sizes = free.components(WalkConfig())
    piece = comp == int(np.argmax(sizes))
    heights = {round(float(z), 2) for z in free.floor_z[piece]}
    # one connected piece holds both rooms: the finish floor and the sunken floor
    assert heights >= {0.02, -0.15}, heights
    # the door is a passage: its middle has less than the free-space clearance, yet it is walked
    mid = np.array([[0.5 * sum(DOOR_X), 0.5 * sum(DOOR_Y)]])
    r, c = free.to_cell(mid)[0]
    assert free.passage is not None and free.passage[r, c]
    assert free.clearance[r, c] < WalkConfig().min_clearance_m and piece[r, c]
    # a walk: the camera stays 1.2-1.7 m above the floor it is over, and clear of the walls
    walk = plan_walk(free, 90.0, np.random.default_rng(3))
    poses = walk.poses(np.arange(0.0, walk.duration, 0.1))
    above = poses[:, 2] - free.floor_at(poses[:, :2])
    assert above.min() > 1.1 and above.max() < 1.8, (above.min(), above.max())
    assert world.distance(poses[:, :3]).min() > 0.2
    assert (poses[:, 0] > DOOR_X[1]).any() and (poses[:, 0] < DOOR_X[0]).any()  # both rooms


def test_storey_choice_and_clear_errors(split_level) -> None:
    path, model, world, doors = split_level
    t0 = time.perf_counter()
    best = choose_free_space(world, _levels(model), door_polygons=doors, model_name=str(path))
    assert time.perf_counter() - t0 < 10.0
    by_name = {s.name: s for s in best.surveys}
    assert set(by_name) == {"Basement", "Ground"}
    assert best.level.name == max(by_name, key=lambda k: by_name[k].walkable_m2)
    basement = choose_free_space(world, _levels(model), storey="Basement", door_polygons=doors)
    assert basement.free.z_floor == pytest.approx(-3.0, abs=0.01)
    with pytest.raises(SimError,
                       match=r"no storey named 'Attic' \(storeys: 'Basement', 'Ground'\)"):
        choose_free_space(world, _levels(model), storey="Attic", model_name=str(path))
    t0 = time.perf_counter()
    with pytest.raises(SimError, match=rf"{path.name}: nothing to walk on.*'z=\+7.00'"):
        choose_free_space(world, _levels(model), z_floor=7.0, model_name=str(path))
    assert time.perf_counter() - t0 < 10.0  # fails fast


def test_cli_storey_flag(split_level, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from bimcap.cli import main
    from bimcap.dataset import read_sequence

    path = split_level[0]
    args = ["simulate", str(path), "--small", "--frames", "2", "--workers", "1", "--no-clutter"]
    assert main([*args, "-o", str(tmp_path / "bad"), "--storey", "Attic"]) == 2
    err = capsys.readouterr().err
    assert "no storey named 'Attic'" in err and "split.ifc" in err
    assert main([*args, "-o", str(tmp_path / "seq"), "--storey", "Ground"]) == 0
    assert "walked storey 'Ground'" in capsys.readouterr().out
    seq = read_sequence(tmp_path / "seq")
    assert seq.source["storey"] == "Ground" and seq.source["walkable"]["storey"] == "Ground"


# ------------------------------------------------------------------------- the real models
REAL = {
    # file: (storeys the default may pick, least walkable area m²)
    "AC20-FZK-Haus.ifc": ({"Erdgeschoss"}, 40.0),
    "SampleHouse4.ifc": ({"Ground Floor"}, 20.0),
    "Duplex_A_20110907.ifc": ({"Level 1", "Level 2"}, 15.0),
    "Office_A_20110811.ifc": ({"Level 1", "Level 2"}, 800.0),
}


@pytest.mark.slow
@pytest.mark.needs_shared
@pytest.mark.parametrize("name", sorted(REAL))
def test_real_model_walk_stays_indoors(ifc_dir: Path, name: str) -> None:
    """Each real model: a storey is found in seconds, and a walk on it stays inside rooms."""
    from bimcap.bim import load_model

    model = load_model(ifc_dir / name)
    parts = model_parts(model)
    floors, notes = missing_floor_parts(model)
    if name.startswith("Office"):
        assert floors and any("Level 1" in n for n in notes)  # no floor slabs in that model
    else:
        assert floors == []
    doors = door_footprints([p for p in parts if p.label == Label.DOOR])
    world = World.from_parts([p for p in parts if p.label != Label.DOOR] + floors)
    t0 = time.perf_counter()
    choice = choose_free_space(world, _levels(model), door_polygons=doors, model_name=name)
    seconds = time.perf_counter() - t0
    storeys, least_m2 = REAL[name]
    chosen = next(s for s in choice.surveys if s.name == choice.level.name)
    assert choice.level.name in storeys and chosen.walkable_m2 >= least_m2, choice.to_dict()
    assert seconds < 60.0  # seconds on an idle machine (see the report); generous when shared
    walk = plan_walk(choice.free, 40.0, np.random.default_rng(0))
    poses = walk.poses(np.arange(0.0, walk.duration, 0.25))
    # inside: a roof or ceiling right above, walls around, no triangle within 0.2 m
    up = world.cast(poses[:, :3], np.tile([0.0, 0.0, 1.0], (len(poses), 1)))["t_hit"]
    assert np.all(up < 4.0), up.max()
    assert world.distance(poses[:, :3]).min() > 0.2
    cells = choice.free.to_cell(poses[:, :2])
    assert choice.free.region[cells[:, 0], cells[:, 1]].all()
    above = poses[:, 2] - choice.free.floor_at(poses[:, :2])
    assert above.min() > 1.1 and above.max() < 1.8
