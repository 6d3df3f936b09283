"""``bimcap evaluate``: help, table, JSON against the oracle, clear errors without tracebacks."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bimcap.cli import main


def _write_tum(path: Path, n: int = 10, dx: float = 0.0) -> Path:
    lines = [f"{i:.1f} {i * 0.5 + dx} {np.sin(i)} 1.0 0 0 0 1" for i in range(n)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "EST.tum" in out and "--align" in out and "--reference" in out


def test_table_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    est = _write_tum(tmp_path / "est.tum", dx=0.1)
    gt = _write_tum(tmp_path / "gt.tum")
    out = tmp_path / "m" / "metrics.json"
    assert main(["evaluate", str(est), str(gt), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "ATE_pos" in text and "yaw RMSE" in text and "ZYX" in text
    d = json.loads(out.read_text())
    assert d["trajectory"]["ate_pos_m"]["rmse"] == pytest.approx(0.1, abs=1e-12)
    assert d["trajectory"]["align"] == "none"


@pytest.mark.needs_shared
def test_json_equals_evo_oracle(oracles_dir: Path, tmp_path: Path) -> None:
    d = oracles_dir / "trajectory"
    expected = json.loads((d / "trajectory_expected.json").read_text())["cases"]["sim3"]
    out = tmp_path / "metrics.json"
    assert (
        main(["evaluate", str(d / "est.tum"), str(d / "gt.tum"), "--align", "sim3", "-o", str(out)])
        == 0
    )
    got = json.loads(out.read_text())["trajectory"]
    assert got["ate_pos_m"]["rmse"] == pytest.approx(expected["trans_rmse_m"], abs=1e-9, rel=0)
    assert got["ate_rot_deg"]["mean"] == pytest.approx(expected["rot_mean_deg"], abs=1e-9, rel=0)


def test_map_and_reference(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import open3d as o3d

    rng = np.random.default_rng(0)
    ref = rng.uniform(0.0, 1.0, (300, 3))
    est_map = ref + rng.normal(0.0, 0.01, ref.shape)
    for name, pts in (("map.ply", est_map), ("ref.ply", ref)):
        o3d.io.write_point_cloud(
            tmp_path / name, o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        )
    est = _write_tum(tmp_path / "est.tum")
    out = tmp_path / "metrics.json"
    args = [
        "evaluate",
        str(est),
        str(est),
        "--map",
        str(tmp_path / "map.ply"),
        "--reference",
        str(tmp_path / "ref.ply"),
        "--radius",
        "0.3",
        "-o",
        str(out),
    ]
    assert main(args) == 0
    assert "NND" in capsys.readouterr().out
    m = json.loads(out.read_text())["map"]
    assert (
        0.0 < m["nnd_m"] < 0.05 and m["radius_m"] == 0.3 and m["nnd_reference"].endswith("ref.ply")
    )
    assert np.isfinite(m["mme"]) and m["mpv"] > 0


def test_missing_file_exits_2_without_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gt = _write_tum(tmp_path / "gt.tum")
    assert main(["evaluate", str(tmp_path / "nope.tum"), str(gt)]) == 2
    err = capsys.readouterr().err
    assert "nope.tum" in err and "no such file" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_malformed_file_names_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt = _write_tum(tmp_path / "gt.tum")
    bad = tmp_path / "bad.tum"
    bad.write_text("# header\n0.0 1 2 3 0 0 0 1\n1.0 1 2 x 0 0 0 1\n")
    assert main(["evaluate", str(bad), str(gt)]) == 2
    err = capsys.readouterr().err
    assert "bad.tum" in err and "line 3" in err and "Traceback" not in err


def test_no_matching_timestamps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt = _write_tum(tmp_path / "gt.tum")
    shifted = tmp_path / "late.tum"
    shifted.write_text("100.0 0 0 0 0 0 0 1\n")
    assert main(["evaluate", str(shifted), str(gt)]) == 2
    assert "no timestamps match" in capsys.readouterr().err


def test_never_overwrites_an_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt = _write_tum(tmp_path / "gt.tum")
    est = _write_tum(tmp_path / "est.tum", dx=0.2)
    keep = tmp_path / "copy.tum"
    shutil.copy(gt, keep)
    assert main(["evaluate", str(est), str(gt), "-o", str(gt)]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert gt.read_bytes() == keep.read_bytes()


def test_reference_without_map(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt = _write_tum(tmp_path / "gt.tum")
    assert main(["evaluate", str(gt), str(gt), "--reference", str(gt)]) == 2
    assert "--reference needs --map" in capsys.readouterr().err
