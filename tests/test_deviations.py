"""bimcap.deviations: the refined map and the scan-vs-BIM deviations, against the simulator's
truth sidecar (``built.truth.json``) on a tiny two-storey world."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from _deviation_world import make_deviation_world
from bimcap.labels import Label


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return make_deviation_world(tmp_path_factory.mktemp("devworld"))


@pytest.fixture(scope="module")
def scans(world: dict[str, Path]) -> Any:
    from bimcap.dataset import read_sequence
    from bimcap.deviations.refined_map import load_scans

    seq = read_sequence(world["seq"])
    return load_scans(seq, seq.trajectory("gt").poses)


def _distance_to_model(ifc: Path, points: np.ndarray) -> np.ndarray:
    import open3d as o3d

    from bimcap.bim.ingest import load_model

    scene = o3d.t.geometry.RaycastingScene()
    for e in load_model(ifc).elements:
        if e.label != Label.DOOR:
            scene.add_triangles(o3d.core.Tensor(e.vertices.astype(np.float32)),
                                o3d.core.Tensor(e.faces.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def test_refined_map_lies_on_the_as_built_and_open3d_reads_it(world: dict[str, Path], scans: Any,
                                                              tmp_path: Path) -> None:
    import open3d as o3d

    from bimcap.deviations.refined_map import build_refined_map, write_refined_map
    from bimcap.io.ply import read_labelled_ply

    # labels come from the nearest front-end sample within 10 cm: two labelled samples
    wall_sample = scans.p_in_world[0]
    refined = build_refined_map(scans, voxel_m=0.05, label_points=wall_sample[None, :],
                                label_values=np.array([Label.WALL]))
    assert 1000 < len(refined.points) < len(scans)
    # with the true poses and cam_from_lidar the map lies on the as-built surfaces (the LiDAR's
    # noise is 3 cm), not on the design's shifted walls everywhere
    dist = _distance_to_model(world["built"], refined.points)
    assert np.median(dist) < 0.02 and np.mean(dist < 0.1) > 0.95
    near = np.linalg.norm(refined.points - wall_sample, axis=1) < 0.07
    assert np.all(refined.labels[near] == Label.WALL) and near.any()
    assert np.all(refined.labels[np.linalg.norm(refined.points - wall_sample, axis=1) > 0.15]
                  == Label.UNKNOWN)
    path = tmp_path / "map_refined.ply"
    write_refined_map(path, refined)
    cloud = o3d.io.read_point_cloud(str(path))
    assert np.allclose(np.asarray(cloud.points), refined.points, atol=1e-5)
    assert len(np.asarray(cloud.colors)) == len(refined.points)
    _, labels = read_labelled_ply(path)
    assert np.array_equal(labels, refined.labels)


def test_refined_map_crops_to_a_storey(scans: Any) -> None:
    from bimcap.bim.ingest import Storey
    from bimcap.deviations.refined_map import (
        RefinedMapError,
        build_refined_map,
        storey_z_range,
    )

    storeys = [Storey("S0", 0.0, "a"), Storey("S1", 3.2, "b")]
    z = storey_z_range(storeys, "S0")
    assert z == (-0.3, 3.2)
    cropped = build_refined_map(scans, z_range=z)
    assert cropped.points[:, 2].max() < 3.2 and cropped.z_range == z
    with pytest.raises(RefinedMapError, match=r"no storey 'S9'.*S0"):
        storey_z_range(storeys, "S9")


@pytest.fixture(scope="module")
def report(world: dict[str, Path], scans: Any) -> Any:
    from bimcap.deviations.analysis import analyse_deviations, load_design

    return analyse_deviations(load_design(world["design"]), scans, ifc_path=world["design"])


def test_shifted_walls_are_found_with_their_offsets(world: dict[str, Path], report: Any) -> None:
    """Ground-truth poses: every seen S0 wall's offset equals the as-built's applied shift along
    the wall's normal (the truth's normal is the IFC placement's local y, as offset_m's)."""
    from bimcap.sim.building_truth import load_building_truth

    truth = load_building_truth(world["truth"]).deviations
    assert truth is not None
    walls = [e for e in report.elements if e.ifc_class == "IfcWall" and e.storey == "S0"]
    assert len(walls) == 6
    for e in walls:
        shift = truth.wall_shifts[e.name]
        assert e.offset_m == pytest.approx(shift, abs=0.005), e.name
        expected = "deviating" if abs(shift) > 0.02 else "ok"
        if abs(abs(shift) - 0.02) > 0.005:  # clear of the tolerance
            assert e.status.value == expected, (e.name, shift, e.offset_m)
    corr_north = report.by_name("S0/wall/corr-north")
    assert corr_north.status.value == "deviating" and corr_north.coverage > 0.3
    assert corr_north.tilt_deg is not None and abs(corr_north.tilt_deg) < 0.3


def test_missing_column_is_missing_and_the_unseen_storey_unobserved(world: dict[str, Path],
                                                                     report: Any) -> None:
    from bimcap.sim.building_truth import load_building_truth

    truth = load_building_truth(world["truth"]).deviations
    assert truth is not None and "S0/column/corridor-1" in truth.missing
    col = report.by_name("S0/column/corridor-1")
    assert col.status.value == "missing" and col.n_points == 0 and col.passes >= 30
    # the walk stays on S0: nothing of S1 is judged, and nothing it never saw is called missing
    upper = [e for e in report.elements if e.storey == "S1"]
    assert upper and all(e.status.value == "unobserved" for e in upper)
    assert report.by_name("S1/wall/corr-north").offset_m is None
    missing = {e.name for e in report.elements if e.status.value == "missing"}
    assert missing <= set(truth.missing)
    # a present column: its (dx, dy) as applied; a floor and a ceiling where the model has them
    seen_plates = [e for e in report.elements if e.status.value == "ok"
                   and e.ifc_class in ("IfcSlab", "IfcCovering")]
    assert seen_plates and all(abs(e.offset_m) < 0.005 for e in seen_plates)


def test_deviations_cli_writes_json_csv_ply(world: dict[str, Path], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    import csv
    import json

    import open3d as o3d

    from bimcap.cli import main

    seq = world["seq"]
    out = tmp_path / "dev"
    rc = main(["deviations", "--sequence", str(seq), "--poses", str(seq / "poses" / "gt.tum"),
               "--ifc", str(world["design"]), "-o", str(out), "--storey", "S0"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "1 missing" in text and "S0/wall/corr-south" in text
    doc = json.loads((out / "deviations.json").read_text())
    assert doc["format"] == "bimcap-deviations"
    first = doc["elements"][0]
    assert {"guid", "ifc_class", "name", "storey", "status", "offset_m", "coverage",
            "n_points"} <= set(first)
    assert {e["storey"] for e in doc["elements"]} == {"S0"}
    with (out / "deviations.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["guid"] for r in rows] == [e["guid"] for e in doc["elements"]]
    by_name = {r["name"]: r for r in rows}
    assert by_name["S0/column/corridor-1"]["status"] == "missing"
    assert by_name["S0/column/corridor-1"]["offset_m"] == ""
    cloud = o3d.io.read_point_cloud(str(out / "deviations.ply"))
    assert len(cloud.points) > 1000 and len(cloud.colors) == len(cloud.points)
    assert (out / "deviations.png").stat().st_size > 10_000
    # the property sets a BIM viewer shows, on the same GUIDs
    import ifcopenshell
    import ifcopenshell.util.element as ue

    ifc = ifcopenshell.open(str(out / "deviations.ifc"))
    pset = ue.get_pset(ifc.by_guid(by_name["S0/wall/corr-south"]["guid"]), "BIMCaP_Deviation")
    assert pset["Status"] == "deviating"
    assert pset["Offset_m"] == pytest.approx(float(by_name["S0/wall/corr-south"]["offset_m"]),
                                             abs=1e-4)
    column = ue.get_pset(ifc.by_guid(by_name["S0/column/corridor-1"]["guid"]),
                         "BIMCaP_Deviation")
    assert column["Status"] == "missing" and "Offset_m" not in column
    # the BCF topics: one per deviating or missing element, its GUID selected in the viewpoint
    import zipfile
    from xml.etree import ElementTree as ET

    with zipfile.ZipFile(out / "deviations.bcfzip") as z:
        selected = sorted(ET.fromstring(z.read(n)).find("Components/Selection/Component")
                          .get("IfcGuid") for n in z.namelist() if n.endswith(".bcfv"))
    assert selected == sorted(e["guid"] for e in doc["elements"]
                              if e["status"] in ("deviating", "missing"))
    # a second run does not replace the first one's files without --overwrite
    args = ["deviations", "--sequence", str(seq), "--poses", str(seq / "poses" / "gt.tum"),
            "--ifc", str(world["design"]), "-o", str(out), "--storey", "S0"]
    before = (out / "deviations.json").read_bytes()
    assert main(args) == 2
    assert "pass --overwrite" in capsys.readouterr().err
    assert (out / "deviations.json").read_bytes() == before
    # a run directory that is not one: exit 2, the message names it
    rc = main(["deviations", str(tmp_path)])
    assert rc == 2
    assert "not a refine run" in capsys.readouterr().err


def test_bad_options_name_the_field() -> None:
    from bimcap.deviations.analysis import DeviationInputError, DeviationOptions

    with pytest.raises(DeviationInputError, match="tolerance_m: must be a finite number > 0"):
        DeviationOptions(tolerance_m=-1.0)
    with pytest.raises(DeviationInputError, match=r"missing_fraction: must be in \(0, 1\]"):
        DeviationOptions(missing_fraction=2.0)


@pytest.mark.slow
def test_refine_with_deviations_then_the_run_directory(world: dict[str, Path], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    """``refine --deviations`` writes the map and the deviations into the run's set; ``bimcap
    deviations RUN_DIR`` finds the sequence and the IFC from the run's result.json."""
    import json

    pytest.importorskip("bimcap._core", reason="the C++ core is not built")
    from bimcap.cli import main
    from bimcap.io.outputs import verify_outputs

    run = tmp_path / "run"
    gt = world["seq"] / "poses" / "gt.tum"
    rc = main(["refine", str(world["seq"]), "-o", str(run), "--init", str(gt), "--deviations",
               "-q", "--workers", "1"])
    assert rc == 0
    assert "deviations: " in capsys.readouterr().out
    doc = json.loads((run / "result.json").read_text())
    assert {"map_refined.ply", "deviations.json", "deviations.csv", "deviations.ply",
            "deviations.png", "deviations.ifc", "deviations.bcfzip"} <= set(doc["outputs"])
    html = (run / "report.html").read_text()
    assert "Scan vs BIM: deviations" in html and "S0/column/corridor-1" in html
    assert verify_outputs(run) == []
    assert doc["inputs"]["ifc"] == str(world["design"].resolve())
    dev = json.loads((run / "deviations.json").read_text())
    status = {e["name"]: e["status"] for e in dev["elements"]}
    assert status["S0/column/corridor-1"] == "missing"
    assert status["S0/wall/corr-south"] == "deviating"  # -4.2 cm
    rc = main(["deviations", str(run)])
    assert rc == 0
    assert (run / "deviations" / "deviations.json").is_file()


@pytest.mark.slow
def test_experiment_gains_the_deviation_columns(tmp_path: Path) -> None:
    import csv
    import math

    pytest.importorskip("bimcap._core", reason="the C++ core is not built")
    from bimcap.pipeline.config import Method, RefineConfig
    from bimcap.pipeline.experiment import DEVIATION_COLUMNS, ExperimentOptions, run_experiment

    opts = ExperimentOptions(experiments=("exp2",), seeds=(1,),
                             ablations=((Method.BIMCAP, "G+F+W+Co+Ce"),), preset="tiny",
                             frames=12, scale=0.125, config=RefineConfig(workers=1),
                             deviations=True)
    init, bimcap = run_experiment(tmp_path, opts, quiet=True)
    # the drifted poses (30 cm) put every wall off; the refined ones bring the offsets back
    assert bimcap.values["dev_offset_rmse_m"] < 0.5 * init.values["dev_offset_rmse_m"]
    assert bimcap.values["dev_offset_rmse_m"] < 0.03
    with (tmp_path / "results.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert set(DEVIATION_COLUMNS) <= set(rows[0])
    assert not math.isnan(float(rows[1]["dev_offset_rmse_m"]))


def test_clutter_comes_out_as_a_cluster(world: dict[str, Path], report: Any) -> None:
    """The simulator's placed clutter (the manifest's ``source.clutter``) is in no IFC element:
    each object is a cluster whose box holds its centre; shifted walls make none."""
    import json

    placed = json.loads((world["seq"] / "manifest.json").read_text())["source"]["clutter"]
    assert placed and report.clusters
    for obj in placed:
        x, y = obj["center_xy"]
        assert any(c.min[0] - 0.05 <= x <= c.max[0] + 0.05 and c.min[1] - 0.05 <= y
                   <= c.max[1] + 0.05 for c in report.clusters), obj
    assert len(report.clusters) <= 2 * len(placed)
    big = report.clusters[0]
    assert 0.3 < big.extent[2] < 2.0 and big.n_points >= 30
