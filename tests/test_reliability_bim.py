"""Issue 12, item 2: ``bimcap bim`` never exits 0 with an unusable reference.

Variants of real IFCs (``../shared/data/ifc/AC20-FZK-Haus.ifc``) and of a generated building,
made by text edits into ``tmp_path`` (``_ifc_edits``): a model moved up 300 m (georeferenced z),
without IfcBuildingStorey, with a length-unit prefix changed without rescaling, cut with the
trailer re-appended, with a malformed line. Storey heights come from the geometry where the
attributes disagree or are absent; a damaged file's losses are counted and refused past
``--max-lost-fraction``; an empty floor plan or cloud is an error.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bimcap
from _ifc_edits import cut, double_paren, drop_storeys, length_unit_prefix, move_up, rename_class
from bimcap.bim.errors import BimInputError
from bimcap.cli import main

#: The bimcap under test (PYTHONPATH), handed to the subprocesses.
SOURCES = Path(bimcap.__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny preset of the building generator (one storey, 6 walls, 2 columns)."""
    from bimcap.sim.building import PRESETS, generate_building

    path = tmp_path_factory.mktemp("gen") / "tiny.ifc"
    generate_building(PRESETS["tiny"], seed=0, ifc_path=path)
    return path


def _tiny_elements() -> int:
    """Building elements of the tiny preset (walls, slabs, coverings, columns, doors, windows):
    what the damage check counts, from the generator's own counts."""
    from bimcap.sim.building import PRESETS, expected_counts

    counts = expected_counts(PRESETS["tiny"])
    return sum(v for k, v in counts.items() if k not in ("IfcBuildingStorey", "IfcOpeningElement"))


@pytest.fixture(scope="module")
def fzk(ifc_dir: Path) -> Path:
    return ifc_dir / "AC20-FZK-Haus.ifc"


def _variant(src: Path, tmp: Path, name: str, edit) -> Path:
    path = tmp / f"{src.stem}-{name}.ifc"
    path.write_text(edit(src.read_text(errors="surrogateescape")), errors="surrogateescape")
    return path


def _bim(model: Path, out: Path, *extra: str) -> tuple[int, str, str]:
    """``bimcap bim`` in a subprocess (a damaged file must not hang it: timeout)."""
    r = subprocess.run([sys.executable, "-m", "bimcap", "bim", str(model), "-o", str(out), *extra],
                       capture_output=True, text=True, timeout=300,
                       env={"PYTHONPATH": str(SOURCES), "PATH": "/usr/bin:/bin"})
    return r.returncode, r.stdout, r.stderr


def _reference(out: Path) -> dict:
    return json.loads((out / "reference.json").read_text())


# ----------------------------------------------------------------------------- storey heights
def _summary(path: Path) -> tuple[dict, list[str]]:
    """The reference summary of an IFC and the storey notes of its loading."""
    import warnings

    from bimcap.bim.errors import BimWarning
    from bimcap.bim.ingest import load_model
    from bimcap.bim.reference import build_reference

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BimWarning)
        model = load_model(path, include_furniture=False)
        summary = build_reference(model).summary()
    summary["damage"] = model.damage
    return summary, model.notes


@pytest.fixture(scope="module")
def fzk_original(fzk: Path) -> tuple[dict, list[str]]:
    return _summary(fzk)


def _check_moved(orig: dict, ref: dict, notes: list[str]) -> None:
    assert any("stand at 300.000 m" in n and "using its placement's height" in n for n in notes)
    walls0, walls = orig["segments"]["wall"], ref["segments"]["wall"]
    assert walls["count"] > 0  # 0 before: the cut used Elevation 0, the walls stood at 300 m
    assert walls["length_m"] == pytest.approx(walls0["length_m"], rel=0.05)
    for a, b in zip(orig["storeys"], ref["storeys"], strict=True):
        assert b["elevation_m"] == pytest.approx(a["elevation_m"] + 300.0, abs=1e-6)


def _check_no_storeys(orig: dict, ref: dict, notes: list[str]) -> None:
    assert any("has no IfcBuildingStorey" in n for n in notes)
    assert ref["segments"]["wall"]["count"] > 0  # 0 before
    assert ref["segments"]["wall"]["length_m"] == pytest.approx(
        orig["segments"]["wall"]["length_m"], rel=0.05)
    np.testing.assert_allclose([s["elevation_m"] for s in ref["storeys"]],
                               [s["elevation_m"] for s in orig["storeys"]], atol=0.05)
    assert all("(from geometry)" in s["name"] for s in ref["storeys"])


def test_generated_moved_up_300_m(generated: Path, tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    moved = _variant(generated, tmp_path, "moved", lambda t: move_up(t, 300.0))
    assert main(["bim", str(moved), "-o", str(tmp_path / "moved")]) == 0
    assert "using its placement's height 300.000 m" in capsys.readouterr().out
    _check_moved(_summary(generated)[0], _reference(tmp_path / "moved"), _summary(moved)[1])


def test_generated_without_storeys(generated: Path, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    bare = _variant(generated, tmp_path, "nostorey", drop_storeys)
    assert main(["bim", str(bare), "-o", str(tmp_path / "bare")]) == 0
    assert "has no IfcBuildingStorey" in capsys.readouterr().out
    _check_no_storeys(_summary(generated)[0], _reference(tmp_path / "bare"), _summary(bare)[1])


@pytest.mark.slow
def test_fzk_moved_up_300_m(fzk: Path, fzk_original: tuple[dict, list[str]],
                            tmp_path: Path) -> None:
    ref, notes = _summary(_variant(fzk, tmp_path, "moved", lambda t: move_up(t, 300.0)))
    _check_moved(fzk_original[0], ref, notes)


@pytest.mark.slow
def test_fzk_without_storeys(fzk: Path, fzk_original: tuple[dict, list[str]],
                             tmp_path: Path) -> None:
    ref, notes = _summary(_variant(fzk, tmp_path, "nostorey", drop_storeys))
    _check_no_storeys(fzk_original[0], ref, notes)


# ----------------------------------------------------------------------------- units
@pytest.mark.parametrize("source", ["generated", pytest.param("fzk", marks=pytest.mark.slow)])
def test_unit_prefix_without_rescaling_is_refused(source: str, request: pytest.FixtureRequest,
                                                  tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    src = request.getfixturevalue(source)
    mm = _variant(src, tmp_path, "mm", length_unit_prefix)
    assert main(["bim", str(mm), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert str(mm) in err and "LENGTHUNIT" in err and "MILLIMETRE" in err
    assert not (tmp_path / "out").exists()  # nothing written


# ----------------------------------------------------------------------------- damage
def test_generated_cut_file_is_refused_with_counts(generated: Path, tmp_path: Path) -> None:
    bad = _variant(generated, tmp_path, "cut", lambda t: cut(t, 0.6))
    rc, _, err = _bim(bad, tmp_path / "out")
    assert rc == 2, err
    assert str(bad) in err and "damaged IFC file" in err and "missing from the file" in err
    assert f"of {_tiny_elements()} building elements" in err
    # A higher limit uses what is left, and says so loudly.
    rc, _, err = _bim(bad, tmp_path / "out", "--max-lost-fraction", "1")
    assert rc == 0, err
    assert "WARNING" in err and "DAMAGED IFC FILE" in err


def test_generated_malformed_line_is_refused(generated: Path, tmp_path: Path) -> None:
    bad = _variant(generated, tmp_path, "unknown",
                   lambda t: rename_class(t, "IFCWALL", "IFCWALLXX"))
    from bimcap.bim.ingest import load_model

    with pytest.raises(BimInputError,
                       match=rf"lost 1 of {_tiny_elements()} building elements .*1 unreadable"):
        load_model(bad)


def test_parser_swallowing_the_rest_neither_hangs_nor_passes(generated: Path,
                                                             tmp_path: Path) -> None:
    bad = _variant(generated, tmp_path, "dbl", lambda t: double_paren(t, "IFCWALL"))
    rc, _, err = _bim(bad, tmp_path / "out")
    assert rc == 2, err
    assert "instances IfcOpenShell could not read" in err


@pytest.mark.slow
def test_fzk_cut_is_refused(fzk: Path, tmp_path: Path) -> None:
    """FZK-Haus cut at 60 % (walls 13 → 9 before, silently)."""
    bad = _variant(fzk, tmp_path, "cut", lambda t: cut(t, 0.6))
    rc, _, err = _bim(bad, tmp_path / "out")
    assert rc == 2, err
    assert "lost 13 of 84 building elements" in err and "13 missing from the file" in err


@pytest.mark.slow
def test_fzk_one_malformed_wall_is_a_loud_warning(fzk: Path, tmp_path: Path) -> None:
    """One unreadable wall of 85 elements (1.2 %, under the 2 % default): a warning with counts."""
    bad = _variant(fzk, tmp_path, "unknown",
                   lambda t: rename_class(t, "IFCWALLSTANDARDCASE", "IFCWALLXX"))
    rc, _out, err = _bim(bad, tmp_path / "out")
    assert rc == 0, err
    assert "WARNING" in err and "lost 1 of 85 building elements" in err and "IFCWALLXX 1" in err
    rc, _, err = _bim(bad, tmp_path / "strict", "--max-lost-fraction", "0")
    assert rc == 2 and "damaged IFC file" in err


@pytest.mark.slow
def test_fzk_double_paren_neither_hangs_nor_passes(fzk: Path, tmp_path: Path) -> None:
    """Before: IfcOpenShell read 8636 of 44249 instances; the geometry iterator then waited
    forever with two threads."""
    bad = _variant(fzk, tmp_path, "dbl", lambda t: double_paren(t, "IFCWALLSTANDARDCASE"))
    rc, _, err = _bim(bad, tmp_path / "out")
    assert rc == 2, err
    assert "35613 of 44249 instances IfcOpenShell could not read" in err


@pytest.mark.slow
def test_real_models_are_not_reported_damaged(ifc_dir: Path,
                                              fzk_original: tuple[dict, list[str]]) -> None:
    """No false alarm on the real models: no dangling reference in any; FZK-Haus loads without
    damage and without a storey correction."""
    from bimcap.bim.ingest import _scan_step_text

    for path in sorted(ifc_dir.glob("*.ifc")):
        assert not _scan_step_text(path).dangling, path.name
    summary, notes = fzk_original
    assert summary["damage"] is None and notes == []


# ----------------------------------------------------------------------------- empty reference
def test_empty_floor_plan_or_cloud_is_an_error(generated: Path) -> None:
    from bimcap.bim.ingest import load_model
    from bimcap.bim.reference import build_reference

    ref = build_reference(load_model(generated))
    ref.check_usable()
    empty_plan = dataclasses.replace(ref, segments=np.zeros((0, 4)),
                                     segment_class=np.zeros(0, np.int32),
                                     segment_z=np.zeros((0, 2)))
    with pytest.raises(BimInputError, match="empty floor plan") as info:
        empty_plan.check_usable()
    assert str(generated) in str(info.value) and "S0 0.000 m" in str(info.value)
    no_cloud = dataclasses.replace(ref, points=np.zeros((0, 3)), labels=np.zeros(0, np.uint8))
    with pytest.raises(BimInputError, match="empty semantic cloud"):
        no_cloud.check_usable()
