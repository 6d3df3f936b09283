"""Real-world IFC variants of one generated building (issue 11): georeferenced (moved to a
5.4·10⁶ m northing and turned 37°), millimetre and foot units, raised storeys, IfcWall for
IfcWallStandardCase. Each is written by ``bench/ifc_variants.py`` with IfcOpenShell, whose
geometry engine reads it back: the BIM reference must be the original's, moved by the variant's
transform (:func:`ifc_variants.world_from_model`) and nothing else."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from _bim_building import dist_to_segments
from bimcap.bim.errors import StoreyHeightWarning
from bimcap.bim.ingest import BimModel, load_model
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


@pytest.mark.parametrize("name", ["georef", "mm", "ft", "raised", "ifcwall"])
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
