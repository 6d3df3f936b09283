"""End-to-end: ``simulate`` and ``bimcap simulate`` on generated (design + as-built) and real
IFC."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimcap.cli import main
from bimcap.dataset import read_sequence
from bimcap.labels import Label
from bimcap.sim.render import World
from bimcap.sim.simulator import (
    SimError,
    SimulatorConfig,
    load_ifc_parts,
    sidecar_free_space,
    simulate,
)
from bimcap.sim.walk import FreeSpace, plan_walk


@pytest.fixture(scope="module")
def buildings(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from bimcap.sim.building import as_built, generate_building

    d = tmp_path_factory.mktemp("building")
    design = generate_building(seed=0, ifc_path=d / "design.ifc")
    as_built(design, seed=1, ifc_path=d / "asbuilt.ifc")
    return d / "design.ifc", d / "asbuilt.ifc"


def test_simulate_generated_building(tmp_path: Path, buildings: tuple[Path, Path]) -> None:
    design, built = buildings
    seq = simulate(design, tmp_path / "seq", SimulatorConfig.small(frames=3), seed=2,
                   as_built_ifc=built)
    again = read_sequence(tmp_path / "seq")
    assert len(again.frames) == 3
    assert again.ifc_path is not None and again.ifc_path.resolve() == design.resolve()
    assert seq.source["free_space"] == "polygons" and seq.source["as_built_ifc"] == str(built)
    labels = np.concatenate([np.ravel(again.load_labels(i)) for i in range(3)])
    assert (labels == Label.WALL).mean() > 0.2
    assert (labels == Label.FLOOR).any()
    # the GT poses stand on the storey floor at 1.2-1.7 m
    gt = again.trajectory("gt")
    assert np.all((gt.poses[:, 2] >= 1.2) & (gt.poses[:, 2] <= 1.7))


def test_long_walk_in_as_built_building_keeps_clear(buildings: tuple[Path, Path]) -> None:
    """The planner walks the sidecar's free space, checking clearance on the as-built meshes."""
    _, built = buildings
    world = World.from_parts([p for p in load_ifc_parts(built) if p.label != Label.DOOR])
    side = sidecar_free_space(built)
    assert side is not None
    polygons, z_floor = side
    free = FreeSpace.from_polygons(world, polygons, z_floor)
    walk = plan_walk(free, 120.0, np.random.default_rng(4))
    poses = walk.poses(np.arange(0.0, walk.duration, 0.05))
    assert world.distance(poses[:, :3]).min() > 0.3
    h = poses[:, 2] - z_floor
    assert h.min() >= 1.2 and h.max() <= 1.7


def test_cli_simulate(
    tmp_path: Path, buildings: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    design, _ = buildings
    out = tmp_path / "cli-seq"
    args = ["simulate", str(design), "-o", str(out), "--frames", "2", "--small", "--workers", "1"]
    rc = main([*args, "--no-depth", "--seed", "5"])
    assert rc == 0
    assert "wrote 2 frames (320x239" in capsys.readouterr().out
    seq = read_sequence(out)
    assert not seq.has_depth and seq.has_labels
    # a second run into the same folder is refused with exit status 2 and a clear message
    rc = main(args)
    assert rc == 2
    assert "already holds a sequence" in capsys.readouterr().err


def test_simulate_missing_ifc_is_an_input_error(tmp_path: Path) -> None:
    from bimcap.errors import BimcapError

    with pytest.raises(BimcapError):
        simulate(tmp_path / "nope.ifc", tmp_path / "seq", SimulatorConfig.small(frames=1))
    with pytest.raises(SimError, match="frames"):
        SimulatorConfig.small(frames=0)


@pytest.mark.slow
@pytest.mark.needs_shared
def test_simulate_real_ifc_with_mesh_free_space(tmp_path: Path, ifc_dir: Path) -> None:
    """A real ArchiCAD model with no sidecar: free space comes from the meshes."""
    seq = simulate(ifc_dir / "AC20-FZK-Haus.ifc", tmp_path / "fzk", SimulatorConfig.small(frames=2),
                   seed=0)
    assert seq.source["free_space"] == "meshes"
    assert seq.source["z_floor"] == pytest.approx(0.0, abs=0.05)  # Erdgeschoss at 0 m
    assert seq.source["storey"] == "Erdgeschoss"
    surveys = {s["name"]: s for s in seq.source["walkable"]["surveys"]}
    assert set(surveys) == {"Erdgeschoss", "Dachgeschoss"}
    assert surveys["Erdgeschoss"]["walkable_m2"] > surveys["Dachgeschoss"]["walkable_m2"]
    lab = seq.load_labels(0)
    assert lab is not None and (lab == Label.WALL).any()
