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


def test_streamed_refined_map_equals_the_whole_merge(world: dict[str, Path], scans: Any) -> None:
    """``stream_refined_map`` (a few scans at a time, what ``bimcap refine`` writes) gives the
    map of ``build_refined_map`` on every return at once: the same voxels, their centroids to
    the rounding of the sums, the same labels, returns and frames."""
    from bimcap.dataset import read_sequence
    from bimcap.deviations.refined_map import build_refined_map, stream_refined_map

    seq = read_sequence(world["seq"])
    samples = scans.p_in_world[::500]
    values = np.arange(len(samples)) % 4 + 1
    whole = build_refined_map(scans, label_points=samples, label_values=values, z_range=(0.5, 2.0))
    streamed = stream_refined_map(seq, seq.trajectory("gt").poses, label_points=samples,
                                  label_values=values, z_range=(0.5, 2.0), chunk_frames=3)
    assert len(streamed.points) == len(whole.points) > 1000
    np.testing.assert_allclose(streamed.points, whole.points, rtol=0, atol=1e-12)
    assert np.array_equal(streamed.labels, whole.labels)
    assert (streamed.returns, streamed.frames) == (whole.returns, whole.frames)
    assert streamed.returns < len(scans)  # the crop dropped the floor and the ceiling


def test_voxel_accumulator_in_chunks_is_the_voxel_centroid() -> None:
    """Centroids on the world-aligned grid, whatever the chunking: checked against a direct
    computation per voxel (floor(p / voxel) as the voxel's index)."""
    from bimcap.deviations.refined_map import RefinedMapError, VoxelAccumulator

    rng = np.random.default_rng(3)
    p = rng.uniform(-2.0, 2.0, (5000, 3))
    acc = VoxelAccumulator(0.5)
    for part in np.array_split(p, 7):
        acc.add(part)
    cells = np.floor(p / 0.5).astype(int)
    _, inverse = np.unique(cells, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    expected = np.array([p[inverse == v].mean(axis=0) for v in range(inverse.max() + 1)])
    got = acc.centroids()
    assert len(got) == len(expected) == 512 and acc.points_added == 5000
    order = np.lexsort(expected.T)
    np.testing.assert_allclose(got[np.lexsort(got.T)], expected[order], atol=1e-12)
    with pytest.raises(RefinedMapError, match="km from the first ones"):
        acc.add(np.array([[1e9, 0.0, 0.0]]))
    with pytest.raises(RefinedMapError, match="voxel_m"):
        VoxelAccumulator(0.0)
    # a georeferenced map (northing 5.4e6 m, beyond the keys' ±31 km): the same voxels, moved
    shift = np.array([512_345.5, 5_401_234.5, 212.5])  # whole 0.5 m voxels
    far = VoxelAccumulator(0.5)
    for part in np.array_split(p + shift, 7):
        far.add(part)
    got_far = far.centroids() - shift
    np.testing.assert_allclose(got_far[np.lexsort(got_far.T)], expected[order], atol=1e-6)


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
    assert doc["datum"]["mode"] == "none" and "no datum" in text
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
    """``refine --deviations --datum`` writes the map and the deviations (relative to the datum)
    into the run's set; ``bimcap deviations RUN_DIR`` finds the sequence and the IFC from the
    run's result.json."""
    import json

    pytest.importorskip("bimcap._core", reason="the C++ core is not built")
    from bimcap.cli import main
    from bimcap.io.outputs import verify_outputs

    run = tmp_path / "run"
    gt = world["seq"] / "poses" / "gt.tum"
    rc = main(["refine", str(world["seq"]), "-o", str(run), "--init", str(gt), "--deviations",
               "-q", "--workers", "1", "--datum", ",".join(DATUM), "--map-storey", "S0"])
    assert rc == 0
    assert "deviations: " in capsys.readouterr().out
    doc = json.loads((run / "result.json").read_text())
    z_min, z_max = doc["map_refined"]["z_range"]  # S0: from 0.3 m under it to S1's elevation
    assert z_min == pytest.approx(-0.3) and 2.5 < z_max < 4.0
    import open3d as o3d

    z = np.asarray(o3d.io.read_point_cloud(str(run / "map_refined.ply")).points)[:, 2]
    assert len(z) > 1000 and z.min() >= z_min - 0.03 and z.max() < z_max + 0.03
    assert doc["deviations"]["datum"]["mode"] == "datum"
    assert doc["deviations"]["datum"]["names"] == DATUM_NAMES
    assert {"map_refined.ply", "deviations.json", "deviations.csv", "deviations.ply",
            "deviations.png", "deviations.ifc", "deviations.bcfzip"} <= set(doc["outputs"])
    html = (run / "report.html").read_text()
    assert "Scan vs BIM: deviations" in html and "S0/column/corridor-1" in html
    assert "Offsets relative to the datum (3 element(s)" in html
    assert verify_outputs(run) == []
    assert doc["inputs"]["ifc"] == str(world["design"].resolve())
    dev = json.loads((run / "deviations.json").read_text())
    status = {e["name"]: e["status"] for e in dev["elements"]}
    assert status["S0/column/corridor-1"] == "missing"
    assert status["S0/wall/corr-south"] == "deviating"  # -4.2 cm
    capsys.readouterr()
    rc = main(["deviations", str(run)])  # the run's datum is used again
    assert rc == 0
    again = json.loads((run / "deviations" / "deviations.json").read_text())
    assert again["datum"]["mode"] == "datum" and again["datum"]["names"] == DATUM_NAMES
    assert "datum of the refine run" in capsys.readouterr().err
    rc = main(["deviations", str(run), "--no-datum", "-o", str(tmp_path / "plain")])
    assert rc == 0
    plain = json.loads((tmp_path / "plain" / "deviations.json").read_text())
    assert plain["datum"]["mode"] == "none"
    assert main(["deviations", str(run), "--no-datum", "--datum", DATUM[0], "-o",
                 str(tmp_path / "both")]) != 0


def test_refine_refuses_an_unknown_map_storey_before_the_front_end(
        world: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--map-storey`` names a storey the IFC does not have: a one-line error naming the field
    and the storeys there are, from the BIM reference, before any frame is processed."""
    pytest.importorskip("bimcap._core", reason="the C++ core is not built")
    from bimcap.cli import main

    run = tmp_path / "run"
    rc = main(["refine", str(world["seq"]), "-o", str(run), "--init",
               str(world["seq"] / "poses" / "gt.tum"), "--workers", "1", "--map-storey", "S9"])
    err = capsys.readouterr().err
    assert rc != 0 and "map_storey" in err and "'S9'" in err and "S0" in err and "S1" in err
    assert "front end over" not in err
    assert not (run / "result.json").exists()


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


# ------------------------------------------------------------------------------ datum
#: The tiny world's datum: the two walls the as-built keeps at design, and the floor for z.
DATUM = ("name:S0/wall/ext-south", "name:S0/wall/ext-west", "name:S0/slab/floor")
DATUM_NAMES = [sel.removeprefix("name:") for sel in DATUM]


def _rigidly_offset(world_from_cam: np.ndarray) -> np.ndarray:
    """The poses moved by one rigid motion of the world: (+2.5, −2.0, +1.0) cm and 0.4° yaw
    about the origin, what a refinement pulled towards the design leaves in common."""
    from bimcap.geometry.poses import compose, matrix_to_pose

    yaw = np.radians(0.4)
    t = np.eye(4)
    t[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    t[:3, 3] = [0.025, -0.020, 0.010]
    return compose(np.repeat(matrix_to_pose(t[None]), len(world_from_cam), axis=0),
                   world_from_cam)


def test_datum_finds_shifted_walls_under_rigidly_offset_poses(world: dict[str, Path]) -> None:
    """Poses off by one rigid motion: without a datum the walls read wrong by up to 1.5 cm; with
    the datum (two walls built right, and the floor) every S0 wall reads its applied shift, the
    correction undoes the motion, and the report says what the offsets are relative to."""
    from bimcap.dataset import read_sequence
    from bimcap.deviations.analysis import analyse_deviations, load_design
    from bimcap.deviations.datum import DatumSpec
    from bimcap.deviations.refined_map import load_scans
    from bimcap.sim.building_truth import load_building_truth

    truth = load_building_truth(world["truth"]).deviations
    assert truth is not None and "S0/wall/ext-south" in truth.datum
    seq = read_sequence(world["seq"])
    moved = _rigidly_offset(seq.trajectory("gt").poses)
    model = load_design(world["design"])
    scans = load_scans(seq, moved)
    plain = analyse_deviations(model, scans, ifc_path=world["design"], storey="S0")
    spec = DatumSpec.parse(DATUM)
    fixed = analyse_deviations(model, scans, ifc_path=world["design"], storey="S0", datum=spec)
    walls = [e.name for e in plain.elements if e.ifc_class == "IfcWall"]
    assert len(walls) == 6
    err_plain = [abs(plain.by_name(n).offset_m - truth.wall_shifts[n]) for n in walls]
    err_fixed = [abs(fixed.by_name(n).offset_m - truth.wall_shifts[n]) for n in walls]
    assert max(err_plain) > 0.01  # the case that fails without a datum
    assert max(err_fixed) < 0.004, dict(zip(walls, err_fixed, strict=True))
    # the shifted corridor walls: found, with their offsets
    for name in ("S0/wall/corr-south", "S0/wall/corr-north"):
        e = fixed.by_name(name)
        assert e.status.value == "deviating" and not e.datum
        assert e.offset_m == pytest.approx(truth.wall_shifts[name], abs=0.004)
    assert fixed.by_name("S0/wall/ext-south").datum
    assert fixed.by_name("S0/slab/floor").offset_m == pytest.approx(0.0, abs=0.003)
    d = fixed.to_dict()["datum"]
    assert d["mode"] == "datum" and d["free"] == []
    assert d["yaw_deg"] == pytest.approx(-0.4, abs=0.05)
    # the correction maps the offset poses' sensor centres back onto the true ones
    t = np.asarray(d["world_datum_from_world"])
    back = moved[:, :3] @ t[:3, :3].T + t[:3, 3]
    assert np.abs(back - seq.trajectory("gt").poses[:, :3]).max() < 0.005
    assert plain.to_dict()["datum"]["mode"] == "none"
    assert "relative to the refined poses" in plain.to_dict()["datum"]["note"]
    # one rigid motion: the per-frame fit (the default) has little left to move (its own
    # noise: a few millimetres on this 12-frame walk)
    assert d["frames"]["frame_step_max_m"] < 0.006


def test_per_frame_datum_fit_removes_frame_to_frame_pose_error(world: dict[str, Path]) -> None:
    """Poses off by a rigid motion and, from the middle of the walk on, by 2 cm more in x and y
    (what a refinement leaves when part of the walk was pulled elsewhere): the rigid correction
    leaves a centimetre in the walls that half sees; the joint per-frame fit (frames placed by
    the datum and by the elements they share) reads every S0 wall within 3 mm."""
    from dataclasses import replace

    from bimcap.dataset import read_sequence
    from bimcap.deviations.analysis import analyse_deviations, load_design
    from bimcap.deviations.datum import DatumFitMode, DatumSpec
    from bimcap.deviations.refined_map import load_scans
    from bimcap.geometry.poses import compose, matrix_to_pose
    from bimcap.sim.building_truth import load_building_truth

    truth = load_building_truth(world["truth"]).deviations
    assert truth is not None
    gt = read_sequence(world["seq"]).trajectory("gt").poses
    n = len(gt)
    step = np.repeat(np.eye(4)[None], n, axis=0)
    step[:, :2, 3] = 0.02 * np.clip((np.arange(n) - n / 2) / 2, 0, 1)[:, None]
    moved = compose(matrix_to_pose(step), _rigidly_offset(gt))
    model = load_design(world["design"])
    scans = load_scans(read_sequence(world["seq"]), moved)
    frames = DatumSpec.parse(DATUM)
    assert frames is not None and frames.fit is DatumFitMode.FRAMES
    errors = {}
    for spec in (replace(frames, fit=DatumFitMode.RIGID), frames):
        rep = analyse_deviations(model, scans, ifc_path=world["design"], storey="S0",
                                 datum=spec)
        errors[spec.fit] = {e.name: abs(e.offset_m - truth.wall_shifts[e.name])
                            for e in rep.elements if e.ifc_class == "IfcWall"}
    assert len(errors[DatumFitMode.FRAMES]) == 6
    assert max(errors[DatumFitMode.RIGID].values()) > 0.008
    assert max(errors[DatumFitMode.FRAMES].values()) < 0.003, errors
    assert rep.datum["frames"]["n_elements"] >= 6
    assert len(rep.datum["frames"]["world_datum_from_world"]) == len(gt)


def test_bad_datum_input_is_refused_naming_the_flag(world: dict[str, Path]) -> None:
    from bimcap.deviations.analysis import load_design
    from bimcap.deviations.datum import DatumError, DatumSpec, check_datum

    with pytest.raises(DatumError, match=r"--datum: 'ext-south' is not an IFC GlobalId"):
        DatumSpec.parse(["ext-south"])
    with pytest.raises(DatumError, match=r"--datum: unknown selector 'tag:x'"):
        DatumSpec.parse(["tag:x"])
    assert DatumSpec.parse(["", " , "]) is None
    model = load_design(world["design"])
    unknown = "0123456789abcdefABCDEF"
    with pytest.raises(DatumError, match=f"--datum: unknown IFC GUID '{unknown}'"):
        DatumSpec.parse([unknown]).resolve(model)  # type: ignore[union-attr]
    with pytest.raises(DatumError, match=r"'name:S9/\*' matches no element"):
        DatumSpec.parse(["name:S9/*"]).resolve(model)  # type: ignore[union-attr]
    with pytest.raises(DatumError, match="only walls, columns, floor slabs and ceilings"):
        DatumSpec.parse(["class:IfcDoor"]).resolve(model)  # type: ignore[union-attr]
    # parallel walls only: x (along them) is free (their length gives yaw); one column: yaw
    parallel = DatumSpec.parse(["name:S0/wall/ext-south,name:S0/wall/corr-*"])
    assert parallel is not None
    with pytest.raises(DatumError, match=r"--datum: the datum \(3 element\(s\): .*\) leaves x "
                       "free: add an element of another orientation"):
        check_datum(model, parallel.resolve(model))
    one = DatumSpec.parse(["name:S0/column/hall"])
    assert one is not None
    with pytest.raises(DatumError, match="leaves yaw free"):
        check_datum(model, one.resolve(model))
    columns = DatumSpec.parse(["class:IfcColumn"])  # the corridor's and the hall's
    assert columns is not None and check_datum(model, columns.resolve(model)) == ["z"]
    # two walls of different orientation: x, y, yaw; z only with a slab or a ceiling
    walls = DatumSpec.parse(DATUM[:2])
    assert walls is not None and check_datum(model, walls.resolve(model)) == ["z"]
    full = DatumSpec.parse(DATUM)
    assert full is not None and check_datum(model, full.resolve(model)) == []


def test_deviations_cli_with_a_datum(world: dict[str, Path], tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """``--datum`` on rigidly offset poses: the corridor walls read their shifts; the JSON and
    the CSV mark the datum. A GUID the model lacks: exit 2 before the scans are read, naming
    the flag and the GUID; so does ``refine --deviations --datum``."""
    import csv
    import json

    from bimcap.cli import main
    from bimcap.geometry.trajectory import Trajectory, write_tum
    from bimcap.sim.building_truth import load_building_truth

    seq = world["seq"]
    from bimcap.dataset import read_sequence

    gt = read_sequence(seq).trajectory("gt")
    poses = tmp_path / "offset.tum"
    write_tum(poses, Trajectory(gt.timestamps, _rigidly_offset(gt.poses)))
    out = tmp_path / "dev"
    base = ["deviations", "--sequence", str(seq), "--poses", str(poses), "--ifc",
            str(world["design"]), "--storey", "S0"]
    rc = main([*base, "-o", str(out), "--datum", ",".join(DATUM)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "datum: 3 element(s); poses corrected by" in text
    doc = json.loads((out / "deviations.json").read_text())
    truth = load_building_truth(world["truth"]).deviations
    assert truth is not None
    by_name = {e["name"]: e for e in doc["elements"]}
    assert by_name["S0/wall/corr-south"]["offset_m"] == pytest.approx(
        truth.wall_shifts["S0/wall/corr-south"], abs=0.004)
    assert doc["datum"]["mode"] == "datum" and by_name["S0/wall/ext-west"]["datum"] is True
    with (out / "deviations.csv").open() as fh:
        rows = {r["name"]: r for r in csv.DictReader(fh)}
    assert rows["S0/wall/ext-west"]["datum"] == "True"
    assert rows["S0/wall/corr-south"]["datum"] == "False"
    unknown = "0123456789abcdefABCDEF"
    rc = main([*base, "-o", str(tmp_path / "bad"), "--datum", f"name:S0/wall/ext-*,{unknown}"])
    err = capsys.readouterr().err
    assert rc == 2 and f"--datum: unknown IFC GUID '{unknown}'" in err
    assert "Traceback" not in err and not (tmp_path / "bad").exists()
    rc = main([*base, "-o", str(tmp_path / "bad"), "--datum", "name:S0/wall/corr-*"])
    assert rc == 2 and "leaves x free" in capsys.readouterr().err
    rc = main(["refine", str(seq), "-o", str(tmp_path / "run"), "--init", str(poses),
               "--deviations", "--datum", unknown, "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and f"--datum / datum: unknown IFC GUID '{unknown}'" in err
    assert not (tmp_path / "run" / "refined.tum").exists()


def test_refine_config_reads_and_writes_the_datum(tmp_path: Path) -> None:
    from bimcap.pipeline.config import ConfigError, RefineConfig, toml_text

    toml = tmp_path / "run.toml"
    toml.write_text('datum = ["class:IfcColumn", "name:S0/wall/ext-*"]\ndatum_fit = "rigid"\n')
    cfg = RefineConfig.from_toml(toml)
    assert cfg.datum == ["class:IfcColumn", "name:S0/wall/ext-*"] and cfg.datum_fit == "rigid"
    again = tmp_path / "again.toml"
    again.write_text(toml_text({"datum": cfg.datum}))
    assert RefineConfig.from_toml(again).datum == cfg.datum
    assert RefineConfig().datum_fit == "frames"
    toml.write_text('datum_fit = "best"\n')
    with pytest.raises(ConfigError, match="datum_fit: unknown datum fit 'best'"):
        RefineConfig.from_toml(toml)
    toml.write_text('datum = ["ext-south"]\n')
    with pytest.raises(ConfigError, match=r"run.toml: datum: 'ext-south' is not an IFC GlobalId"):
        RefineConfig.from_toml(toml)
    toml.write_text('datum = "class:IfcColumn"\n')
    with pytest.raises(ConfigError, match="datum: must be a list of selectors"):
        RefineConfig.from_toml(toml)


def test_georeferenced_model_gives_the_same_deviations(world: dict[str, Path], scans: Any,
                                                       report: Any) -> None:
    """The design and the scans moved to a georeferenced position (northing 5.4·10⁶ m, where
    float32 ray casting steps by 0.5 m): the same status, offset and coverage per element."""
    from bimcap.deviations.analysis import analyse_deviations, load_design
    from bimcap.deviations.refined_map import ScanSet

    shift = np.array([512_345.6, 5_401_234.5, 212.3])
    model = load_design(world["design"])
    for e in model.elements:
        e.vertices = e.vertices + shift
    moved = ScanSet(scans.p_in_world + shift, scans.frame, scans.origins + shift)
    far = analyse_deviations(model, moved, ifc_path=world["design"])
    assert [e.name for e in far.elements] == [e.name for e in report.elements]
    for a, b in zip(report.elements, far.elements, strict=True):
        assert b.status == a.status, a.name
        if a.offset_m is not None:
            assert b.offset_m == pytest.approx(a.offset_m, abs=1e-3), a.name
        assert b.coverage == pytest.approx(a.coverage, abs=0.02), a.name
    assert len(far.clusters) == len(report.clusters)
