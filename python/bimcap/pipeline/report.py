"""The report: one self-contained HTML file (figures embedded as PNG data URIs, plus the PNG
files beside it), opened without a server.

Sections: the before/after metrics table (trajectory and map), trajectories over the floor plan,
error per frame before/after (the paper's Fig. 5), side views of floor and ceiling points before
and after (Fig. 6), what the BIM observes per frame, with ``refine --deviations`` the scan-vs-BIM
deviations (picture over the floor plan, every deviating and missing element), per-term costs,
the solver summary, and the settings and seeds that reproduce the run.
"""

from __future__ import annotations

import base64
import html
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bimcap.io.atomic import atomic_write_text
from bimcap.labels import Label


@dataclass
class RunRow:
    """One row of the report's tables: a trajectory and what was measured of it."""

    name: str
    poses: np.ndarray
    metrics: Any = None  #: TrajectoryMetrics or None
    map_metrics: Any = None  #: MapMetrics or None
    summary: Any = None  #: SolveSummary of the last solve stage, or None
    seconds: float | None = None


@dataclass
class ReportInput:
    """Everything a report shows."""

    title: str
    out_dir: Path
    rows: list[RunRow]
    segments: np.ndarray
    segment_class: np.ndarray
    gt_poses: np.ndarray | None = None
    map_points: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    heights: dict[str, float] = field(default_factory=dict)
    settings: dict[str, Any] = field(default_factory=dict)
    reproduce: str = ""
    notes: list[str] = field(default_factory=list)
    observability: Any = None  #: bimcap.optimize.observability.Observability of the refined run
    deviations: Any = None  #: bimcap.deviations.outputs.DeviationRun, or None


def _fmt(x: Any, digits: int = 4) -> str:
    if x is None:
        return "–"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return html.escape(str(x))
    return "–" if not math.isfinite(v) else f"{v:.{digits}f}"


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}"/>'
            f"<figcaption>{html.escape(alt)} ({path.name})</figcaption></figure>")


def metrics_table_html(rows: list[RunRow]) -> str:
    head = ("<tr><th>run</th><th>ATE<sub>pos</sub> RMSE [m]</th><th>ATE<sub>rot</sub> RMSE [°]</th>"
            "<th>yaw [°]</th><th>pitch [°]</th><th>roll [°]</th><th>MME</th><th>MPV</th>"
            "<th>NND [m]</th><th>solve [s]</th></tr>")
    body = []
    for r in rows:
        m, mm = r.metrics, r.map_metrics
        cells = [html.escape(r.name)]
        if m is not None:
            cells += [_fmt(m.ate_pos_m.rmse), _fmt(m.ate_rot_deg.rmse, 3), _fmt(m.yaw_rmse_deg, 3),
                      _fmt(m.pitch_rmse_deg, 3), _fmt(m.roll_rmse_deg, 3)]
        else:
            cells += ["–"] * 5
        if mm is not None:
            cells += [_fmt(mm.mme, 3), _fmt(mm.mpv, 4), _fmt(mm.nnd_m, 4)]
        else:
            cells += ["–"] * 3
        cells.append(_fmt(r.seconds, 2))
        body.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return f"<table>{head}{''.join(body)}</table>"


def term_costs(summary: Any) -> dict[str, dict[str, float]]:
    """``{"cost_before": {term: c}, "cost_after": {term: c}}`` of the active terms."""
    before, after = {}, {}
    for t in summary.terms:
        if t.active:
            before[t.name] = float(t.initial_cost)
            after[t.name] = float(t.final_cost)
    return {"cost_before": before, "cost_after": after}


_STYLE = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
          "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;"
          "padding:4px 8px;text-align:right}td:first-child,th:first-child{text-align:left}"
          "img{max-width:100%}figure{margin:1em 0}figcaption{color:#666;font-size:90%}"
          "pre{background:#f5f5f5;padding:8px;overflow-x:auto}")


def _head_html(inp: ReportInput) -> list[str]:
    """The document head, the title and the notes."""
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>"
             f"{html.escape(inp.title)}</title><style>{_STYLE}</style></head><body>",
             f"<h1>{html.escape(inp.title)}</h1>"]
    parts += [f"<p>{html.escape(note)}</p>" for note in inp.notes]
    return parts


def _metrics_html(inp: ReportInput) -> list[str]:
    """The metrics table and what its columns mean."""
    parts = ["<h2>Metrics</h2>", metrics_table_html(inp.rows)]
    conv = next((r.metrics.ypr_convention for r in inp.rows if r.metrics is not None), None)
    mm = next((r.map_metrics for r in inp.rows if r.map_metrics is not None), None)
    expl = ["ATE without alignment (the BIM frame is shared)."]
    if conv:
        expl.append(f"Yaw/pitch/roll: {conv}.")
    if mm is not None:
        expl.append(f"MME/MPV of the semantic map with radius {mm.radius_m:g} m and more than "
                    f"{mm.min_neighbours} neighbours; NND against the {mm.nnd_reference} "
                    f"(cut-off {mm.nnd_cutoff_m:g} m, {mm.nnd_cutoff_mode.value}).")
    parts.append(f"<p>{html.escape(' '.join(expl))}</p>")
    return parts


def _trajectories_html(inp: ReportInput, figs: Path) -> list[str]:
    """Every trajectory (and the ground truth) over the floor plan."""
    from bimcap.evaluation import plots

    trajs: dict[str, np.ndarray] = {}
    if inp.gt_poses is not None:
        trajs["ground truth"] = inp.gt_poses
    for r in inp.rows:
        trajs[r.name] = r.poses
    p = figs / "trajectories.png"
    plots.plot_trajectories_on_plan(inp.segments, inp.segment_class, trajs, p)
    return ["<h2>Trajectories over the floor plan</h2>" + _img(p, "top view")]


def _errors_html(inp: ReportInput, figs: Path) -> list[str]:
    """Error per frame of each run against the first one with metrics (none for fewer than
    two)."""
    from bimcap.evaluation import plots

    with_metrics = [r for r in inp.rows
                    if r.metrics is not None and r.metrics.frame_errors is not None]
    if len(with_metrics) < 2:
        return []
    parts = ["<h2>Error per frame</h2>"]
    first = with_metrics[0]
    for r in with_metrics[1:]:
        p = figs / f"errors_{_slug(r.name)}.png"
        plots.plot_errors_per_frame(first.metrics.frame_errors, r.metrics.frame_errors, p)
        parts.append(_img(p, f"error per frame: {first.name} (before) vs {r.name} (after)"))
    return parts


def _side_views_html(inp: ReportInput, figs: Path) -> list[str]:
    """Side views of each map's floor and ceiling points."""
    from bimcap.evaluation import plots

    if not inp.map_points:
        return []
    parts = ["<h2>Floor and ceiling points, side views</h2>"]
    for label, (pts, labs) in inp.map_points.items():
        keep = np.isin(labs, [int(Label.FLOOR), int(Label.CEILING)])
        if keep.sum() == 0:
            continue
        p = figs / f"side_{_slug(label)}.png"
        plots.plot_side_view(pts[keep], labs[keep], inp.heights or None, p,
                             title=f"Floor and ceiling points: {label}")
        parts.append(_img(p, f"side view, {label}"))
    return parts


def _observability_html(inp: ReportInput, figs: Path) -> list[str]:
    """What the BIM observes per frame (none without an observability analysis)."""
    from bimcap.evaluation import plots

    if inp.observability is None or not inp.observability.frames:
        return []
    obs = inp.observability
    p = figs / "observability.png"
    plots.plot_observability(obs.sigma(), obs.options.max_sigma_m, obs.options.max_sigma_deg, p)
    return ["<h2>What the BIM observes, per frame</h2>",
            f"<p>{html.escape(obs.summary_line())}. Standard deviations of each degree of "
            "freedom from the BIM terms alone (F, Ce, W, Co, with their noise scales and "
            "robust weights), in a frame aligned with the camera's heading. Degrees of "
            "freedom the BIM does not pin are held by G (the neighbouring frames), the "
            "odometry and the pose prior.</p>",
            _img(p, "BIM observability per frame")]


def _deviations_html(inp: ReportInput) -> list[str]:
    """Scan vs BIM: the floor-plan picture, the counts, every deviating and missing element."""
    dev = inp.deviations
    if dev is None:
        return []
    rep = dev.report
    counts = ", ".join(f"{n} {k}" for k, n in rep.counts().items())
    parts = ["<h2>Scan vs BIM: deviations</h2>",
             f"<p>Per IFC element, under the refined poses (tolerance "
             f"{100 * rep.options.tolerance_m:g} cm): {html.escape(counts)}; "
             f"{len(rep.clusters)} clusters of points no element explains. Files: "
             "deviations.json / .csv / .ply / .ifc (property set BIMCaP_Deviation).</p>"]
    png = dev.files.get("deviations.png")
    if png is not None and Path(png).is_file():
        parts.append(_img(Path(png), "walls and columns coloured by offset; missing: red cross"))
    flagged = [e for e in rep.elements if e.status.value in ("deviating", "missing")]
    flagged.sort(key=lambda e: (e.status.value != "missing", -abs(e.offset_m or 0.0)))
    if flagged:
        parts.append("<table><tr><th>status</th><th>element</th><th>class</th><th>storey</th>"
                     "<th>offset [cm]</th><th>coverage</th><th>points</th><th>GUID</th></tr>")
        for e in flagged:
            off = "–" if e.offset_m is None else f"{100 * e.offset_m:+.1f}"
            parts.append(
                f"<tr><td>{e.status.value}</td><td>{html.escape(e.name)}</td>"
                f"<td>{html.escape(e.ifc_class)}</td><td>{html.escape(str(e.storey))}</td>"
                f"<td>{off}</td><td>{e.coverage:.0%}</td><td>{e.n_points}</td>"
                f"<td>{html.escape(e.guid)}</td></tr>")
        parts.append("</table>")
    return parts


def _solver_html(inp: ReportInput, figs: Path) -> list[str]:
    """Per-term costs and the solver summary of each solved run."""
    from bimcap.evaluation import plots

    solved = [r for r in inp.rows if r.summary is not None]
    if not solved:
        return []
    parts = ["<h2>Solver</h2>"]
    for r in solved:
        costs = term_costs(r.summary)
        if costs["cost_before"]:
            p = figs / f"costs_{_slug(r.name)}.png"
            plots.plot_term_costs(costs, p)
            parts.append(_img(p, f"per-term cost, {r.name}"))
        parts.append(f"<h3>{html.escape(r.name)}</h3><pre>{html.escape(r.summary.table())}</pre>")
    return parts


def _reproduce_html(inp: ReportInput) -> list[str]:
    """The command and the settings that reproduce the run, and the end of the document."""
    parts = ["<h2>Reproduce</h2>"]
    if inp.reproduce:
        parts.append(f"<pre>{html.escape(inp.reproduce)}</pre>")
    parts.append(f"<pre>{html.escape(json.dumps(inp.settings, indent=2, default=str))}</pre>")
    parts.append("</body></html>")
    return parts


def write_report(inp: ReportInput, name: str = "report.html") -> Path:
    """Render ``inp`` into ``out_dir/name`` (and its figures into ``out_dir/figures/``)."""
    figs = inp.out_dir / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    parts = _head_html(inp) + _metrics_html(inp)
    parts += _trajectories_html(inp, figs)
    parts += _errors_html(inp, figs)
    parts += _side_views_html(inp, figs)
    parts += _observability_html(inp, figs)
    parts += _deviations_html(inp)
    parts += _solver_html(inp, figs)
    parts += _reproduce_html(inp)
    path = inp.out_dir / name
    atomic_write_text(path, "\n".join(parts))
    return path


def _slug(s: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in s.lower()).strip("_")


def bim_heights(reference: Any) -> dict[str, float]:
    """Mean z of the BIM floor and ceiling planes (for the side views)."""
    out = {}
    kinds = reference.plane_kind
    for kind, name in ((Label.FLOOR, "BIM floor"), (Label.CEILING, "BIM ceiling")):
        sel = reference.planes[kinds == int(kind)]
        # plane n·p + d = 0 with n ≈ ±z: z = −d / n_z
        sel = sel[np.abs(sel[:, 2]) > 0.9]
        if len(sel):
            out[name] = float(np.median(-sel[:, 3] / sel[:, 2]))
    return out


def write_refine_report(
    result: Any, prepared: Any, gt: Any, extra: list[RunRow] | None = None
) -> Path:
    """The report of one ``bimcap refine`` run (``extra`` rows, e.g. FACaP, are shown beside)."""
    from bimcap.frontend.semantic_map import semantic_points

    rows = [RunRow("initial", result.init.poses, result.metrics_before, result.map_before)]
    rows += list(extra or [])
    rows.append(RunRow(f"{result.config.method.value} {result.config.effective_terms}",
                       result.refined.poses, result.metrics_after, result.map_after,
                       result.outcome.summary, result.outcome.seconds))
    ref = prepared.reference
    maps = {"before": semantic_points(prepared.map_source, result.init.poses),
            "after": semantic_points(prepared.map_source, result.refined.poses)}
    inp = ReportInput(
        title="bimcap refinement report",
        out_dir=result.out_dir,
        rows=rows,
        segments=ref.segments,
        segment_class=ref.segment_class,
        gt_poses=None if gt is None else gt.poses,
        map_points=maps,
        heights=bim_heights(ref),
        settings={"config": result.config.to_dict(),
                  "problem": result.outcome.problem_stats.to_dict(),
                  "timings_s": result.timings},
        reproduce=result.command,
        observability=result.outcome.observability,
        deviations=getattr(result, "deviation_run", None),
    )
    return write_report(inp)
