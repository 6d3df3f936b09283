"""Real-world IFC variants of one generated building (issue 11): georeferenced (moved to a
5.4·10⁶ m northing and turned 37°), millimetre and foot units, raised storeys, IfcWall for
IfcWallStandardCase, walls and columns written as IfcBuildingElementProxy. Each is written by
``bench/ifc_variants.py`` with IfcOpenShell, whose geometry engine reads it back: the BIM
reference must be the original's, moved by the variant's transform
(:func:`ifc_variants.world_from_model`) and nothing else."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from _bim_building import dist_to_segments
from bimcap.bim.errors import BimInputError, ProxyElementWarning, StoreyHeightWarning
from bimcap.bim.ingest import BimModel, load_model, proxy_shape_agrees
from bimcap.bim.reference import BimReference, build_reference
from bimcap.bim.slicing import sample_segments
from bimcap.labels import Label

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import ifc_variants  # bench/ifc_variants.py, the writer of the variants

building = pytest.importorskip("bimcap.sim.building")


@pytest.fixture(scope="module")
def original(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, BimModel, BimReference]:
    path = tmp_path_factory.mktemp("variants") / "gen.ifc"
    building.generate_building(building.BuildingSpec(storeys=2), seed=3, ifc_path=path)
    model = load_model(path)
    return path, model, build_reference(model)


def _variant(original: tuple[Path, BimModel, BimReference], name: str
             ) -> tuple[BimModel, BimReference, list[Any]]:
    src = original[0]
    path = ifc_variants.make_variant(src, name, src.parent)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = load_model(path)
    return model, build_reference(model), list(caught)


def _area_by_height(ref: BimReference, kind: Label, up: float) -> dict[float, float]:
    """Total polygon area (m²) of the ``kind`` planes per height (mm, less ``up``)."""
    out: dict[float, float] = {}
    for p in ref.plane_info:
        if p.kind == kind:
            h = round(p.height - up, 3)
            out[h] = out.get(h, 0.0) + p.area_m2
    return out


def _moved(points: np.ndarray, m: np.ndarray) -> np.ndarray:
    return points @ m[:3, :3].T + m[:3, 3]


@pytest.mark.parametrize("name", ["georef", "mm", "ft", "raised", "ifcwall", "proxy"])
def test_variant_reference_is_the_original_moved(
        original: tuple[Path, BimModel, BimReference], name: str) -> None:
    """Every element's mesh, the storey heights, the floor/ceiling planes and the floor plan's
    wall and column lines are the original's under the variant's transform (millimetres)."""
    _, model0, ref0 = original
    model, ref, _ = _variant(original, name)
    m = ifc_variants.world_from_model(name)
    up = float(m[2, 3])
    assert model.unit_scale == {"mm": 0.001, "ft": 0.3048}.get(name, model0.unit_scale)
    by_guid = {e.guid: e for e in model.elements}
    assert sorted(by_guid) == sorted(e.guid for e in model0.elements)
    for e0 in model0.elements:
        e = by_guid[e0.guid]
        assert e.label == e0.label and e.storey == e0.storey, e0.guid
        assert np.abs(e.vertices - _moved(e0.vertices, m)).max() < 1e-6, e0.guid
    assert [s.name for s in model.storeys] == [s.name for s in model0.storeys]
    assert [s.elevation_m for s in model.storeys] == pytest.approx(
        [s.elevation_m + up for s in model0.storeys], abs=1e-6)
    # planes: the same kinds at the same heights (+ the shift up) over the same area (how a
    # storey's floor is cut into connected pieces may differ: slivers under the walls)
    for kind in (Label.FLOOR, Label.CEILING):
        area0 = _area_by_height(ref0, kind, 0.0)
        area = _area_by_height(ref, kind, up)
        assert sorted(area) == sorted(area0), kind
        for h, a in area0.items():
            assert area[h] == pytest.approx(a, rel=0.01), (kind, h)
    # floor plan: every wall and column line of the variant on the moved original's (1 cm)
    for cls in (Label.WALL, Label.COLUMN):
        sel0, sel = ref0.segment_class == int(cls), ref.segment_class == int(cls)
        assert sel.sum() > 0
        seg0 = ref0.segments[sel0].reshape(-1, 2)
        seg0 = _moved(np.column_stack([seg0, np.zeros(len(seg0))]), m)[:, :2].reshape(-1, 4)
        pts, _ = sample_segments(ref.segments[sel], 0.05)
        assert np.quantile(dist_to_segments(pts, seg0)[0], 0.98) < 0.01, cls
        back, _ = sample_segments(seg0, 0.05)
        assert np.quantile(dist_to_segments(back, ref.segments[sel])[0], 0.98) < 0.01, cls
    # the semantic cloud covers the moved original's surfaces
    assert len(ref.points) == pytest.approx(len(ref0.points), rel=0.05)
    lo0, hi0 = ref0.points.min(axis=0), ref0.points.max(axis=0)
    if name != "georef":  # a turned box has other bounds
        assert np.allclose(ref.points.min(axis=0), lo0 + m[:3, 3], atol=0.05)
        assert np.allclose(ref.points.max(axis=0), hi0 + m[:3, 3], atol=0.05)


def test_raised_storeys_load_without_corrections(
        original: tuple[Path, BimModel, BimReference]) -> None:
    """A building on a slope (placements and Elevation attributes raised together) is a
    consistent model: no storey height is corrected, nothing is noted."""
    model, _, caught = _variant(original, "raised")
    assert not [w for w in caught if issubclass(w.category, StoreyHeightWarning)]
    assert model.notes == []


def test_proxy_walls_and_columns_are_taken_by_name_and_said_so(
        original: tuple[Path, BimModel, BimReference]) -> None:
    """A generic export (every wall and column an IfcBuildingElementProxy) loads as the original
    (the reference test above) and says what it took: one ProxyElementWarning, one note."""
    model0 = original[1]
    model, _, caught = _variant(original, "proxy")
    walls0 = sum(e.label == Label.WALL for e in model0.elements)
    columns0 = sum(e.label == Label.COLUMN for e in model0.elements)
    assert walls0 > 0 and columns0 > 0
    assert {e.ifc_class for e in model.by_label(Label.WALL, Label.COLUMN)} == {
        "IfcBuildingElementProxy"}
    said = [str(w.message) for w in caught if issubclass(w.category, ProxyElementWarning)]
    assert len(said) == 1
    assert f"{walls0} IfcBuildingElementProxy elements taken as walls and {columns0} as columns" \
        in said[0]
    assert said[0] in model.notes


def _box(size_xyz: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A closed axis-aligned box mesh (8 vertices, 12 outward triangles), metres."""
    sx, sy, sz = size_xyz
    v = np.array([[x, y, z] for z in (0, sz) for y in (0, sy) for x in (0, sx)], float)
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int32)
    return v, f


@pytest.mark.parametrize(("size", "label", "agrees"), [
    ((4.0, 0.2, 2.7), Label.WALL, True),     # a partition
    ((8.8, 0.42, 0.61), Label.WALL, True),   # a parapet (Duplex_A)
    ((0.6, 0.6, 2.1), Label.WALL, False),    # a cupboard named after the wall it stands at
    ((3.0, 1.5, 3.0), Label.WALL, False),    # too thick for a wall
    ((5.0, 0.2, 0.1), Label.WALL, False),    # a skirting board
    ((0.4, 0.4, 3.0), Label.COLUMN, True),
    ((0.4, 0.4, 0.8), Label.COLUMN, False),  # a post shorter than a column
    ((4.0, 0.3, 3.0), Label.COLUMN, False),  # a wall named "column"
])
def test_proxy_shape_check_reads_a_box_of_the_same_volume_and_side_area(
        size: tuple[float, float, float], label: Label, agrees: bool) -> None:
    v, f = _box(size)
    assert proxy_shape_agrees(label, v, f) is agrees


def test_proxies_named_as_walls_but_not_shaped_so_are_refused(tmp_path: Path) -> None:
    """A model whose only 'walls' are proxies no wall could be (cupboards named 'Wall 1') is
    refused as having no walls, naming the file and IfcWall."""
    path = tmp_path / "cupboards.ifc"
    _write_cupboards(path)
    with pytest.raises(BimInputError) as err:
        load_model(path)
    assert "cupboards.ifc" in str(err.value) and "not shaped as walls" in str(err.value)


def _write_cupboards(path: Path) -> None:
    import ifcopenshell
    import ifcopenshell.api

    f = ifcopenshell.file(schema="IFC4")
    run = ifcopenshell.api.run
    project = run("root.create_entity", f, ifc_class="IfcProject", name="p")
    run("unit.assign_unit", f)
    ctx = run("context.add_context", f, context_type="Model")
    body = run("context.add_context", f, context_type="Model", context_identifier="Body",
               target_view="MODEL_VIEW", parent=ctx)
    site = run("root.create_entity", f, ifc_class="IfcSite", name="site")
    building = run("root.create_entity", f, ifc_class="IfcBuilding", name="b")
    storey = run("root.create_entity", f, ifc_class="IfcBuildingStorey", name="s")
    run("aggregate.assign_object", f, products=[site], relating_object=project)
    run("aggregate.assign_object", f, products=[building], relating_object=site)
    run("aggregate.assign_object", f, products=[storey], relating_object=building)
    for i in range(3):
        el = run("root.create_entity", f, ifc_class="IfcBuildingElementProxy", name=f"Wall {i}")
        run("geometry.edit_object_placement", f, product=el,
            matrix=np.array([[1, 0, 0, 2.0 * i], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
        rep = run("geometry.add_wall_representation", f, context=body, length=0.6, height=2.0,
                  thickness=0.6)
        run("geometry.assign_representation", f, product=el, representation=rep)
        run("spatial.assign_container", f, products=[el], relating_structure=storey)
    f.write(str(path))
