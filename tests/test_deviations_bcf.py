"""bimcap.deviations.bcf: the BCF 2.1 export (``deviations.bcfzip``), read back by IfcOpenShell's
``bcf-client`` (an independent reader: xsdata classes generated from buildingSMART's BCF
schemas) on the tiny deviation world with ground-truth poses."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

import numpy as np
import pytest

from _deviation_world import make_deviation_world
from bimcap.labels import Label


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return make_deviation_world(tmp_path_factory.mktemp("bcfworld"))


@pytest.fixture(scope="module")
def analysed(world: dict[str, Path]) -> tuple[Any, Any, Any]:
    """(model, scans, report) with the ground-truth poses."""
    from bimcap.dataset import read_sequence
    from bimcap.deviations.analysis import analyse_deviations, load_design
    from bimcap.deviations.refined_map import load_scans

    seq = read_sequence(world["seq"])
    scans = load_scans(seq, seq.trajectory("gt").poses)
    model = load_design(world["design"])
    return model, scans, analyse_deviations(model, scans, ifc_path=world["design"])


def _ifc_centres(ifc_path: Path, guids: set[str]) -> dict[str, np.ndarray]:
    """Bounding-box centre (3,) of each element, tessellated here by IfcOpenShell (world
    coordinates, metres), independently of bimcap's ingest."""
    import ifcopenshell
    import ifcopenshell.geom

    f = ifcopenshell.open(str(ifc_path))
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    out = {}
    for guid in guids:
        shape = ifcopenshell.geom.create_shape(settings, f.by_guid(guid))
        v = np.asarray(shape.geometry.verts, dtype=np.float64).reshape(-1, 3)
        out[guid] = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return out


def _box_entry(eye: np.ndarray, u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Distance along the ray ``eye + t u`` at which it enters the box [lo, hi] (slab test)."""
    with np.errstate(divide="ignore"):
        t1, t2 = (lo - eye) / u, (hi - eye) / u
    return float(np.max(np.minimum(t1, t2)))


def test_bcf_reads_back_with_one_topic_per_flagged_element(world: dict[str, Path],
                                                           analysed: tuple[Any, Any, Any],
                                                           tmp_path: Path) -> None:
    bcfxml = pytest.importorskip("bcf.bcfxml", reason="bcf-client (the test extra) is absent")
    import ifcopenshell
    import open3d as o3d

    from bimcap.bim.ingest import load_model
    from bimcap.deviations.bcf import write_deviation_bcf

    model, scans, report = analysed
    path = tmp_path / "deviations.bcfzip"
    write_deviation_bcf(path, report, model, viewers=scans.origins, ifc_path=world["design"])
    doc = report.to_dict()  # deviations.json
    flagged = {e["guid"]: e for e in doc["elements"] if e["status"] in ("deviating", "missing")}
    # the tiny world: five S0 walls shifted beyond 2 cm, the corridor column missing
    assert sum(e["status"] == "missing" for e in flagged.values()) == 1
    assert sum(e["status"] == "deviating" for e in flagged.values()) >= 3

    bcf = bcfxml.load(path)
    assert bcf.version.version_id == "2.1"
    project = ifcopenshell.open(str(world["design"])).by_type("IfcProject")[0].GlobalId
    assert len(bcf.topics) == len(flagged)
    seen: dict[str, Any] = {}
    for guid, handler in bcf.topics.items():
        topic = handler.topic
        assert topic.guid == guid and topic.topic_type == "Issue" and topic.topic_status == "Open"
        assert handler.header.file[0].filename == "design.ifc"
        assert handler.header.file[0].ifc_project == project
        (viewpoint,) = handler.viewpoints.values()
        (element,) = viewpoint.get_selected_guids()
        assert element in flagged and element not in seen
        seen[element] = viewpoint.visualization_info.perspective_camera
        e = flagged[element]
        assert e["name"] in topic.title and e["status"] in topic.title
        for key in ("offset_m", "coverage", "n_points", "tolerance"):
            assert key in topic.description, key
        assert f"n_points = {e['n_points']}" in topic.description
        if e["status"] == "deviating":
            assert f"built {100 * abs(e['offset_m']):.1f} cm off" in topic.title
            assert f"{e['offset_m']:+.4f} m" in topic.description
        else:
            assert topic.title.endswith("missing")
    assert set(seen) == set(flagged)

    # every camera looks at its element's centre (as IfcOpenShell tessellates it) ...
    centres = _ifc_centres(world["design"], set(flagged))
    scene = o3d.t.geometry.RaycastingScene()
    boxes = {}
    for el in load_model(world["design"]).elements:
        scene.add_triangles(o3d.core.Tensor(el.vertices.astype(np.float32)),
                            o3d.core.Tensor(el.faces.astype(np.uint32)))
        boxes[el.guid] = (el.vertices.min(axis=0), el.vertices.max(axis=0))
    for guid, cam in seen.items():
        eye = np.array([cam.camera_view_point.x, cam.camera_view_point.y, cam.camera_view_point.z])
        d = np.array([cam.camera_direction.x, cam.camera_direction.y, cam.camera_direction.z])
        up = np.array([cam.camera_up_vector.x, cam.camera_up_vector.y, cam.camera_up_vector.z])
        to_centre = centres[guid] - eye
        cos = to_centre @ d / (np.linalg.norm(to_centre) * np.linalg.norm(d))
        assert np.degrees(np.arccos(min(cos, 1.0))) < 3.0, (flagged[guid]["name"], eye, d)
        assert abs(up @ d) < 1e-3 and 45.0 <= cam.field_of_view <= 60.0
        # ... from outside it, at least a metre away, with nothing of the model in between
        # (but what stands within 10 cm of its face: a window's sill)
        u = to_centre / np.linalg.norm(to_centre)
        entry = _box_entry(eye, u, *boxes[guid])
        assert 1.0 <= entry <= 6.5, (flagged[guid]["name"], entry)
        ans = scene.cast_rays(o3d.core.Tensor(np.array([[*eye, *u]], dtype=np.float32)))
        assert float(ans["t_hit"].numpy()[0]) >= entry - 0.1, flagged[guid]["name"]


def test_bcf_xml_follows_the_bcf21_element_names(world: dict[str, Path],
                                                 analysed: tuple[Any, Any, Any],
                                                 tmp_path: Path) -> None:
    """The files and elements BCF 2.1's schemas (markup.xsd, visinfo.xsd, version.xsd) name, in
    their sequence order, parsed with the standard library."""
    from bimcap.deviations.bcf import write_deviation_bcf

    model, scans, report = analysed
    path = tmp_path / "d.bcfzip"
    topics = write_deviation_bcf(path, report, model, viewers=scans.origins)
    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
        assert names == {"bcf.version"} | {f"{t.guid}/{f}" for t in topics
                                           for f in ("markup.bcf", "viewpoint.bcfv")}
        version = ET.fromstring(z.read("bcf.version"))
        assert version.tag == "Version" and version.get("VersionId") == "2.1"
        for t in topics:
            markup = ET.fromstring(z.read(f"{t.guid}/markup.bcf"))
            assert markup.tag == "Markup" and [c.tag for c in markup] == ["Topic", "Viewpoints"]
            topic = markup.find("Topic")
            assert topic is not None and topic.get("Guid") == t.guid
            assert [c.tag for c in topic] == ["Title", "Labels", "Labels", "CreationDate",
                                              "CreationAuthor", "Description"]
            vp_ref = markup.find("Viewpoints")
            assert vp_ref is not None and vp_ref.findtext("Viewpoint") == "viewpoint.bcfv"
            vis = ET.fromstring(z.read(f"{t.guid}/viewpoint.bcfv"))
            assert vis.tag == "VisualizationInfo" and vis.get("Guid") == vp_ref.get("Guid")
            assert [c.tag for c in vis] == ["Components", "PerspectiveCamera"]
            comps = vis.find("Components")
            assert comps is not None and [c.tag for c in comps] == ["Selection", "Visibility"]
            assert [c.get("IfcGuid") for c in comps.iter("Component")] == [t.element_guid]
            cam = vis.find("PerspectiveCamera")
            assert cam is not None and [c.tag for c in cam] == [
                "CameraViewPoint", "CameraDirection", "CameraUpVector", "FieldOfView"]
            assert [c.tag for c in cam[0]] == ["X", "Y", "Z"]


def test_titles_and_an_empty_export(analysed: tuple[Any, Any, Any], tmp_path: Path) -> None:
    from dataclasses import replace

    from bimcap.deviations.analysis import ElementDeviation, ElementStatus
    from bimcap.deviations.bcf import topic_title, write_deviation_bcf

    wall = ElementDeviation("0" * 22, "IfcWallStandardCase", "Partition 3", "S0",
                            ElementStatus.DEVIATING, -0.0421, 0.6, 1200, 1300, 3)
    assert topic_title(wall) == "Wall 'Partition 3' built 4.2 cm off (deviating)"
    column = ElementDeviation("1" * 22, "IfcColumn", "C2", "S0", ElementStatus.MISSING, None,
                              0.0, 0, 90, 80)
    assert topic_title(column) == "Column 'C2' missing"
    # nothing flagged: a valid BCF without topics
    model, _, report = analysed
    calm = replace(report, elements=[e for e in report.elements
                                     if e.status.value not in ("deviating", "missing")])
    path = tmp_path / "none.bcfzip"
    assert write_deviation_bcf(path, calm, model) == []
    with zipfile.ZipFile(path) as z:
        assert z.namelist() == ["bcf.version"]


def test_floor_and_ceiling_cameras_look_down_and_up(analysed: tuple[Any, Any, Any]) -> None:
    from bimcap.deviations.bcf import element_camera, model_scene

    model = analysed[0]
    scene = model_scene(model)
    floor = next(e for e in model.elements if e.label == Label.FLOOR and e.storey == "S0")
    ceiling = next(e for e in model.elements if e.label == Label.CEILING and e.storey == "S0")
    down = element_camera(floor, scene)
    assert down.direction == pytest.approx((0.0, 0.0, -1.0))
    assert floor.zmax + 0.9 < down.eye[2] < ceiling.zmin  # above the floor, under the ceiling
    up = element_camera(ceiling, scene)
    assert up.direction == pytest.approx((0.0, 0.0, 1.0))
    assert floor.zmax < up.eye[2] < ceiling.zmin - 0.9
    for cam in (down, up):
        assert abs(np.dot(cam.up, cam.direction)) < 1e-9
