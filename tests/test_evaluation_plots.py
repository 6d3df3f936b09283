"""Each plot writes a non-empty PNG (and returns its figure)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimcap.evaluation import plots
from bimcap.evaluation.errors import EvaluationError
from bimcap.evaluation.metrics import trajectory_metrics
from bimcap.labels import Label

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _is_png(path: Path) -> bool:
    return path.is_file() and path.stat().st_size > 1000 and path.read_bytes()[:8] == PNG_MAGIC


def _poses(n: int, offset: float) -> np.ndarray:
    s = np.linspace(0.0, 2.0 * np.pi, n)
    p = np.zeros((n, 7))
    p[:, 0], p[:, 1], p[:, 2] = 4 + 3 * np.cos(s) + offset, 4 + 2 * np.sin(s), 1.5
    p[:, 6] = 1.0
    return p


def test_trajectories_on_plan(tmp_path: Path) -> None:
    segments = np.array(
        [[0, 0, 8, 0], [8, 0, 8, 8], [8, 8, 0, 8], [0, 8, 0, 0], [4, 4, 4.4, 4]], float
    )
    classes = np.array([Label.WALL] * 4 + [Label.COLUMN])
    out = tmp_path / "plan.png"
    fig = plots.plot_trajectories_on_plan(
        segments, classes, {"ground truth": _poses(50, 0)[:, :3], "before": _poses(50, 0.3)}, out
    )
    assert fig is not None and _is_png(out)
    with pytest.raises(EvaluationError):
        plots.plot_trajectories_on_plan(segments, classes[:2], {}, tmp_path / "x.png")


def test_errors_per_frame(tmp_path: Path) -> None:
    gt = _poses(40, 0.0)
    before = trajectory_metrics(_poses(40, 0.3), gt).frame_errors
    after = trajectory_metrics(_poses(40, 0.01), gt).frame_errors
    assert before is not None and after is not None
    out = tmp_path / "sub" / "errors.png"
    plots.plot_errors_per_frame(before, after, out)
    assert _is_png(out)


def test_side_view(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(0.0, 8.0, (500, 3))
    labels = np.where(rng.random(500) < 0.5, Label.FLOOR, Label.CEILING).astype(np.uint8)
    pts[:, 2] = np.where(labels == Label.FLOOR, 0.0, 3.0) + rng.normal(0.0, 0.02, 500)
    out = tmp_path / "side.png"
    plots.plot_side_view(pts, labels, {"BIM floor": 0.0, "BIM ceiling": 3.0}, out)
    assert _is_png(out)


def test_term_costs(tmp_path: Path) -> None:
    out = tmp_path / "costs.png"
    summary = {
        "terms": {
            "G": {"cost_before": 10.0, "cost_after": 1.0},
            "F": {"initial": 2.0, "final": 0.5},
        }
    }
    plots.plot_term_costs(summary, out)
    assert _is_png(out)
    flat = {"cost_before": {"W": 3.0}, "cost_after": {"W": 1.0}}
    plots.plot_term_costs(flat, tmp_path / "flat.png")
    assert _is_png(tmp_path / "flat.png")
    with pytest.raises(EvaluationError, match="per-term"):
        plots.plot_term_costs({"iterations": 3}, tmp_path / "none.png")


# ---- what the report's figures must show (issue 17) ------------------------------------------

def _walk(n: int, yaw_offset_deg: float = 0.0, shift: float = 0.0) -> np.ndarray:
    """(n, 7) cameras on an arc, looking horizontally along the walk (+ ``yaw_offset_deg``)."""
    from bimcap.geometry.poses import rotmat_to_quat

    s = np.linspace(0.0, np.pi / 2, n)
    p = np.zeros((n, 7))
    p[:, 0], p[:, 1], p[:, 2] = 4 + 3 * np.cos(s) + shift, 4 + 3 * np.sin(s), 1.5
    psi = s + np.pi / 2 + np.radians(yaw_offset_deg)  # tangent of the arc
    z_cam = np.stack([np.cos(psi), np.sin(psi), np.zeros(n)], axis=1)
    x_cam = np.stack([np.sin(psi), -np.cos(psi), np.zeros(n)], axis=1)
    y_cam = np.cross(z_cam, x_cam)
    p[:, 3:] = rotmat_to_quat(np.stack([x_cam, y_cam, z_cam], axis=2))
    return p


_PLAN = (np.array([[0, 0, 20, 0], [20, 0, 20, 20], [20, 20, 0, 20], [0, 20, 0, 0],
                   [4, 4, 4.4, 4]], float),
         np.array([Label.WALL] * 4 + [Label.COLUMN]))


def test_runs_have_distinct_fixed_colours() -> None:
    names = ["ground truth", "initial", "facap G+F+W", "bimcap G+F+W+Co+Ce"]
    colours = [plots.run_colour(n) for n in names]
    assert len(set(colours)) == 4
    assert colours[0] == "black" and plots.run_colour("BIMCaP") == plots.run_colour("after")


def test_trajectory_plot_colours_headings_and_zoom(tmp_path: Path) -> None:
    gt, est = _walk(30), _walk(30, yaw_offset_deg=9.0, shift=0.2)
    fig = plots.plot_trajectories_on_plan(*_PLAN, {"ground truth": gt, "bimcap G+F+W": est},
                                          tmp_path / "t.png", heading_every=3)
    assert _is_png(tmp_path / "t.png")
    ax = fig.axes[0]
    by_label = {ln.get_label(): ln for ln in ax.get_lines()}
    assert by_label["ground truth"].get_color() != by_label["bimcap G+F+W"].get_color()
    # zoomed to the walk (x 4..7.2, y 4..7), not the 20 m building
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    assert x0 > 1.5 and x1 < 10.0 and y0 > 1.5 and y1 < 10.0
    # one quiver of headings per trajectory, every 3rd frame, 9 degrees apart
    from matplotlib.quiver import Quiver

    quivers = [c for c in ax.collections if isinstance(c, Quiver)]
    assert len(quivers) == 2 and all(len(q.U) == 10 for q in quivers)
    a = np.degrees(np.arctan2(quivers[0].V, quivers[0].U))
    b = np.degrees(np.arctan2(quivers[1].V, quivers[1].U))
    np.testing.assert_allclose((b - a + 180) % 360 - 180, 9.0, atol=1e-6)
    np.testing.assert_allclose(plots.camera_forward_xy(gt[:1]), [[-np.sin(0), np.cos(0)]],
                               atol=1e-12)
    assert any("heading" in t.get_text() for t in fig.legends[0].get_texts())


def test_error_figures_share_their_scale_and_differ_in_title(tmp_path: Path) -> None:
    gt = _poses(40, 0.0)
    first = trajectory_metrics(_poses(40, 0.3), gt).frame_errors
    runs = {"facap G+F+W": trajectory_metrics(_poses(40, 0.1), gt).frame_errors,
            "bimcap G+F+W+Co+Ce": trajectory_metrics(_poses(40, 0.01), gt).frame_errors}
    assert first is not None and all(e is not None for e in runs.values())
    ylim = plots.error_limits([first, *runs.values()])  # type: ignore[list-item]
    figs = [plots.plot_errors_per_frame(first, e, tmp_path / f"{k}.png", names=("initial", n),
                                        ylim=ylim)  # type: ignore[arg-type]
            for k, (n, e) in enumerate(runs.items())]
    assert figs[0].axes[0].get_ylim() == figs[1].axes[0].get_ylim()
    assert figs[0].axes[1].get_ylim() == figs[1].axes[1].get_ylim()
    assert figs[0].axes[0].get_ylim()[1] == pytest.approx(0.3 * 1.05)
    assert figs[0].axes[0].get_title() != figs[1].axes[0].get_title()
    colours = {ln.get_label().split(" (")[0]: ln.get_color() for ln in figs[1].axes[0].get_lines()}
    assert colours["initial"] != colours["bimcap G+F+W+Co+Ce"]


def test_side_view_says_when_a_class_has_no_points(tmp_path: Path) -> None:
    pts = np.column_stack([np.linspace(0, 5, 50), np.zeros(50), np.zeros(50)])
    fig = plots.plot_side_view(pts, np.full(50, Label.FLOOR, np.uint8), {"BIM ceiling": 3.0},
                               tmp_path / "side.png")
    for ax in fig.axes:
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert not any(lab.startswith("ceiling") for lab in labels)
        assert any("no ceiling samples" in t.get_text() for t in ax.texts)


def test_term_costs_are_linear_shares_with_the_tiny_prior_annotated(tmp_path: Path) -> None:
    costs = {"cost_before": {"G": 300.0, "W": 100.0, "prior": 0.0},
             "cost_after": {"G": 100.0, "W": 100.0, "prior": 1e-28}}
    fig = plots.plot_term_costs(costs, tmp_path / "c.png", notes=["Ce: 0 samples"])
    assert _is_png(tmp_path / "c.png")
    share_ax, cost_ax = fig.axes[:2]
    assert cost_ax.get_yscale() == "linear" and share_ax.get_xscale() == "linear"
    widths = [p.get_width() for p in share_ax.patches]
    assert sum(widths[:3]) == pytest.approx(100.0) and widths[0] == pytest.approx(75.0)
    # the prior's round-off cost reads 0, not 1e-28
    assert any(t.get_text() == "0 →\n0" for t in cost_ax.texts)
    assert not any("e-28" in t.get_text() for t in cost_ax.texts)


def test_new_figures(tmp_path: Path) -> None:
    gt = _walk(20)
    runs = {"initial": (_walk(20, shift=0.3), np.full(20, 0.3)),
            "bimcap": (gt, np.linspace(0.0, 0.02, 20))}
    fig = plots.plot_errors_on_plan(*_PLAN, runs, tmp_path / "e.png")
    assert _is_png(tmp_path / "e.png")
    cbar_axes = [a for a in fig.axes if "cm" in a.get_ylabel()]
    assert len(cbar_axes) == 1
    scatters = [c for a in fig.axes[:2] for c in a.collections if c.get_array() is not None]
    assert len(scatters) == 2 and all(s.norm.vmax == pytest.approx(30.0) for s in scatters)
    # 0.1 cm … 30 cm: a logarithmic scale, so 1 cm and 30 cm are far apart in colour
    assert type(scatters[0].norm).__name__ == "LogNorm" and "log scale" in cbar_axes[0].get_ylabel()
    assert scatters[0].norm(30.0) - scatters[0].norm(1.0) > 0.5
    narrow = plots.plot_errors_on_plan(*_PLAN, {"a": (gt, np.full(20, 0.01)),
                                                "b": (gt, np.full(20, 0.02))})
    lin = [c for a in narrow.axes[:2] for c in a.collections if c.get_array() is not None]
    assert type(lin[0].norm).__name__ == "Normalize" and lin[0].norm.vmin == 0.0
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 8, (400, 3))
    labs = rng.choice([Label.WALL, Label.COLUMN, Label.FLOOR], 400).astype(np.uint8)
    plots.plot_maps_on_plan(*_PLAN, {"before": (pts + 0.3, labs), "after": (pts, labs)},
                            tmp_path / "m.png")
    assert _is_png(tmp_path / "m.png")
    fig3 = plots.plot_map_3d(pts, labs, {"ground truth": gt, "bimcap": gt}, tmp_path / "3d.png")
    assert _is_png(tmp_path / "3d.png") and fig3.axes[0].name == "3d"
    with pytest.raises(EvaluationError):
        plots.plot_errors_on_plan(*_PLAN, {"x": (gt, np.zeros(3))})
