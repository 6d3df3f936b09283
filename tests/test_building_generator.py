"""The parametric IFC building generator: counts, units, geometry against the sidecar, determinism,
the as-built variant and the walkable space."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ifcopenshell")
import ifcopenshell.geom
import ifcopenshell.guid
import ifcopenshell.util.element
import ifcopenshell.util.placement
import ifcopenshell.util.unit

from bimcap.cli import main as cli_main
from bimcap.sim.building import (
    BuildingSpec,
    BuildingSpecError,
    GeneratedBuilding,
    as_built,
    expected_counts,
    generate_building,
    truth_path_for,
)
from bimcap.sim.building_truth import (
    BuildingTruthError,
    ColumnShape,
    Region,
    Variant,
    WallKind,
    load_building_truth,
)

ELEMENT_CLASSES = ("IfcBuildingStorey", "IfcWall", "IfcSlab", "IfcCovering", "IfcColumn",
                   "IfcDoor", "IfcWindow", "IfcOpeningElement")


def _bounds(f: ifcopenshell.file) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Name -> (min xyz, max xyz) of every tessellated product, world coordinates."""
    settings = ifcopenshell.geom.settings()
    settings.set(settings.USE_WORLD_COORDS, True)
    it = ifcopenshell.geom.iterator(settings, f)
    assert it.initialize()
    out = {}
    while True:
        shape = it.get()
        v = np.asarray(shape.geometry.verts, dtype=np.float64).reshape(-1, 3)
        out[f.by_guid(shape.guid).Name] = (v.min(0), v.max(0))
        if not it.next():
            break
    return out


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> GeneratedBuilding:
    return generate_building(BuildingSpec(), 0, tmp_path_factory.mktemp("demo") / "demo.ifc")


@pytest.fixture(scope="module")
def demo_built(demo: GeneratedBuilding, tmp_path_factory: pytest.TempPathFactory
               ) -> GeneratedBuilding:
    return as_built(demo, 7, ifc_path=tmp_path_factory.mktemp("built") / "built.ifc")


@pytest.fixture(scope="module")
def demo_bounds(demo: GeneratedBuilding) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    assert demo.ifc_path is not None
    return _bounds(ifcopenshell.open(str(demo.ifc_path)))


def _counts(f: ifcopenshell.file) -> dict[str, int]:
    return {cls: len(f.by_type(cls)) for cls in ELEMENT_CLASSES}


# --- counts, units, storeys -------------------------------------------------------------------


def test_demo_counts_read_back_from_file(demo: GeneratedBuilding) -> None:
    f = ifcopenshell.open(str(demo.ifc_path))
    assert f.schema == "IFC4"
    # Hand count: 4 exterior + 2 corridor + 2 north + 3 south partitions; 7 rooms -> 7 doors + the
    # entrance, 7 windows + the corridor end; 2 corridor columns + the hall; base slab + roof;
    # a suspended ceiling per room and the corridor.
    assert _counts(f) == {"IfcBuildingStorey": 1, "IfcWall": 11, "IfcSlab": 2, "IfcCovering": 8,
                          "IfcColumn": 3, "IfcDoor": 8, "IfcWindow": 8, "IfcOpeningElement": 16}
    assert demo.truth.counts == _counts(f) == expected_counts(demo.spec)
    assert sorted(s.PredefinedType for s in f.by_type("IfcSlab")) == ["BASESLAB", "ROOF"]
    assert [c.PredefinedType for c in f.by_type("IfcCovering")] == ["CEILING"] * 8
    assert len(f.by_type("IfcRelVoidsElement")) == 16
    assert len(f.by_type("IfcRelFillsElement")) == 16


@pytest.mark.parametrize("preset", ["tiny", "tower"])
def test_preset_counts(preset: str, tmp_path: Path) -> None:
    spec = getattr(BuildingSpec, preset)()
    b = generate_building(spec, 3, tmp_path / "b.ifc")
    counts = _counts(ifcopenshell.open(str(tmp_path / "b.ifc")))
    if preset == "tiny":  # 6 walls, 2 room doors + entrance, 2 windows + corridor end, 2 columns
        assert counts == {"IfcBuildingStorey": 1, "IfcWall": 6, "IfcSlab": 2, "IfcCovering": 3,
                          "IfcColumn": 2, "IfcDoor": 3, "IfcWindow": 3, "IfcOpeningElement": 6}
    else:  # three demo storeys, one entrance, one roof
        assert counts == {"IfcBuildingStorey": 3, "IfcWall": 33, "IfcSlab": 4, "IfcCovering": 24,
                          "IfcColumn": 9, "IfcDoor": 22, "IfcWindow": 24,
                          "IfcOpeningElement": 46}
    assert counts == b.truth.counts


# IfcOpenShell's rule executor leaves its rules file open (a ResourceWarning, not our bug).
@pytest.mark.filterwarnings("ignore::ResourceWarning",
                            "ignore::pytest.PytestUnraisableExceptionWarning")
def test_schema_valid(tmp_path: Path) -> None:
    """IfcOpenShell's validator (attribute types, inverse counts, EXPRESS where-rules) is silent."""
    import gc

    import ifcopenshell.validate

    generate_building(BuildingSpec.tiny(), 0, tmp_path / "t.ifc")
    logger = ifcopenshell.validate.json_logger()
    ifcopenshell.validate.validate(ifcopenshell.open(str(tmp_path / "t.ifc")), logger,
                                   express_rules=True)
    gc.collect()  # let the leaked file handle go while the warning filter is active
    assert logger.statements == []


def test_units_are_metres(demo: GeneratedBuilding) -> None:
    f = ifcopenshell.open(str(demo.ifc_path))
    assert ifcopenshell.util.unit.calculate_unit_scale(f) == 1.0
    (length,) = [u for u in f.by_type("IfcSIUnit") if u.UnitType == "LENGTHUNIT"]
    assert length.Name == "METRE" and length.Prefix is None


def test_storey_elevations(tmp_path: Path) -> None:
    spec = BuildingSpec(storeys=3, storey_height_m=3.3)
    b = generate_building(spec, 0, tmp_path / "t.ifc")
    f = ifcopenshell.open(str(tmp_path / "t.ifc"))
    storeys = sorted(f.by_type("IfcBuildingStorey"), key=lambda s: s.Elevation)
    assert [s.Elevation for s in storeys] == pytest.approx([0.0, 3.3, 6.6])
    for s in storeys:
        z = ifcopenshell.util.placement.get_local_placement(s.ObjectPlacement)[2, 3]
        assert z == pytest.approx(s.Elevation)
    assert [s.ceiling_z for s in b.truth.storeys] == pytest.approx([2.7, 6.0, 9.3])
    bounds = _bounds(f)
    for s in b.truth.storeys:  # the floor slab's top is the elevation, the ceiling is on time
        assert bounds[f"S{s.index}/slab/floor"][1][2] == pytest.approx(s.floor_z, abs=1e-6)
        assert bounds[f"S{s.index}/ceiling/north-1"][0][2] == pytest.approx(s.ceiling_z, abs=1e-6)
        assert bounds[f"S{s.index}/ceiling/corridor"][0][2] == pytest.approx(
            s.floor_z + spec.corridor_ceiling_height_m, abs=1e-6)
        for w in (w for w in b.truth.walls if w.storey == s.index):
            lo, hi = bounds[w.id]
            assert (lo[2], hi[2]) == pytest.approx((s.floor_z, s.wall_top_z), abs=1e-6)
            np.testing.assert_allclose(lo[:2], w.faces.reshape(-1, 2).min(0), atol=1e-3)
        # every element of this storey is contained in it
        storey = next(x for x in storeys if x.Name == s.name)
        contained = {e.Name for r in storey.ContainsElements for e in r.RelatedElements}
        assert {w.id for w in b.truth.walls if w.storey == s.index} <= contained


# --- geometry against the sidecar ---------------------------------------------------------------


def _wall_box_from_faces(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pts = faces.reshape(-1, 2)
    return pts.min(0), pts.max(0)


@pytest.mark.parametrize("variant", ["design", "as_built"])
def test_wall_geometry_matches_face_lines(variant: str, demo: GeneratedBuilding,
                                          demo_built: GeneratedBuilding,
                                          demo_bounds: dict) -> None:
    b = demo if variant == "design" else demo_built
    bounds = demo_bounds if variant == "design" else _bounds(ifcopenshell.open(str(b.ifc_path)))
    for w in b.truth.walls:
        lo, hi = bounds[w.id]
        flo, fhi = _wall_box_from_faces(w.faces)
        np.testing.assert_allclose(lo[:2], flo, atol=1e-3, err_msg=w.id)
        np.testing.assert_allclose(hi[:2], fhi, atol=1e-3, err_msg=w.id)
        assert (lo[2], hi[2]) == pytest.approx((w.z_min, w.z_max), abs=1e-3)
        # the two face lines are thickness apart and parallel to the centre line
        f0, f1 = w.faces
        assert np.linalg.norm(f0[:2] - f1[:2]) == pytest.approx(w.thickness)
        assert np.dot(f0[2:] - f0[:2], w.normal) == pytest.approx(0.0, abs=1e-12)


def test_column_and_slab_geometry(demo: GeneratedBuilding, demo_bounds: dict) -> None:
    shapes = sorted(c.shape for c in demo.truth.columns)
    assert shapes.count(ColumnShape.ROUND) == 1 and len(shapes) == 3
    for c in demo.truth.columns:
        lo, hi = demo_bounds[c.id]
        half = np.array([c.radius, c.radius]) if c.shape is ColumnShape.ROUND \
            else np.asarray(c.size) / 2
        np.testing.assert_allclose((lo[:2] + hi[:2]) / 2, c.center, atol=1e-3)
        np.testing.assert_allclose((hi[:2] - lo[:2]) / 2, half, atol=1e-3)
    for s in (*demo.truth.slabs, *demo.truth.coverings):
        lo, hi = demo_bounds[s.id]
        poly = np.asarray(s.polygon)
        np.testing.assert_allclose(lo, [*poly.min(0), s.z_min], atol=1e-3)
        np.testing.assert_allclose(hi, [*poly.max(0), s.z_max], atol=1e-3)


def test_openings_cut_their_host(demo: GeneratedBuilding, demo_bounds: dict) -> None:
    f = ifcopenshell.open(str(demo.ifc_path))
    for o in (*demo.truth.doors, *demo.truth.windows):
        opening = f.by_guid(o.opening_guid)
        assert opening.VoidsElements[0].RelatingBuildingElement.Name == o.host_wall
        fill = f.by_guid(o.fill_guid)
        assert fill.Name == o.id and fill.FillsVoids[0].RelatingOpeningElement == opening
        lo, hi = demo_bounds[o.id + "/opening"]
        d = np.asarray(o.direction)
        along = np.abs(d) > 0.5
        assert (hi - lo)[:2][along][0] == pytest.approx(o.width, abs=1e-3)
        assert (lo[2], hi[2]) == pytest.approx((o.z_min, o.z_max), abs=1e-3)
        host = demo.truth.wall(o.host_wall)
        assert np.dot(np.subtract(o.center, host.start), host.normal) == pytest.approx(0.0)


def test_demo_world_shape(demo: GeneratedBuilding) -> None:
    corridor = next(r for r in demo.truth.free_space[0].regions if r.kind == "corridor")
    x0, y0, x1, y1 = corridor.rect
    assert 12.0 <= x1 - x0 <= 16.0 and y1 - y0 == pytest.approx(2.4)
    rooms = [r for r in demo.truth.free_space[0].regions if r.kind == "room"]
    north = [r for r in rooms if r.rect[1] > 0]
    assert len(north) in (3, 4) and len(rooms) - len(north) in (3, 4)
    for r in rooms:
        assert 3.0 <= r.rect[2] - r.rect[0] <= 5.5 and 3.5 <= r.rect[3] - r.rect[1] <= 4.5
    # Not mirror symmetric: the door positions differ between the two sides.
    xs_n = sorted(d.center[0] for d in demo.truth.doors if d.center[1] > 0)
    xs_s = sorted(d.center[0] for d in demo.truth.doors if d.center[1] < 0)
    assert xs_n != xs_s[: len(xs_n)]
    # Walls in both directions constrain x, y and yaw.
    dirs = {tuple(np.abs(w.direction).round()) for w in demo.truth.walls}
    assert dirs == {(1.0, 0.0), (0.0, 1.0)}
    assert demo.truth.storeys[0].ceiling_z == pytest.approx(2.7)


# --- determinism -------------------------------------------------------------------------------


def test_same_seed_same_bytes_different_seed_different(tmp_path: Path) -> None:
    a = generate_building(BuildingSpec.tiny(), 5, tmp_path / "a.ifc")
    b = generate_building(BuildingSpec.tiny(), 5, tmp_path / "b.ifc")
    c = generate_building(BuildingSpec.tiny(), 6, tmp_path / "c.ifc")
    assert (tmp_path / "a.ifc").read_bytes() == (tmp_path / "b.ifc").read_bytes()
    assert (tmp_path / "a.truth.json").read_bytes() == (tmp_path / "b.truth.json").read_bytes()
    assert (tmp_path / "a.ifc").read_bytes() != (tmp_path / "c.ifc").read_bytes()
    assert a.truth.walls != c.truth.walls  # the layout itself varies with the seed
    guids = [e.GlobalId for e in a.ifc.by_type("IfcRoot")]
    assert len(set(guids)) == len(guids)
    assert all(len(ifcopenshell.guid.expand(g)) == 32 for g in guids)
    assert not set(guids) & {e.GlobalId for e in c.ifc.by_type("IfcRoot")}
    assert b.ifc_text() == a.ifc_text()


def test_as_built_deterministic(demo: GeneratedBuilding) -> None:
    assert as_built(demo, 3).ifc_text() == as_built(demo, 3).ifc_text()
    assert as_built(demo, 3).ifc_text() != as_built(demo, 4).ifc_text()
    # From the spec with the design's seed: the same as-built.
    assert as_built(BuildingSpec(), 3, design_seed=0).ifc_text() == as_built(demo, 3).ifc_text()


# --- as-built ----------------------------------------------------------------------------------


def test_as_built_differs_by_recorded_shifts(demo: GeneratedBuilding,
                                             demo_built: GeneratedBuilding,
                                             demo_bounds: dict) -> None:
    dev = demo_built.truth.deviations
    assert dev is not None and demo_built.truth.variant is Variant.AS_BUILT
    built_bounds = _bounds(ifcopenshell.open(str(demo_built.ifc_path)))
    shifts = np.array(list(dev.wall_shifts.values()))
    assert 0.005 < np.abs(shifts).mean() < 0.06 and np.abs(shifts).max() <= 0.06
    for w in demo_built.truth.walls:
        n = demo.truth.wall(w.id).normal
        axis = int(np.argmax(np.abs(n)))
        centre_design = (demo_bounds[w.id][0] + demo_bounds[w.id][1])[axis] / 2
        centre_built = (built_bounds[w.id][0] + built_bounds[w.id][1])[axis] / 2
        assert (centre_built - centre_design) * n[axis] == pytest.approx(
            dev.wall_shifts[w.id], abs=1e-3), w.id
        assert demo_built.truth.wall(w.id).guid == demo.truth.wall(w.id).guid
    for c in demo_built.truth.columns:
        c0 = next(x for x in demo.truth.columns if x.id == c.id)
        np.testing.assert_allclose(np.subtract(c.center, c0.center), dev.column_offsets[c.id])


def test_as_built_missing_elements(demo: GeneratedBuilding) -> None:
    built = as_built(demo, 11, missing_fraction=0.4)
    dev = built.truth.deviations
    # Removable on the demo's one storey: 3 columns + 5 partitions + 8 door and 8 window fills.
    assert dev is not None and len(dev.missing) == round(0.4 * 24)
    names = {e.Name for e in built.ifc.by_type("IfcProduct")}
    design_names = {e.Name for e in demo.ifc.by_type("IfcProduct")}
    assert not names & set(dev.missing) and set(dev.missing) <= design_names
    assert sum(built.truth.counts.values()) < sum(demo.truth.counts.values())
    for w in demo.truth.walls:  # the shell and the corridor are always there
        if w.kind is not WallKind.PARTITION:
            assert w.id in names
    assert {s.id for s in demo.truth.slabs} | {c.id for c in demo.truth.coverings} <= names
    # A missing fill leaves its opening; a missing partition becomes walkable.
    assert len(built.ifc.by_type("IfcOpeningElement")) == 16
    removed = {r.id for r in built.truth.free_space[0].regions if r.kind == "removed_wall"}
    assert removed == {m for m in dev.missing if "/wall/part-" in m}


def test_as_built_datum_is_at_design_and_recorded(demo: GeneratedBuilding, tmp_path: Path
                                                  ) -> None:
    """Datum walls and columns keep the design's geometry and are recorded in the sidecar; the
    other elements' shifts and the missing ones are those of the same seed without a datum."""
    from bimcap.sim.building_truth import load_building_truth

    plain = as_built(demo, 5, missing_fraction=0.3)
    built = as_built(demo, 5, missing_fraction=0.3, datum=("ext-south", "ext-west"),
                     ifc_path=tmp_path / "built.ifc")
    dev, ref = built.truth.deviations, plain.truth.deviations
    assert dev is not None and ref is not None
    datum = {"S0/wall/ext-south", "S0/wall/ext-west"}
    assert set(dev.datum) == datum and not ref.datum
    assert dev.wall_shifts["S0/wall/ext-south"] == 0.0 == dev.wall_shifts["S0/wall/ext-west"]
    assert ref.wall_shifts["S0/wall/ext-south"] != 0.0
    for w in datum:  # the same line (the ends follow the shifted walls they butt into)
        a, b = built.truth.wall(w), demo.truth.wall(w)
        assert np.dot(a.start, b.normal) == pytest.approx(np.dot(b.start, b.normal), abs=1e-9)
        assert np.dot(a.end, b.normal) == pytest.approx(np.dot(b.end, b.normal), abs=1e-9)
    assert {k: v for k, v in dev.wall_shifts.items() if k not in datum} == \
        {k: v for k, v in ref.wall_shifts.items() if k not in datum}
    assert dev.missing == ref.missing and dev.column_offsets == ref.column_offsets
    # a removable datum (a column) is never left out
    col = as_built(demo, 5, missing_fraction=1.0, datum=("column/corridor-1",)).truth.deviations
    assert col is not None and col.datum == ("S0/column/corridor-1",)
    assert col.column_offsets["S0/column/corridor-1"] == (0.0, 0.0)
    assert "S0/column/corridor-1" not in col.missing
    assert load_building_truth(tmp_path / "built.truth.json").deviations == dev
    with pytest.raises(BuildingSpecError, match="datum: unknown wall or column key 'ext-up'"):
        as_built(demo, 5, datum=("ext-up",))


def test_as_built_without_deviation_is_the_design(demo: GeneratedBuilding) -> None:
    same = as_built(demo, 1, shift_sigma_m=0.0, missing_fraction=0.0)
    assert same.truth.walls == demo.truth.walls and same.truth.columns == demo.truth.columns
    assert same.truth.counts == demo.truth.counts


# --- walkable space ----------------------------------------------------------------------------


def _in_free_space(regions, p: np.ndarray) -> np.ndarray:
    inside = np.zeros(len(p), dtype=bool)
    for r in regions:
        inside |= r.contains(p)
    return inside


@pytest.mark.parametrize("variant", ["design", "as_built"])
def test_walk_graph_is_collision_free(variant: str, demo: GeneratedBuilding,
                                      demo_built: GeneratedBuilding) -> None:
    b = demo if variant == "design" else demo_built
    fs = b.truth.free_space[0]
    walls = [w for w in b.truth.walls if w.storey == 0]
    # Door holes (and removed walls), grown by 0.35 m: where the walk may cross a wall line.
    doors = [Region(r.id, r.kind, (r.rect[0] - 0.35, r.rect[1] - 0.35, r.rect[2] + 0.35,
                                   r.rect[3] + 0.35))
             for r in fs.regions if r.kind in ("door", "removed_wall")]
    samples = []
    for i, j in fs.edges:
        t = np.linspace(0.0, 1.0, 200)[:, None]
        samples.append(fs.nodes[i] * (1 - t) + fs.nodes[j] * t)
    p = np.concatenate(samples)
    assert _in_free_space(fs.regions, p).all()
    in_door = _in_free_space(doors, p)
    for w in walls:  # outside every wall, except through a door hole, by at least 0.3 m
        lo, hi = _wall_box_from_faces(w.faces)
        near = np.all((p > lo - 0.3) & (p < hi + 0.3), axis=1)
        assert not np.any(near & ~in_door), w.id
    for c in b.truth.columns:
        r = c.radius if c.radius is not None else np.hypot(*c.size) / 2
        assert np.min(np.linalg.norm(p - np.asarray(c.center), axis=1)) - r > 0.3, c.id
    # The tour walks the graph and enters every room.
    edges = {tuple(sorted(e)) for e in fs.edges.tolist()}
    steps = [tuple(sorted(s))
             for s in zip(fs.tour[:-1].tolist(), fs.tour[1:].tolist(), strict=True)]
    assert all(s in edges or s[0] == s[1] for s in steps)
    assert fs.tour[0] == fs.tour[-1]
    for room in (r for r in fs.regions if r.kind == "room"):
        assert room.contains(fs.tour_xy(), margin=0.5).any(), room.id


def test_rooms_do_not_overlap_walls(demo: GeneratedBuilding) -> None:
    fs = demo.truth.free_space[0]
    for r in fs.regions:
        if r.kind not in ("room", "corridor"):
            continue
        x0, y0, x1, y1 = r.rect
        for w in demo.truth.walls:
            lo, hi = _wall_box_from_faces(w.faces)
            overlap = min(x1, hi[0]) - max(x0, lo[0]), min(y1, hi[1]) - max(y0, lo[1])
            assert min(overlap) <= 1e-9, (r.id, w.id)
    area = sum((r.rect[2] - r.rect[0]) * (r.rect[3] - r.rect[1]) for r in fs.regions
               if r.kind in ("room", "corridor"))
    outer = np.asarray(next(s for s in demo.truth.slabs if s.predefined_type == "BASESLAB").polygon)
    walls_inside = sum(w.length * w.thickness for w in demo.truth.walls
                       if w.kind is not WallKind.EXTERIOR)
    inner_area = np.prod(outer.max(0) - outer.min(0) - 2 * demo.spec.exterior_wall_thickness_m)
    assert area + walls_inside == pytest.approx(inner_area)  # rooms + walls tile the interior


# --- files, errors, CLI --------------------------------------------------------------------------


def test_suspended_ceiling_per_room_and_corridor(demo: GeneratedBuilding, demo_bounds: dict,
                                                 tmp_path: Path) -> None:
    """Every room and the corridor has its own IfcCovering CEILING below the slab, filling the
    room wall face to wall face, at the spec's heights; the as-built's ceilings close up where a
    partition is missing."""
    spec = demo.spec
    f = ifcopenshell.open(str(demo.ifc_path))
    ceilings = {c.Name: c for c in f.by_type("IfcCovering") if c.PredefinedType == "CEILING"}
    regions = {r.id.split("/")[-1]: r for r in demo.truth.free_space[0].regions
               if r.kind in ("room", "corridor")}
    assert set(ceilings) == {f"S0/ceiling/{k}" for k in regions} and len(regions) == 8
    st = demo.truth.storeys[0]
    for key, region in regions.items():
        name = f"S0/ceiling/{key}"
        lo, hi = demo_bounds[name]
        np.testing.assert_allclose([*lo[:2], *hi[:2]], region.rect, atol=1e-6)
        want = spec.corridor_ceiling_height_m if key == "corridor" else spec.ceiling_height_m
        assert lo[2] == pytest.approx(st.floor_z + want, abs=1e-6)
        assert hi[2] == pytest.approx(st.floor_z + want + spec.ceiling_thickness_m, abs=1e-6)
        assert hi[2] < st.wall_top_z  # below the structural slab
        storey = ifcopenshell.util.element.get_container(ceilings[name])
        assert storey.Name == "S0"
    assert (spec.ceiling_height_m, spec.corridor_ceiling_height_m) == (2.7, 2.5)
    # As built: a missing partition leaves no gap in the ceiling of the two rooms it split.
    built = as_built(demo, 3, missing_fraction=1.0, shift_sigma_m=0.0)
    gone = [m for m in built.truth.deviations.missing if "/wall/part-" in m]
    assert gone
    polys = [np.asarray(c.polygon) for c in built.truth.coverings]
    area = sum(np.prod(p.max(0) - p.min(0)) for p in polys)
    walls_inside = sum(w.length * w.thickness for w in built.truth.walls
                       if w.kind is not WallKind.EXTERIOR)
    base = next(s for s in built.truth.slabs if s.predefined_type == "BASESLAB")
    outer = np.asarray(base.polygon)
    inner_area = np.prod(outer.max(0) - outer.min(0) - 2 * spec.exterior_wall_thickness_m)
    assert area + walls_inside == pytest.approx(inner_area)
    with pytest.raises(BuildingSpecError, match="corridor_ceiling_height_m"):
        BuildingSpec(corridor_ceiling_height_m=2.0)


def test_explicit_room_widths(tmp_path: Path) -> None:
    # 15 m corridor, 0.12 m partitions: 3 north rooms fill 14.76 m, 2 south rooms 14.88 m.
    spec = BuildingSpec(room_widths_north_m=(3.0, 6.76, 5.0), rooms_south=2,
                        room_widths_south_m=(10.0, 4.88))
    t = generate_building(spec, 0, tmp_path / "w.ifc").truth
    assert t.wall("S0/wall/part-north-1").start[0] == pytest.approx(3.06)
    assert t.wall("S0/wall/part-north-2").start[0] == pytest.approx(3.0 + 0.12 + 6.76 + 0.06)
    assert t.wall("S0/wall/part-south-1").start[0] == pytest.approx(10.06)
    rooms = sorted((r.rect for r in t.free_space[0].regions if r.kind == "room"),
                   key=lambda r: (r[1], r[0]))
    assert [r[2] - r[0] for r in rooms] == pytest.approx([10.0, 4.88, 3.0, 6.76, 5.0])
    assert BuildingSpec.from_dict(json.loads((tmp_path / "w.truth.json").read_text())["spec"]) \
        == spec


def test_sidecar_round_trip(demo: GeneratedBuilding, demo_built: GeneratedBuilding) -> None:
    for b in (demo, demo_built):
        assert b.truth_path == truth_path_for(b.ifc_path)
        raw = json.loads(b.truth_path.read_text())
        assert raw["format"] == "bimcap-building-truth" and raw["version"] == 1
        assert raw["units"] == "m"
        back = load_building_truth(b.truth_path)
        assert back.to_dict() == raw
        assert back.walls == b.truth.walls


def test_bad_sidecar_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "x.truth.json"
    p.write_text('{"format": "something-else"}')
    with pytest.raises(BuildingTruthError, match=r"x\.truth\.json.*format"):
        load_building_truth(p)
    p.write_text("{not json")
    with pytest.raises(BuildingTruthError, match="not JSON"):
        load_building_truth(p)


@pytest.mark.parametrize(
    ("changes", "field"),
    [({"rooms_north": 0}, "rooms_north"), ({"corridor_length_m": 4.0}, "corridor_length_m"),
     ({"ceiling_height_m": 3.0}, "ceiling_height_m"), ({"storeys": 0}, "storeys"),
     ({"door_width_m": float("nan")}, "door_width_m"),
     ({"room_widths_north_m": (5.0, 5.0, 5.0)}, "room_widths_north_m"),
     ({"room_widths_south_m": (8.0, 6.64)}, "room_widths_south_m")],
)
def test_bad_spec_names_the_field(changes: dict, field: str) -> None:
    with pytest.raises(BuildingSpecError, match=field):
        BuildingSpec(**changes)


def test_cli_writes_design_and_as_built(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out, built = tmp_path / "b.ifc", tmp_path / "b_built.ifc"
    rc = cli_main(["generate-building", "-o", str(out), "--building", "tiny", "--seed", "4",
                   "--storeys", "2", "--as-built", str(built)])
    assert rc == 0
    assert out.exists() and built.exists() and truth_path_for(built).exists()
    text = capsys.readouterr().out
    assert "IfcBuildingStorey" not in text and "BuildingStorey 2" in text
    assert out.read_bytes() == generate_building(
        BuildingSpec(storeys=2, corridor_length_m=5.0, rooms_north=1, rooms_south=1,
                     room_depth_north_m=3.6, room_depth_south_m=4.0, corridor_columns=1),
        4).ifc_text().encode()
    assert cli_main(["generate-building", "-o", str(tmp_path / "c.ifc"), "--rooms-north",
                     "0"]) == 2
    assert cli_main(["generate-building", "-o", str(out), "--as-built", str(out)]) == 2
    # the ceiling heights are one flag away
    assert cli_main(["generate-building", "-o", str(tmp_path / "d.ifc"), "--building", "tiny",
                     "--ceiling-height", "2.6", "--corridor-ceiling-height", "2.4"]) == 0
    assert "suspended ceilings at 2.400, 2.600 m" in capsys.readouterr().out
    d = load_building_truth(truth_path_for(tmp_path / "d.ifc"))
    assert sorted(c.z_min for c in d.coverings) == pytest.approx([2.4, 2.6, 2.6])
    assert cli_main(["generate-building", "-o", str(tmp_path / "e.ifc"),
                     "--corridor-ceiling-height", "3.0"]) == 2


def test_same_bytes_in_another_process(tmp_path: Path) -> None:
    """Set iteration order in IfcOpenShell's API must not leak into the file."""
    import os
    import subprocess
    import sys

    code = ("import sys; from bimcap.sim.building import BuildingSpec, generate_building; "
            "sys.stdout.write(generate_building(BuildingSpec.tiny(), 9).ifc_text())")
    env = dict(os.environ, PYTHONHASHSEED="12345",
               PYTHONPATH=str(Path(__file__).resolve().parents[1] / "python"))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout
    assert out == generate_building(BuildingSpec.tiny(), 9).ifc_text()


# --- exact plan section ------------------------------------------------------------------------


def _length(segments: np.ndarray) -> float:
    return float(np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]).sum())


@pytest.mark.parametrize("variant", ["design", "as_built"])
def test_plan_outline_lengths(variant: str, demo: GeneratedBuilding,
                              demo_built: GeneratedBuilding) -> None:
    t = (demo if variant == "design" else demo_built).truth
    fs = t.free_space[0]
    # Above doors and windows the wall section is the outer rectangle plus the boundary of every
    # room and the corridor (rooms, corridor and walls tile the interior). A missing partition
    # leaves the rooms' shared side out of the section.
    outer = np.asarray(t.slabs[0].polygon)
    te = t.spec["exterior_wall_thickness_m"]
    shell = t.wall("S0/wall/ext-west"), t.wall("S0/wall/ext-east")
    xs = [shell[0].start[0] - te / 2, shell[1].start[0] + te / 2]
    ys = [t.wall("S0/wall/ext-south").start[1] - te / 2,
          t.wall("S0/wall/ext-north").start[1] + te / 2]
    expected = 2 * (xs[1] - xs[0]) + 2 * (ys[1] - ys[0])
    for r in fs.regions:
        x0, y0, x1, y1 = r.rect
        if r.kind in ("room", "corridor"):
            expected += 2 * (x1 - x0 + y1 - y0)
        elif r.kind == "removed_wall":  # the two rooms merge: their shared sides go, the
            expected += 2 * (x1 - x0) - 2 * (y1 - y0)  # partition's width joins both long sides
    high = t.plan_outline(0, 2.5)
    walls_high = high.segments[high.segment_class == 1]
    assert _length(walls_high) == pytest.approx(expected, abs=1e-6)
    if variant == "design":
        assert outer.min(0) == pytest.approx([xs[0], ys[0]])
    # At 1 m every door and window hole takes its width out of both faces and adds two jambs.
    low = t.plan_outline(0, 1.0)
    delta = sum(-2 * o.width + 2 * t.wall(o.host_wall).thickness
                for o in (*t.doors, *t.windows) if o.storey == 0)
    assert _length(low.segments[low.segment_class == 1]) == pytest.approx(expected + delta,
                                                                          abs=1e-6)
    # Every wall segment is axis-aligned and lies on a face or an end of some wall.
    seg = low.segments[low.segment_class == 1]
    assert np.all((seg[:, 0] == seg[:, 2]) | (seg[:, 1] == seg[:, 3]))
    cols = low.segments[low.segment_class == 4]
    n_round = sum(c.shape is ColumnShape.ROUND for c in t.columns)
    assert len(cols) == 4 * (len(t.columns) - n_round) + 32 * n_round


def test_plan_outline_demo_by_hand(demo: GeneratedBuilding) -> None:
    """Total wall section of the demo above the openings, from the spec alone."""
    s = demo.spec
    te, ti = s.exterior_wall_thickness_m, s.interior_wall_thickness_m
    length_in = s.corridor_length_m
    depth_in = s.corridor_width_m + 2 * ti + s.room_depth_north_m + s.room_depth_south_m
    outer = 2 * (length_in + 2 * te) + 2 * (depth_in + 2 * te)
    corridor = 2 * (s.corridor_length_m + s.corridor_width_m)
    # Room widths sum to the corridor length minus the partitions on each side.
    north = 2 * (s.corridor_length_m - (s.rooms_north - 1) * ti) \
        + 2 * s.rooms_north * s.room_depth_north_m
    south = 2 * (s.corridor_length_m - (s.rooms_south - 1) * ti) \
        + 2 * s.rooms_south * s.room_depth_south_m
    o = demo.truth.plan_outline(0, 2.5)
    assert _length(o.segments[o.segment_class == 1]) == pytest.approx(
        outer + corridor + north + south, abs=1e-6)
