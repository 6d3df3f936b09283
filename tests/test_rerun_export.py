"""The Rerun recording of a run (``refine --rerun``, ``bimcap export-rerun``), loaded by the Rerun
CLI's ``rrd verify`` and read back with Rerun's own reader (``rerun.chunk.RrdReader``): the
entity paths, the frames on the ``frame`` timeline, the refined cameras against
``refined.tum``, the errors against ``gt.tum``."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bimcap.cli import main
from bimcap.geometry import read_tum

pytest.importorskip("bimcap._core", reason="the C++ core is not built")
pytest.importorskip("rerun", reason="the rerun extra is not installed")

#: Every entity a run with ground truth, a BIM, a map and images gives (BIMCaP only, no FACaP).
ENTITIES = {"/world", "/world/bim/walls", "/world/bim/columns", "/world/map_refined",
            "/world/camera", "/world/camera/image",
            *(f"/world/trajectories/{n}" for n in ("initial", "refined", "ground_truth")),
            *(f"/errors/{k}/{n}" for k in ("position", "rotation") for n in ("initial",
                                                                              "refined"))}


@pytest.fixture(scope="module")
def rerun_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo on the tiny building (8 frames at 1/8 ConSLAM resolution, BIMCaP only) with
    ``rerun = true``: its ``refine/`` is what ``bimcap refine --rerun`` writes."""
    from bimcap.pipeline.config import ColmapExport, RefineConfig
    from bimcap.pipeline.demo import DemoOptions, run_demo

    out = tmp_path_factory.mktemp("demo")
    cfg = RefineConfig(workers=1, rerun=True, colmap=ColmapExport.OFF)
    run_demo(out, DemoOptions(preset="tiny", frames=8, scale=0.125, fps=2.0, config=cfg,
                              facap=False), quiet=True)
    return out / "refine"


def read_recording(path: Path) -> dict[str, dict[str, list[Any]]]:
    """Entity path → column name → the values of every row, over all the entity's chunks
    (static and temporal), in the order of the ``frame`` timeline where there is one."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch().to_pydict()
        for i in range(chunk.num_rows):
            rows[chunk.entity_path].append({k: v[i] for k, v in batch.items()})
    out: dict[str, dict[str, list[Any]]] = {}
    for entity, items in rows.items():
        if entity.startswith("/__"):
            continue  # the recording's properties
        items.sort(key=lambda r: r.get("frame") if r.get("frame") is not None else -1)
        cols: dict[str, list[Any]] = defaultdict(list)
        for r in items:
            for k, v in r.items():
                if v is not None:
                    cols[k].append(v)
        out[entity] = dict(cols)
    return out


def _frames(cols: dict[str, list[Any]]) -> list[int]:
    return list(cols.get("frame", []))


@pytest.mark.slow
def test_refine_rerun_writes_the_recording_of_the_run(rerun_run: Path) -> None:
    result = json.loads((rerun_run / "result.json").read_text())
    assert result["files"]["rerun"] == "run.rrd" and "run.rrd" in result["outputs"]
    assert result["config"]["rerun"] is True
    rec = read_recording(rerun_run / "run.rrd")
    assert set(rec) == ENTITIES
    refined = read_tum(rerun_run / "refined.tum")
    n = len(refined)
    cam = rec["/world/camera"]
    assert _frames(cam) == list(range(n))  # one pose per frame on the frame timeline
    # the time timeline: seconds since the first frame
    np.testing.assert_allclose([t.total_seconds() for t in cam["time"]],
                               refined.timestamps - refined.timestamps[0], atol=1e-6)
    # the refined camera centres and rotations of refined.tum (float32 in the recording)
    centres = np.array([t[0] for t in cam["Transform3D:translation"]])
    np.testing.assert_allclose(centres, refined.poses[:, :3], rtol=0, atol=1e-5)
    quats = np.array([q[0] for q in cam["Transform3D:quaternion"]])
    np.testing.assert_allclose(np.abs(np.sum(quats * refined.poses[:, 3:], axis=1)), 1.0,
                               atol=1e-6)
    # a pinhole and a JPEG image for every frame
    image = rec["/world/camera/image"]
    assert len(image["Pinhole:image_from_camera"]) == n
    assert len(image["EncodedImage:blob"]) == n
    assert all(m == ["image/jpeg"] for m in image["EncodedImage:media_type"])
    assert rec["/world"]["ViewCoordinates:xyz"]  # RIGHT_HAND_Z_UP, logged once


@pytest.mark.slow
def test_the_viewer_loads_the_recording(rerun_run: Path) -> None:
    """Oracle: the Rerun CLI's ``rrd verify`` (Rust, the viewer's own loader), which loads the
    file and checks every chunk against the archetypes' schemas."""
    import subprocess
    import sys

    pytest.importorskip("rerun_cli", reason="rerun-sdk without its CLI")
    done = subprocess.run([sys.executable, "-m", "rerun_cli", "rrd", "verify",
                           str(rerun_run / "run.rrd")], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "1 file verified without error" in done.stdout + done.stderr


@pytest.mark.slow
def test_the_recording_holds_the_bim_the_trajectories_the_map_and_the_errors(
        rerun_run: Path) -> None:
    from bimcap.io.ply import read_labelled_ply

    rec = read_recording(rerun_run / "run.rrd")
    ref = np.load(rerun_run / "bim" / "reference.npz")
    for entity, label in (("/world/bim/walls", 1), ("/world/bim/columns", 4)):
        strips = rec[entity]["LineStrips3D:strips"][0]
        assert len(strips) == int((ref["segment_class"] == label).sum()) > 0
        assert all(len(s) == 5 and s[0] == s[-1] for s in strips)  # closed outlines
    gt = read_tum(rerun_run.parent / "sequence" / "poses" / "gt.tum")
    refined = read_tum(rerun_run / "refined.tum")
    for name, poses in (("ground_truth", gt.poses), ("refined", refined.poses)):
        strip = np.array(rec[f"/world/trajectories/{name}"]["LineStrips3D:strips"][0][0])
        np.testing.assert_allclose(strip, poses[:, :3], atol=1e-5)
    # the per-frame position error of the refined trajectory: |t - t_gt| of the two files
    err = np.array(rec["/errors/position/refined"]["Scalars:scalars"]).ravel()
    np.testing.assert_allclose(err, np.linalg.norm(refined.poses[:, :3] - gt.poses[:, :3],
                                                   axis=1), atol=1e-9)
    assert _frames(rec["/errors/rotation/initial"]) == list(range(len(gt)))
    points, labels = read_labelled_ply(rerun_run / "map_refined.ply")
    logged = np.array(rec["/world/map_refined"]["Points3D:positions"][0])
    assert len(logged) == min(len(points), 100_000) > 100
    assert set(rec["/world/map_refined"]["Points3D:class_ids"][0]) <= set(labels.tolist())


@pytest.mark.slow
def test_export_rerun_writes_the_same_recording_from_the_run_directory(
        rerun_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.rrd"
    assert main(["export-rerun", str(rerun_run), "-o", str(out), "--max-points", "500"]) == 0
    assert "8 frames, 8 images" in capsys.readouterr().out
    rec, refined_rec = read_recording(out), read_recording(rerun_run / "run.rrd")
    assert set(rec) == set(refined_rec) == ENTITIES
    for col in ("Transform3D:translation", "Transform3D:quaternion", "frame"):
        assert rec["/world/camera"][col] == refined_rec["/world/camera"][col]
    assert len(rec["/world/map_refined"]["Points3D:positions"][0]) == 500
    # smaller without images; an existing file is kept without --overwrite
    small = tmp_path / "small.rrd"
    assert main(["export-rerun", str(rerun_run), "-o", str(small), "--no-images", "-q",
                 "--max-points", "500"]) == 0
    assert "EncodedImage:blob" not in read_recording(small)["/world/camera/image"]
    assert small.stat().st_size < out.stat().st_size
    before = small.read_bytes()
    assert main(["export-rerun", str(rerun_run), "-o", str(small), "--no-images"]) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err
    assert small.read_bytes() == before


def test_export_rerun_names_a_missing_run_directory_or_result(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nope"
    assert main(["export-rerun", str(missing), "-o", str(tmp_path / "a.rrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"bimcap export-rerun: error: {missing}: no such run directory"]
    run = tmp_path / "run"
    run.mkdir()
    (run / "refined.tum").write_text("")
    assert main(["export-rerun", str(run), "-o", str(tmp_path / "a.rrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{run / 'result.json'}: missing" in err[0]
    (run / "result.json").write_text("{not json")
    assert main(["export-rerun", str(run), "-o", str(tmp_path / "a.rrd")]) == 2
    assert "result.json: not valid JSON" in capsys.readouterr().err
    assert not (tmp_path / "a.rrd").exists()
    assert not list(tmp_path.glob(".a.rrd*"))  # no temporary file left behind


def test_recording_options_are_checked() -> None:
    from bimcap.errors import InputError
    from bimcap.pipeline.rerun_export import RecordingOptions

    for bad in ({"image_scale": 0.0}, {"image_scale": 1.5}, {"jpeg_quality": 0},
                {"max_points": -1}):
        with pytest.raises(InputError, match=next(iter(bad))):
            RecordingOptions(**bad)


def test_wall_outlines_close_each_segment_over_its_z_band() -> None:
    from bimcap.pipeline.rerun_export import wall_outlines

    out = wall_outlines(np.array([[0.0, 1.0, 4.0, 1.0]]), np.array([[0.0, 3.0]]))
    np.testing.assert_array_equal(out[0], [[0, 1, 0], [4, 1, 0], [4, 1, 3], [0, 1, 3],
                                           [0, 1, 0]])


def test_the_config_file_and_the_flag_switch_the_recording_on(tmp_path: Path) -> None:
    import argparse

    from bimcap.cli import build_parser
    from bimcap.cli.refine import config_from_args
    from bimcap.pipeline.config import ConfigError, RefineConfig

    toml = tmp_path / "run.toml"
    toml.write_text("rerun = true\n")
    assert RefineConfig.from_toml(toml).rerun is True
    assert RefineConfig().rerun is False
    toml.write_text('rerun = "yes"\n')
    with pytest.raises(ConfigError, match="rerun must be true or false"):
        RefineConfig.from_toml(toml)
    args: argparse.Namespace = build_parser("refine").parse_args(
        ["refine", "seq", "-o", "out", "--rerun"])
    assert config_from_args(args).rerun is True
