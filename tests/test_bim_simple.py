"""The BIM reference of a small IFC4 building with known geometry (tests/_bim_building.py):
walls, columns, planes and plane_under, the floor plan against the known faces, save / load."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _bim_building import SimpleBuilding, build_simple_building, dist_to_segments
from bimcap.bim.floorplan import FloorPlanOptions, Vectorizer, build_floor_plan
from bimcap.bim.ingest import BimModel, load_model
from bimcap.bim.reference import BimReference, ReferenceOptions, build_reference
from bimcap.bim.semantic_cloud import read_ply
from bimcap.bim.slicing import sample_segments
from bimcap.labels import Label

CUT = 1.2  # default cut height above the storey


@pytest.fixture(scope="module", params=[0.0, 17.0], ids=["axis-aligned", "rotated17"])
def building(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
             ) -> tuple[SimpleBuilding, BimModel]:
    path = tmp_path_factory.mktemp("simple") / "simple.ifc"
    b = build_simple_building(path, site_angle_deg=request.param)
    return b, load_model(path)


@pytest.fixture(scope="module")
def reference(building: tuple[SimpleBuilding, BimModel]) -> BimReference:
    return build_reference(building[1], ReferenceOptions(density_per_m2=50.0, seed=1))


def test_element_counts_and_storeys(building: tuple[SimpleBuilding, BimModel]) -> None:
    _, m = building
    assert m.counts() == {"wall": 10, "column": 4, "door": 2, "window": 2, "floor": 2,
                          "ceiling": 1, "other": 1}
    assert [(s.name, s.elevation_m) for s in m.storeys] == [("Storey 0", 0.0), ("Storey 1", 3.0)]
    assert m.failed == []
    walls = m.by_label(Label.WALL)
    assert {w.storey for w in walls} == {"Storey 0", "Storey 1"}
    # Metres: the wall heights are 2.8 m.
    assert all(w.zmax - w.zmin == pytest.approx(2.8, abs=1e-6) for w in walls)


def test_planes_at_known_heights(reference: BimReference) -> None:
    """The visible surfaces: each room's floor and ceiling, without the footprints of the walls
    and columns that stand on the slab or pass through the covering."""
    got = sorted((p.kind.name, p.storey, round(p.height, 6), p.source, round(p.area_m2, 2))
                 for p in reference.plane_info)
    room = 3.7 * 5.6  # clear area of each room (x 0.2..3.9 and 4.1..7.8, y 0.2..5.8)
    left = round(room - 0.3 * 0.3, 2)  # the square column
    right = round(room - np.pi * 0.15**2, 2)  # the round column
    assert got == [
        # the covering spans x 0.2..4.0: its last 0.1 m lies inside the interior wall
        ("CEILING", "Storey 0", 2.6, "covering", left),
        ("CEILING", "Storey 0", 2.8, "slab-above", right),
        ("CEILING", "Storey 1", 5.8, "slab-above", left),
        ("CEILING", "Storey 1", 5.8, "slab-above", right),
        ("FLOOR", "Storey 0", 0.0, "slab", left),
        ("FLOOR", "Storey 0", 0.0, "slab", right),
        ("FLOOR", "Storey 1", 3.0, "slab", left),
        ("FLOOR", "Storey 1", 3.0, "slab", right),
    ]
    for p, row in zip(reference.plane_info, reference.planes, strict=True):
        assert np.linalg.norm(row[:3]) == pytest.approx(1.0)
        # Floors face up, ceilings face down (into the room).
        assert row[2] == (1.0 if p.kind == Label.FLOOR else -1.0)


def test_plane_under_and_sign(building: tuple[SimpleBuilding, BimModel],
                              reference: BimReference) -> None:
    b, _ = building
    local = np.array([[2.0, 4.0, 1.0], [6.0, 4.0, 1.0], [6.0, 4.0, 4.5], [20.0, 20.0, 1.0],
                      [2.0, 4.0, 3.05]])
    xy = (b.site_from_local @ np.c_[local[:, :2], np.ones(len(local))].T).T[:, :2]
    p = np.c_[xy, local[:, 2]]
    fl = reference.plane_under(p, Label.FLOOR)
    ce = reference.plane_under(p, Label.CEILING)
    h = {i: (pl.kind, round(pl.height, 6)) for i, pl in enumerate(reference.plane_info)}
    assert [h[i][1] if i >= 0 else None for i in fl] == [0.0, 0.0, 3.0, None, 3.0]
    assert [h[i][1] if i >= 0 else None for i in ce] == [2.6, 2.8, 5.8, None, 2.6]
    assert fl.dtype == np.int32
    # A point inside a room is at positive signed distance from its floor and its ceiling.
    for k in range(3):
        for idx, expected in ((fl[k], local[k, 2] - h[fl[k]][1]),
                              (ce[k], h[ce[k]][1] - local[k, 2])):
            n, d = reference.planes[idx, :3], reference.planes[idx, 3]
            assert n @ p[k] + d == pytest.approx(expected)
            assert expected > 0


def test_floor_plan_reproduces_known_walls(building: tuple[SimpleBuilding, BimModel],
                                           reference: BimReference) -> None:
    b, _ = building
    segs, cls = reference.segments, reference.segment_class
    assert set(np.unique(cls)) == {int(Label.WALL), int(Label.COLUMN)}
    for k in range(b.n_storeys):
        zk = 3.0 * k
        in_storey = (reference.segment_z[:, 0] == zk)
        walls = segs[in_storey & (cls == Label.WALL)]
        faces = b.wall_faces(k, CUT)
        for face in faces:
            p, _ = sample_segments(face[None], 0.01)
            d, j = dist_to_segments(p, walls)
            assert d.max() <= 0.01, f"storey {k}: face {face} off by {d.max():.4f} m"
            u = face[2:] - face[:2]
            for s in walls[np.unique(j)]:
                v = s[2:] - s[:2]
                cos = abs(u @ v) / np.linalg.norm(u) / np.linalg.norm(v)
                assert np.degrees(np.arccos(min(1.0, cos))) <= 1.0
        # Precision against the known faces: every detected wall point lies on a known face.
        p, _ = sample_segments(walls, 0.01)
        d, _ = dist_to_segments(p, faces)
        assert d.max() <= 0.01
        # The door gap in the interior wall stays open.
        door_mid = b.site_from_local @ np.array([4.0, 2.45, 1.0])
        d, _ = dist_to_segments(door_mid[None, :2], walls)
        assert d[0] > 0.05


def test_columns_outlined(building: tuple[SimpleBuilding, BimModel],
                          reference: BimReference) -> None:
    b, _ = building
    cols = reference.segments[(reference.segment_class == Label.COLUMN)
                              & (reference.segment_z[:, 0] == 0.0)]
    rect = b.column_faces()
    p, _ = sample_segments(rect, 0.01)
    d, _ = dist_to_segments(p, cols)
    assert d.max() <= 0.01
    # The round column: every outline vertex within 1 cm of the 0.15 m circle, all around it.
    c = b.site_from_local @ np.array([6.0, 3.0, 1.0])
    near = cols[np.linalg.norm(cols[:, :2] - c[:2], axis=1) < 0.5]
    r = np.linalg.norm(near[:, :2] - c[:2], axis=1)
    assert np.all(np.abs(r - 0.15) <= 0.01)
    length = np.hypot(near[:, 2] - near[:, 0], near[:, 3] - near[:, 1]).sum()
    assert length == pytest.approx(2 * np.pi * 0.15, rel=0.05)


def test_agreement_above_095(reference: BimReference) -> None:
    assert reference.floor_plan is not None
    for sp in reference.floor_plan.storeys:
        for name in ("wall", "column", "all"):
            a = sp.agreement[name]
            assert a.coverage >= 0.95 and a.precision >= 0.95, (sp.storey, name, a)


@pytest.mark.parametrize("method", [Vectorizer.HOUGH, Vectorizer.CONTOUR, Vectorizer.LSD])
def test_vectorizers_measured(building: tuple[SimpleBuilding, BimModel], method: Vectorizer
                              ) -> None:
    """Every vectorizer is precise (the refinement snaps to faces); Hough, the default, is the
    one that also covers ≥ 0.95 (see bench/bench_bim.py for the comparison on real models)."""
    fp = build_floor_plan(building[1], FloorPlanOptions(vectorizer=method))
    for sp in fp.storeys:
        a = sp.agreement["wall"]
        assert a.precision >= 0.99
        if method == Vectorizer.HOUGH:
            assert a.coverage >= 0.95


def test_save_load_round_trip(reference: BimReference, tmp_path: Path) -> None:
    reference.save(tmp_path)
    for name in ("reference.json", "planes.json", "floorplan.json", "reference.npz",
                 "semantic_cloud.ply", "floorplan_00_Storey_0.svg", "floorplan_01_Storey_1.png"):
        assert (tmp_path / name).is_file(), name
    r2 = BimReference.load(tmp_path)
    for attr in ("planes", "segments", "segment_class", "segment_z", "points", "labels"):
        assert np.array_equal(getattr(r2, attr), getattr(reference, attr)), attr
    assert r2.segment_class.dtype == np.int32 and r2.planes.dtype == np.float64
    p = np.array([[11.0, -3.0, 1.0], [100.0, 0.0, 0.0]])
    assert np.array_equal(r2.plane_under(p, Label.FLOOR), reference.plane_under(p, Label.FLOOR))
    pts, labels = read_ply(tmp_path / "semantic_cloud.ply")
    assert np.allclose(pts, reference.points, atol=1e-5)
    assert np.array_equal(labels, reference.labels)
    import json

    fp = json.loads((tmp_path / "floorplan.json").read_text())
    assert fp["resolution_m"] == 0.05 and len(fp["origin"]) == 2
    assert len(fp["segments"]) == len(reference.segments)
    s0 = fp["segments"][0]
    assert set(s0) == {"x1", "y1", "x2", "y2", "class", "storey"}
    assert fp["storeys"][0]["band"] == pytest.approx([1.0, 1.4])


def test_cloud_labels_and_density(building: tuple[SimpleBuilding, BimModel],
                                  reference: BimReference) -> None:
    _, m = building
    counts = np.bincount(reference.labels, minlength=8)
    assert counts[Label.UNKNOWN] == 0 and counts[Label.CLUTTER] == 0
    # Expected count per class = density x mesh area, within 5 sigma (Poisson).
    for lab in (Label.WALL, Label.FLOOR, Label.COLUMN):
        v, f = m.mesh(lab)
        t = v[f]
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
        expected = 50.0 * area
        assert abs(counts[lab] - expected) < 5 * np.sqrt(expected), lab
    # Floor points lie on the slabs' faces: z in {-0.2, 0, 2.8, 3.0} or on their sides.
    z = reference.points[reference.labels == Label.FLOOR, 2]
    assert z.min() >= -0.2 - 1e-9 and z.max() <= 3.0 + 1e-9
