"""The report states what it shows with a picture or a number (issue 17): run colours, shared
scales, idle terms, empty side views, the coarse stage, units; and the floor-plan pictures
(legend, SVG in metres). Built from hand-made inputs: no pipeline run, a few seconds."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bimcap.evaluation.metrics import trajectory_metrics
from bimcap.labels import LABEL_COLORS, Label
from bimcap.optimize.summary import SolveSummary, TermSummary
from bimcap.pipeline.report import ReportInput, RunRow, idle_terms, write_report

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _walk(n: int, dx: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    p = np.zeros((n, 7))
    p[:, 0], p[:, 1], p[:, 2] = np.linspace(1.0, 5.0, n) + dx, 2.0, 1.5
    # optical axis along +x, y down: columns x_cam (0, -1, 0), y_cam (0, 0, -1), z_cam (1, 0, 0)
    r0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    rz = Rotation.from_euler("z", np.full((n, 1), yaw_deg), degrees=True).as_matrix()
    p[:, 3:] = Rotation.from_matrix(rz @ r0).as_quat()
    return p


def _summary(terms: dict[str, tuple[int, float, float]], skipped: dict[str, int]) -> SolveSummary:
    """term → (samples, cost before, cost after); a term with 0 samples is inactive."""
    out = SolveSummary(success=True, termination="CONVERGENCE", iterations=5)
    for name, (n, before, after) in terms.items():
        out.terms.append(TermSummary(name=name, active=n > 0, num_residual_blocks=n,
                                     num_skipped=skipped.get(name, 0), initial_cost=before,
                                     final_cost=after, initial_rms=2.0 * before / max(n, 1),
                                     final_rms=after / max(n, 1)))
    out.initial_cost = sum(v[1] for v in terms.values())
    out.final_cost = sum(v[2] for v in terms.values())
    return out


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("report")
    n = 12
    gt, init, refined = _walk(n), _walk(n, 0.3, 9.0), _walk(n, 0.01, 0.1)
    stage1 = _summary({"G": (500, 9000.0, 400.0), "F": (80, 50.0, 5.0), "Ce": (0, 0.0, 0.0),
                       "W": (300, 800.0, 90.0), "prior": (12, 0.0, 1e-28)}, {})
    stage2 = _summary({"G": (500, 400.0, 380.0), "F": (80, 5.0, 4.0), "Ce": (0, 0.0, 0.0),
                       "W": (300, 90.0, 80.0), "Co": (0, 0.0, 0.0), "prior": (12, 1e-28, 2e-3)},
                      {"Co": 31})
    outcome = SimpleNamespace(
        summaries=[stage1, stage2], diverged_frames=[],
        coarse={"n_frames": n, "n_windows": 1, "accepted": [False] * n, "seconds": 0.5,
                "poses": init.tolist(), "frame_level": None, "near_probe_drift_m": 0.1,
                "windows": [{"start": 0, "stop": n, "n_points": 900, "accepted": False,
                             "n_hypotheses": 0,
                             "yaw_deg": 0.0, "t_m": [0.0, 0.0], "inlier_ratio": 0.0,
                             "score": 0.0, "reason": "input already near the plan"}]},
        reprojection={k: {"n": 1000, "behind": b, "median_px": m, "p90_px": 3 * m,
                          "rms_px": 9 * m, "inlier_px": 3.0, "inlier_share": s}
                      for k, b, m, s in (("before", 7, 41.5, 0.02), ("after", 0, 0.42, 0.97))})
    rows = [RunRow("initial", init, trajectory_metrics(init, gt)),
            RunRow("facap G+F+W", _walk(n, 0.2, 5.0), trajectory_metrics(_walk(n, 0.2, 5.0), gt),
                   summary=stage1, terms="G+F+W", g_unit="m",
                   outcome=SimpleNamespace(summaries=[stage1], coarse=None, diverged_frames=[],
                                           reprojection=None)),
            RunRow("bimcap G+F+W+Co+Ce", refined, trajectory_metrics(refined, gt),
                   summary=stage2, seconds=1.0, outcome=outcome, terms="G+F+W+Co+Ce")]
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(0, 6, 200), rng.uniform(0, 4, 200), np.zeros(200)])
    wall = np.column_stack([rng.uniform(0, 6, 200), np.full(200, 4.0), rng.uniform(0, 2.5, 200)])
    labels = np.repeat([int(Label.FLOOR), int(Label.WALL)], 200).astype(np.uint8)
    maps = {"before": (np.vstack([floor, wall]) + np.array([0.3, 0.0, 0.0]), labels),
            "after": (np.vstack([floor, wall]), labels)}
    segments = np.array([[0, 0, 6, 0], [6, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0],
                         [30, -20, 30, 20]], float)  # a far wall: the plot must not zoom out to it
    classes = np.array([Label.WALL] * 5)
    inp = ReportInput(title="test report", out_dir=out, rows=rows, segments=segments,
                      segment_class=classes, gt_poses=gt, map_points=maps,
                      heights={"BIM floor": 0.0, "BIM ceiling": 2.7},
                      scan_samples={"wall": 120, "floor": 30, "ceiling": 40})
    path = write_report(inp)
    return out, path.read_text()


def _text(html: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", re.sub(r'src="[^"]*"', "", html)))


def test_the_report_states_what_the_run_could_not_do(report: tuple[Path, str]) -> None:
    text = _text(report[1])
    assert "What this run could not do" in text
    assert "Ce: 0 samples, the term did not act" in text
    assert "Co: 0 samples (31 column samples skipped" in text
    # the maps hold the camera pixels' samples; the scan's ceiling samples are named, not hidden
    assert ("map after: no ceiling samples from the camera pixels (the LiDAR scan gave the solve "
            "40; not drawn)") in text
    assert ("no ceiling samples from the camera pixels; the LiDAR scan gave the solve 40 ceiling "
            "samples (not drawn).") in text
    assert "the coarse stage handed the poses back unchanged" in text
    assert "input already near the plan" in text  # the coarse stage's own reason
    assert "facap G+F+W: no coarse stage" in text


def test_the_solver_table_has_units_and_the_matches_share(report: tuple[Path, str]) -> None:
    text = _text(report[1])
    assert "px" in text and " σ " in text
    # BIMCaP's G in pixels, FACaP's (point error) in metres, W in metres
    assert re.search(r"1 G 500 0 36 px 0\.8 px", text)
    assert re.search(r"1 G 500 0 36 m 0\.8 m", text)
    assert re.search(r"W 300 0 [\d.]+ m [\d.]+ m", text)
    assert "median reprojection error 41.50 → 0.42 px" in text
    assert "2.0 % → 97.0 %" in text


def test_the_metrics_say_which_way_is_better(report: tuple[Path, str]) -> None:
    text = _text(report[1])
    assert text.count("↓ lower") == 9
    assert "MME : lower is better" in text and "negative by construction" in text


def test_the_figures_exist(report: tuple[Path, str]) -> None:
    figs = report[0] / "figures"
    names = {p.name for p in figs.glob("*.png")}
    assert {"trajectories.png", "errors_on_plan.png", "maps_on_plan.png", "map_3d.png",
            "side_before.png", "side_after.png", "errors_facap_g_f_w.png",
            "errors_bimcap_g_f_w_co_ce.png", "costs_bimcap_g_f_w_co_ce.png"} <= names
    for name in names:
        data = (figs / name).read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 5000, name
    assert report[1].count("data:image/png;base64,") == len(names)


def test_idle_terms_of_a_run_that_used_every_term() -> None:
    s = _summary({"G": (10, 1.0, 0.5), "W": (5, 1.0, 0.5)}, {})
    assert idle_terms(RunRow("x", np.zeros((1, 7)), summary=s, terms="G+W")) == []
    line = idle_terms(RunRow("x", np.zeros((1, 7)), summary=s, terms="G+W+Ce"))
    assert line == []  # Ce is not in the summary at all: nothing measured, nothing claimed
    s.terms.append(TermSummary(name="Ce"))
    assert idle_terms(RunRow("x", np.zeros((1, 7)), summary=s, terms="G+W+Ce")) == [
        "Ce: 0 samples, the term did not act"]


# ---- the floor-plan pictures ----------------------------------------------------------------

def _storey() -> object:
    from bimcap.bim.floorplan import StoreyPlan

    seg = np.array([[0, 0, 8, 0], [8, 0, 8, 5], [8, 5, 0, 5], [0, 5, 0, 0], [3, 2, 3.4, 2]], float)
    return StoreyPlan(storey="S0", elevation_m=0.0, band=np.array([1.0, 1.4]),
                      z_range=np.array([0.0, 3.0]), segments=seg,
                      segment_class=np.array([1, 1, 1, 1, 4], np.int32))


def test_floor_plan_svg_is_in_metres() -> None:
    from bimcap.bim.export import scale_bar_m, storey_svg, svg_frame

    sp = _storey()
    svg = storey_svg(sp)  # type: ignore[arg-type]
    x0, y0, w, h, head = svg_frame(sp)  # type: ignore[arg-type]
    assert (x0, y0, w, h) == pytest.approx((-0.5, -0.5, 9.0, 6.0))  # extent + 0.5 m margin
    vb = [float(v) for v in re.search(r'viewBox="([^"]+)"', svg).group(1).split()]  # type: ignore[union-attr]
    assert vb == pytest.approx([-0.5, -(5.5 + head), 9.0, 6.0 + head], abs=1e-4)
    # the wall from (8, 0) to (8, 5) in metres, y drawn as -y
    assert 'x1="8.0000" y1="-0.0000" x2="8.0000" y2="-5.0000"' in svg
    assert all(s in svg for s in (">wall<", ">column<", ">exact slice<"))
    assert f">{scale_bar_m(9.0):g} m<" in svg and scale_bar_m(9.0) == 1.0
    assert scale_bar_m(60.0) == 10.0 and scale_bar_m(30.0) == 5.0


def test_floor_plan_png_has_a_legend() -> None:
    import cv2

    from bimcap.bim.export import storey_png

    img = cv2.imdecode(np.frombuffer(storey_png(_storey()), np.uint8),  # type: ignore[arg-type]
                       cv2.IMREAD_COLOR)
    legend = img[50:62]  # the legend's row, under the two title lines, above the plan
    for label in (Label.WALL, Label.COLUMN):
        bgr = LABEL_COLORS[int(label)][::-1]
        assert (np.abs(legend.astype(int) - bgr).sum(axis=2) < 30).sum() > 20, label.name


def test_the_report_has_contents_linking_every_section(report: tuple[Path, str]) -> None:
    doc = report[1]
    ids = re.findall(r"<h2 id='([^']+)'>", doc)
    assert len(ids) == doc.count("<h2") >= 8 and len(set(ids)) == len(ids)
    nav = re.search(r"<nav>(.*?)</nav>", doc)
    assert nav is not None and re.findall(r"href='#([^']+)'", nav.group(1)) == ids
    assert doc.index("<nav>") < doc.index("<h2")  # under the title, above the first section
    # the settings JSON is folded; a window whose search did not run shows no numbers
    assert re.search(r"<details><summary>[^<]*</summary><pre>", doc)
    assert re.search(r"0–11 900 no – – – – input already near the plan", _text(doc))
    # round-off of a zero reads 0 in the solver table (the prior's 1e-28 cost)
    assert "1e-28" not in _text(doc).split("Solver")[-1]


def test_a_report_without_ground_truth_says_so(tmp_path: Path) -> None:
    n = 6
    rows = [RunRow("initial", _walk(n, 0.3)), RunRow("bimcap G+F+W", _walk(n), seconds=0.5)]
    inp = ReportInput(title="no gt", out_dir=tmp_path, rows=rows,
                      segments=np.array([[0.0, 0.0, 6.0, 0.0]]),
                      segment_class=np.array([int(Label.WALL)]))
    text = _text(write_report(inp).read_text())
    assert "No ground truth for this run" in text and "Error per frame" not in text
    assert "This run has no ground truth: the runs alone are drawn." in text
    assert "LiDAR" not in text  # no scan note without scan samples
    from bimcap.pipeline.report import _scan_note

    note = _scan_note({"wall": 5, "floor": 2, "frames_without_matches": [3, 4]})[0]
    assert "(5 wall, 2 floor)" in note and "Frames without a match (2: [3, 4])" in note


def test_tiny_costs_beside_the_chart_read_as_zero() -> None:
    """The pose prior starts at its minimum: its cost is round-off (2e-31), written as 0."""
    from bimcap.evaluation.plots import _cost_text

    assert _cost_text(2.1e-31, 9000.0) == "0"
    assert _cost_text(0.0, 9000.0) == "0"
    assert _cost_text(2e-3, 100.0) == "0.002"
    assert _cost_text(12.5, 9000.0) == "12"
