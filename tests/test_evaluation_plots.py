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
