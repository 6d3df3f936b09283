"""Bad input gives a BimInputError naming the file and what is missing; the CLI exits 2."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from _bim_building import build_simple_building
from bimcap.bim.errors import BimError, BimInputError
from bimcap.bim.ingest import load_model
from bimcap.bim.reference import BimReference
from bimcap.cli import main
from bimcap.errors import InputError


@pytest.fixture(scope="module")
def good_ifc(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("good") / "good.ifc"
    build_simple_building(path, n_storeys=1)
    return path


def _raises(path: Path, field: str | None, words: str) -> BimInputError:
    with pytest.raises(BimInputError) as info:
        load_model(path)
    err = info.value
    assert isinstance(err, BimError) and isinstance(err, InputError)
    assert err.path == str(path)
    assert str(path) in str(err)
    assert err.field == field
    assert words in str(err)
    return err


def test_missing_file(tmp_path: Path) -> None:
    _raises(tmp_path / "nope.ifc", None, "file not found")


def test_not_ifc(tmp_path: Path) -> None:
    p = tmp_path / "model.ifc"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))
    _raises(p, "header", "not an IFC STEP file")


def test_truncated(tmp_path: Path, good_ifc: Path) -> None:
    data = good_ifc.read_bytes()
    p = tmp_path / "cut.ifc"
    p.write_bytes(data[: len(data) // 2])
    _raises(p, "trailer", "truncated IFC file")


def test_garbage_body(tmp_path: Path) -> None:
    p = tmp_path / "junk.ifc"
    p.write_text("ISO-10303-21;\nHEADER;\nthis is not STEP\nEND-ISO-10303-21;\n")
    with pytest.raises(BimInputError) as info:
        load_model(p)
    assert str(p) in str(info.value)


def test_no_walls(tmp_path: Path) -> None:
    p = tmp_path / "nowalls.ifc"
    build_simple_building(p, n_storeys=1, with_walls=False)
    _raises(p, "IfcWall", "the model has no walls")


def test_cli_reports_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "model.ifc"
    p.write_text("hello")
    assert main(["bim", str(p), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "bimcap bim: error:" in err and str(p) in err and "ISO-10303-21" in err
    assert not (tmp_path / "out").exists()


def test_cli_refuses_to_overwrite_input(good_ifc: Path) -> None:
    assert main(["bim", str(good_ifc), "-o", str(good_ifc)]) == 2


def test_load_reference_errors(tmp_path: Path) -> None:
    with pytest.raises(BimInputError, match=re.escape("reference.json")):
        BimReference.load(tmp_path)


def test_cli_writes_everything(good_ifc: Path, tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["bim", str(good_ifc), "-o", str(out), "--density", "20", "--meshes"]) == 0
    text = capsys.readouterr().out
    assert "storeys: Storey 0 0.000 m" in text
    assert "coverage" in text and "precision" in text
    names = {p.name for p in out.iterdir()}
    assert {"reference.json", "planes.json", "floorplan.json", "reference.npz",
            "semantic_cloud.ply", "floorplan_00_Storey_0.svg", "floorplan_00_Storey_0.png",
            "mesh_wall.obj", "mesh_column.obj"} <= names
    ref = BimReference.load(out)
    assert ref.segments.shape[1] == 4 and len(ref.segments) > 10
    assert np.all(ref.segment_z == [0.0, 3.0])
    svg = (out / "floorplan_00_Storey_0.svg").read_text()
    assert svg.startswith("<svg") and "<line" in svg


def test_bad_options() -> None:
    from bimcap.bim.errors import BimOptionsError
    from bimcap.bim.floorplan import FloorPlanOptions

    with pytest.raises(BimOptionsError, match="resolution_m"):
        FloorPlanOptions(resolution_m=0.0)
    with pytest.raises(BimOptionsError, match="n_levels"):
        FloorPlanOptions(n_levels=0)
    with pytest.raises(ValueError, match="not a valid Vectorizer"):
        FloorPlanOptions(vectorizer="sobel")  # type: ignore[arg-type]


def test_damaged_reference(tmp_path: Path, good_ifc: Path) -> None:
    from bimcap.bim.reference import build_reference

    ref = build_reference(load_model(good_ifc))
    ref.save(tmp_path)
    (tmp_path / "reference.npz").write_bytes(b"not a zip")
    with pytest.raises(BimInputError, match=re.escape("reference.npz")):
        BimReference.load(tmp_path)
