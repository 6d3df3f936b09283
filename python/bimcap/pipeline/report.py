"""The report: one self-contained HTML file (figures embedded as PNG data URIs, plus the PNG
files beside it), opened without a server.

Sections: the before/after metrics table (trajectory and map, each metric with the direction
that is better), what the run could not do (a configured term with no samples, a map without
ceiling samples, a coarse stage that changed nothing), trajectories with camera headings over the
floor plan (zoomed to the walk), the position error coloured along the path, error per frame
before/after on one scale (the paper's Fig. 5), the semantic maps before/after over the plan,
side views of floor and ceiling points (Fig. 6), a 3-D view of the refined map and the cameras,
what the BIM observes per frame, with ``refine --deviations`` the scan-vs-BIM deviations, the
coarse registration's result, per-term costs and the solver table (with units, and the matches'
median reprojection error and inlier share), and the settings and seeds that reproduce the run.
Runs have one colour on every figure (:func:`bimcap.evaluation.plots.run_colour`: ground truth
black, initial grey, FACaP orange, BIMCaP blue).
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

from bimcap.evaluation.plots import run_colour
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
    #: the pipeline's SolveOutcome (every stage's summary, coarse stage, reprojection), or None
    outcome: Any = None
    terms: str | None = None  #: the configured terms, e.g. "G+F+W+Co+Ce"
    g_unit: str = "px"  #: the G residual's unit: "px" (reprojection / landmark) or "m" (point)


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
    #: samples the LiDAR scan gave the solve per class (``wall``/``floor``/``ceiling``), outside
    #: the maps (which hold the camera pixels' samples); empty when the scan gave none
    scan_samples: dict[str, int] = field(default_factory=dict)


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


#: The metrics table's columns: header, whether lower is better (every one is).
_METRIC_COLUMNS = (
    ("ATE<sub>pos</sub> RMSE [m]", True), ("ATE<sub>rot</sub> RMSE [°]", True),
    ("yaw [°]", True), ("pitch [°]", True), ("roll [°]", True), ("MME [nats]", True),
    ("MPV [m²]", True), ("NND [m]", True), ("solve [s]", True),
)

#: What each metric measures and which way is better (the report's "how to read" list).
METRIC_SENSE = {
    "ATE_pos": "lower is better: RMSE of the camera positions against the ground truth",
    "ATE_rot": "lower is better: RMSE of the camera rotation angles against the ground truth",
    "yaw / pitch / roll": "lower is better: RMSE of each angle of the rotation error",
    "MME": "lower is better (more negative = a sharper map); negative by construction: the "
           "mean entropy ½ ln det(2πe Σ) of a neighbourhood whose spread is centimetres lies "
           "below zero",
    "MPV": "lower is better: mean smallest variance of the neighbourhoods (a thin, planar map)",
    "NND": "lower is better: mean distance to the nearest point of the reference map",
    "solve": "lower is better: seconds of the solve (front end not included)",
}


def metrics_table_html(rows: list[RunRow]) -> str:
    head = ("<tr><th>run</th>" + "".join(f"<th>{h}</th>" for h, _ in _METRIC_COLUMNS)
            + "</tr>")
    sense = ("<tr class='sense'><td>better</td>"
             + "".join(f"<td>{'↓ lower' if low else '↑ higher'}</td>"
                       for _, low in _METRIC_COLUMNS) + "</tr>")
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
        colour = _css(run_colour(r.name, len(body)))
        body.append(f"<tr><td style='border-left:6px solid {colour}'>"
                    + "</td><td>".join(cells) + "</td></tr>")
    return f"<div class='scroll'><table>{head}{sense}{''.join(body)}</table></div>"


def _css(colour: str) -> str:
    """A matplotlib colour as CSS."""
    from matplotlib.colors import to_hex

    return str(to_hex(colour))


def term_costs(summary: Any) -> dict[str, dict[str, float]]:
    """``{"cost_before": {term: c}, "cost_after": {term: c}}`` of the active terms."""
    before, after = {}, {}
    for t in summary.terms:
        if t.active:
            before[t.name] = float(t.initial_cost)
            after[t.name] = float(t.final_cost)
    return {"cost_before": before, "cost_after": after}


_STYLE = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;"
          "color:#222;line-height:1.4}"
          "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;"
          "padding:4px 8px;text-align:right}td:first-child,th:first-child{text-align:left}"
          "th{background:#f3f3f3}tr.sense td{white-space:nowrap;color:#555;font-size:90%}"
          "td:first-child{white-space:nowrap}"
          ".scroll{overflow-x:auto}"
          "img{max-width:100%;height:auto}figure{margin:1em 0}"
          "figcaption{color:#555;font-size:90%}"
          "nav{background:#f7f7f7;border:1px solid #ddd;padding:.5em 1em;margin:1em 0}"
          "nav a{margin-right:1.2em;white-space:nowrap}"
          "h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.8em}"
          "summary{cursor:pointer;color:#333}"
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
    if all(r.metrics is None for r in inp.rows):
        expl = ["No ground truth for this run (no --gt, and the sequence has no poses/gt.tum): "
                "the trajectory and map metrics need one, so the table shows the solve time "
                "alone, and the report has no error figures."]
    if conv:
        expl.append(f"Yaw/pitch/roll: {conv}.")
    if mm is not None:
        expl.append(f"MME/MPV of the semantic map with radius {mm.radius_m:g} m and more than "
                    f"{mm.min_neighbours} neighbours; NND against the {mm.nnd_reference} "
                    f"(cut-off {mm.nnd_cutoff_m:g} m, {mm.nnd_cutoff_mode.value}).")
    parts.append(f"<p>{html.escape(' '.join(expl))}</p>")
    parts.append("<p>How to read each metric:</p><ul>" + "".join(
        f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>" for k, v in METRIC_SENSE.items())
        + "</ul>")
    return parts


def _trajectories(inp: ReportInput) -> dict[str, np.ndarray]:
    """Name → (N, 7) poses of the ground truth, the coarse stage's result (when it moved the
    poses) and every run."""
    trajs: dict[str, np.ndarray] = {}
    if inp.gt_poses is not None:
        trajs["ground truth"] = inp.gt_poses
    for r in inp.rows:
        coarse = coarse_change(r, inp.rows[0].poses)
        if coarse is not None and coarse["changed"]:
            trajs[f"after the coarse stage ({r.name})"] = coarse["poses"]
    for r in inp.rows:
        trajs[r.name] = r.poses
    return trajs


def _trajectories_html(inp: ReportInput, figs: Path) -> list[str]:
    """Every trajectory (and the ground truth) with its headings over the floor plan, zoomed to
    the walk."""
    from bimcap.evaluation import plots

    trajs = _trajectories(inp)
    p = figs / "trajectories.png"
    plots.plot_trajectories_on_plan(inp.segments, inp.segment_class, trajs, p)
    k = plots.heading_step(max(len(t) for t in trajs.values()))
    every = "at every frame" if k == 1 else f"every {k} frames"
    return ["<h2>Trajectories over the floor plan</h2>",
            f"<p>Top view, zoomed to the walk; the arrows are the cameras' optical axes {every}, "
            "so a rotation error shows as arrows that turn away from the ground truth's (black). "
            "Colours: ground truth black, initial grey (dashed), FACaP orange, BIMCaP blue, on "
            "every figure." + ("" if inp.gt_poses is not None else " This run has no ground "
                               "truth: the runs alone are drawn.") + "</p>",
            _img(p, "top view: trajectories and camera headings")]


def _with_errors(inp: ReportInput) -> list[RunRow]:
    return [r for r in inp.rows if r.metrics is not None and r.metrics.frame_errors is not None]


def _errors_html(inp: ReportInput, figs: Path) -> list[str]:
    """Error per frame of each run against the first one with metrics (none for fewer than
    two), every figure on the same scale; the position error along the path over the plan."""
    from bimcap.evaluation import plots

    with_metrics = _with_errors(inp)
    if not with_metrics:
        return []
    parts = ["<h2>Error per frame</h2>"]
    p = figs / "errors_on_plan.png"
    plots.plot_errors_on_plan(inp.segments, inp.segment_class,
                              {r.name: (r.poses, r.metrics.frame_errors.trans_m)
                               for r in with_metrics}, p)
    parts += ["<p>Each camera position coloured by its position error against the ground truth "
              "(one colour scale, in cm, for every panel).</p>",
              _img(p, "position error along the path, per run")]
    if len(with_metrics) < 2:
        return parts
    first = with_metrics[0]
    ylim = plots.error_limits([r.metrics.frame_errors for r in with_metrics])
    parts.append(f"<p>Every run against {html.escape(first.name)}, on the same y-scale "
                 f"(translation up to {ylim[0]:.3g} m, rotation up to {ylim[1]:.3g}°).</p>")
    for r in with_metrics[1:]:
        p = figs / f"errors_{_slug(r.name)}.png"
        title = f"Error per frame: {first.name} vs {r.name} (lower is better)"
        plots.plot_errors_per_frame(first.metrics.frame_errors, r.metrics.frame_errors, p,
                                    names=(first.name, r.name), title=title, ylim=ylim)
        parts.append(_img(p, f"error per frame: {first.name} vs {r.name}"))
    return parts


def _maps_html(inp: ReportInput, figs: Path) -> list[str]:
    """The semantic maps over the plan, the side views of their floor and ceiling points and a
    3-D view of the last map with the cameras."""
    from bimcap.evaluation import plots

    if not inp.map_points:
        return []
    parts = ["<h2>Semantic maps</h2>"]
    p = figs / "maps_on_plan.png"
    plots.plot_maps_on_plan(inp.segments, inp.segment_class, inp.map_points, p)
    parts += ["<p>The wall and column samples of each map from above, over the floor plan: "
              "where a map's walls leave the plan's lines, the poses that placed them are off."
              "</p>", _img(p, "semantic maps over the floor plan")]
    parts.append("<h3>Floor and ceiling points, side views</h3>")
    for label, (pts, labs) in inp.map_points.items():
        keep = np.isin(labs, [int(Label.FLOOR), int(Label.CEILING)])
        counts = {c.name.lower(): int((labs == int(c)).sum()) for c in (Label.FLOOR,
                                                                          Label.CEILING)}
        p = figs / f"side_{_slug(label)}.png"
        plots.plot_side_view(pts[keep], labs[keep], inp.heights or None, p,
                             title=f"Floor and ceiling points: {label}")
        said = ", ".join(f"{n} {c} samples" if n else f"no {c} samples"
                         for c, n in counts.items())
        parts.append(f"<p>{html.escape(label)}: {said} from the camera pixels"
                     f"{_scan_aside(inp.scan_samples, counts)}.</p>")
        parts.append(_img(p, f"side view, {label}"))
    last = list(inp.map_points)[-1]
    pts, labs = inp.map_points[last]
    trajs = {k: v for k, v in _trajectories(inp).items()
             if k == "ground truth" or k == inp.rows[-1].name}
    p = figs / "map_3d.png"
    plots.plot_map_3d(pts, labs, trajs, p,
                      title=f"Semantic map ({last}) and cameras, 3-D")
    parts += [f"<p>3-D view of the {html.escape(last)} map ({len(pts)} samples, class colours) "
              "with the camera centres and optical axes.</p>", _img(p, f"3-D view, {last}")]
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
             f"{len(rep.clusters)} cluster{'' if len(rep.clusters) == 1 else 's'} of points "
             "no element explains. Files: "
             "deviations.json / .csv / .ply / .ifc (property set BIMCaP_Deviation) / .bcfzip (a "
             "BCF topic per deviating or missing element).</p>"]
    d = rep.datum
    if d.get("mode") == "datum":
        tx, ty, tz = (100 * v for v in d["translation_m"])
        frames = d.get("frames")
        parts.append(
            f"<p>Offsets relative to the datum ({len(d['names'])} element(s) declared as built "
            f"right: {html.escape(', '.join(d['names'][:8]))}): the poses were corrected by "
            f"({tx:+.1f}, {ty:+.1f}, {tz:+.1f}) cm and {d['yaw_deg']:+.3f}° as a whole"
            + (f", then per frame ({100 * frames['frame_step_rms_m']:.1f} cm RMS)"
               if frames else "")
            + (f"; left free: {html.escape(', '.join(d['free']))}" if d["free"] else "")
            + ".</p>")
    else:
        parts.append("<p>No datum: offsets are relative to the refined poses, which the "
                     "refinement fits to the design (a displacement common to the building goes "
                     "into the poses; <code>--datum</code> declares elements built right).</p>")
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


#: Each term's residual unit in the solver table (G's depends on the run: :attr:`RunRow.g_unit`).
TERM_UNITS = {"depth": "m", "F": "m", "Ce": "m", "W": "m", "Co": "m", "prior": "σ",
              "odometry": "σ"}
_TERM_WHAT = {"G": "matches", "depth": "depths", "F": "floor samples", "Ce": "ceiling samples",
              "W": "wall samples", "Co": "column samples"}


def term_unit(term: str, g_unit: str = "px") -> str:
    """The unit of ``term``'s rms in the solver table: px or m for G (``g_unit``), m for the
    BIM terms and the depth, σ (whitened) for the pose prior and the odometry."""
    return g_unit if term == "G" else TERM_UNITS.get(term, "")


def _configured(r: RunRow) -> list[str]:
    if r.terms:
        return [t for t in r.terms.replace(",", "+").split("+") if t]
    return [t.name for t in r.summary.terms if t.active] if r.summary is not None else []


def _stage_summaries(r: RunRow) -> list[Any]:
    if r.outcome is not None and getattr(r.outcome, "summaries", None):
        return list(r.outcome.summaries)
    return [] if r.summary is None else [r.summary]


def idle_terms(r: RunRow) -> list[str]:
    """Sentences for the configured terms of ``r`` that had no samples in a solve stage
    (e.g. "Ce: 0 samples, the term did not act")."""
    stages = _stage_summaries(r)
    out = []
    for name in _configured(r):
        empty, acted = [], 0
        skipped = 0
        for k, summary in enumerate(stages):
            try:
                t = summary.term(name)
            except KeyError:  # not measured in this stage's summary
                continue
            if not t.active or t.num_residual_blocks == 0:
                empty.append(k)
                skipped = max(skipped, int(t.num_skipped))
            else:
                acted += 1
        if not empty:
            continue
        why = (f" ({skipped} {_TERM_WHAT.get(name, 'samples')} skipped: none within the "
               "association gate)" if skipped else "")
        if not acted:
            out.append(f"{name}: 0 samples{why}, the term did not act")
        else:
            which = ", ".join(str(k + 1) for k in empty)
            out.append(f"{name}: 0 samples in solve stage {which} of {len(stages)}{why}; it acted "
                       "in the others")
    return out


def coarse_change(r: RunRow, initial: np.ndarray) -> dict[str, Any] | None:
    """How far the coarse stage of ``r`` moved the cameras from ``initial`` (N, 7):
    ``{"poses", "max_m", "max_deg", "changed"}``; None when the run had no coarse stage."""
    info = None if r.outcome is None else getattr(r.outcome, "coarse", None)
    if not info or "poses" not in info:
        return None
    poses = np.asarray(info["poses"], dtype=np.float64).reshape(-1, 7)
    if poses.shape != initial.shape:
        return None
    dt = np.linalg.norm(poses[:, :3] - initial[:, :3], axis=1)
    dots = np.clip(np.abs(np.sum(poses[:, 3:] * initial[:, 3:], axis=1)), 0.0, 1.0)
    dr = np.degrees(2.0 * np.arccos(dots))
    max_m, max_deg = float(dt.max(initial=0.0)), float(dr.max(initial=0.0))
    return {"poses": poses, "max_m": max_m, "max_deg": max_deg,
            "changed": bool(max_m > 1e-6 or max_deg > 1e-4)}


def _limits_html(inp: ReportInput) -> list[str]:
    """What the run could not do: idle terms, maps without floor or ceiling samples, a coarse
    stage that changed nothing, diverged frames."""
    items = []
    for r in inp.rows:
        items += [f"{r.name}: {line}" for line in idle_terms(r)]
        coarse = coarse_change(r, inp.rows[0].poses)
        if coarse is not None and not coarse["changed"]:
            items.append(f"{r.name}: the coarse stage handed the poses back unchanged "
                         "(section Coarse registration says why)")
        diverged = [] if r.outcome is None else getattr(r.outcome, "diverged_frames", [])
        if diverged:
            items.append(f"{r.name}: frames {diverged[:10]} diverged (far outside the building)")
    for label, (_, labs) in inp.map_points.items():
        for c in (Label.FLOOR, Label.CEILING):
            if not (labs == int(c)).any():
                name = c.name.lower()
                n_scan = int(inp.scan_samples.get(name, 0))
                items.append(f"map {label}: no {name} samples from the camera pixels"
                             + (f" (the LiDAR scan gave the solve {n_scan}; not drawn)"
                                if n_scan else ""))
    parts = ["<h2>What this run could not do</h2>"]
    if not items:
        parts.append("<p>Nothing to report: every configured term had samples in every solve "
                     "stage, every map has floor and ceiling samples.</p>")
    else:
        parts.append("<ul>" + "".join(f"<li>{html.escape(i)}</li>" for i in items) + "</ul>")
    return parts


def _coarse_html(inp: ReportInput) -> list[str]:
    """The coarse registration's result of each run that had one (result.json solve.coarse)."""
    parts: list[str] = []
    for r in inp.rows:
        info = None if r.outcome is None else getattr(r.outcome, "coarse", None)
        if r.outcome is None:
            continue
        if not info:
            parts.append(f"<p>{html.escape(r.name)}: no coarse stage in its schedule.</p>")
            continue
        n = int(info.get("n_frames", 0))
        acc = sum(bool(v) for v in info.get("accepted", []))
        line = (f"{r.name}: {acc}/{n} frames accepted by the window search in "
                f"{info.get('n_windows', 0)} window(s), {float(info.get('seconds', 0.0)):.2f} s. ")
        change = coarse_change(r, inp.rows[0].poses)
        if change is not None:
            line += (f"It moved the cameras by at most {change['max_m']:.3f} m and "
                     f"{change['max_deg']:.2f}° (drawn on the trajectories figure)."
                     if change["changed"] else "It handed the poses back unchanged.")
        fl = info.get("frame_level")
        if fl:
            ok = {k: sum(bool(v) for v in fl.get(k, [])) for k in ("yaw_ok", "tilt_ok", "t_ok")}
            line += (f" Per-frame orientation pass: yaw found on {ok['yaw_ok']}/{n} frames, "
                     f"tilt on {ok['tilt_ok']}/{n}, translation on {ok['t_ok']}/{n}; tracked "
                     f"drift {_fmt(fl.get('drift_m'), 3)} m.")
        if info.get("near_probe_drift_m") is not None:
            line += (f" Tracked drift on the first frames {info['near_probe_drift_m']:.3f} m: "
                     "within the bundle adjustment's reach.")
        parts.append(f"<p>{html.escape(line)}</p>")
        windows = info.get("windows") or []
        if windows:
            parts.append("<table><tr><th>frames</th><th>points</th><th>accepted</th>"
                         "<th>yaw [°]</th><th>shift [m]</th><th>inlier share</th>"
                         "<th>score</th><th>why not accepted</th></tr>")
            for w in windows:
                t = w.get("t_m") or (0.0, 0.0)
                # a window whose search did not run (no hypothesis) has no yaw, shift or score
                searched = w.get("accepted") or w.get("n_hypotheses", 1) != 0
                vals = ([_fmt(w.get("yaw_deg"), 2), _fmt(float(np.hypot(t[0], t[1])), 3),
                         _fmt(w.get("inlier_ratio"), 2), _fmt(w.get("score"), 2)]
                        if searched else ["–"] * 4)
                parts.append(
                    f"<tr><td>{w['start']}–{w['stop'] - 1}</td><td>{w.get('n_points', 0)}</td>"
                    f"<td>{'yes' if w.get('accepted') else 'no'}</td><td>"
                    + "</td><td>".join(vals) + "</td>"
                    f"<td>{html.escape(str(w.get('reason') or ''))}</td></tr>")
            parts.append("</table>")
    return ["<h2>Coarse registration</h2>", *parts] if parts else []


def _g4(x: Any) -> str:
    """Four significant digits; a value below 1e-9 in magnitude (round-off of a zero, e.g. the
    pose prior's 7.7e-17 σ at the initial poses) reads 0."""
    v = float(x)
    return "0" if abs(v) < 1e-9 else f"{v:.4g}"


def solver_table_html(r: RunRow) -> str:
    """Every solve stage's terms of ``r``: samples, rms before → after with its unit, cost
    before → after and the share of the stage's final cost."""
    stages = _stage_summaries(r)
    head = ("<table><tr><th>stage</th><th>term</th><th>samples</th><th>skipped</th>"
            "<th>rms before</th><th>rms after</th><th>cost before</th><th>cost after</th>"
            "<th>share of final cost</th></tr>")
    body = []
    configured = set(_configured(r))
    for k, summary in enumerate(stages):
        total = sum(float(t.final_cost) for t in summary.terms if t.active)
        for t in summary.terms:
            if not t.active and t.name not in configured:
                continue
            unit = term_unit(t.name, r.g_unit)
            if not t.active or t.num_residual_blocks == 0:
                body.append(f"<tr><td>{k + 1}</td><td>{t.name}</td><td>0</td>"
                            f"<td>{t.num_skipped}</td><td colspan='5' style='text-align:left'>"
                            "0 samples, the term did not act</td></tr>")
                continue
            share = 100.0 * float(t.final_cost) / total if total > 0 else 0.0
            body.append(
                f"<tr><td>{k + 1}</td><td>{t.name}</td><td>{t.num_residual_blocks}</td>"
                f"<td>{t.num_skipped}</td><td>{_g4(t.initial_rms)} {unit}</td>"
                f"<td>{_g4(t.final_rms)} {unit}</td><td>{_g4(t.initial_cost)}</td>"
                f"<td>{_g4(t.final_cost)}</td><td>{share:.1f} %</td></tr>")
        body.append(f"<tr><td>{k + 1}</td><td colspan='8' style='text-align:left'>"
                    f"{html.escape(summary.termination)}: {summary.iterations} iterations, "
                    f"{summary.time_s:.3f} s, cost {summary.initial_cost:.6g} → "
                    f"{summary.final_cost:.6g}</td></tr>")
    return "<div class='scroll'>" + head + "".join(body) + "</table></div>"


def reprojection_html(r: RunRow) -> str:
    """The G matches' median reprojection error and inlier share before → after (pixels)."""
    rep = None if r.outcome is None else getattr(r.outcome, "reprojection", None)
    if not rep:
        return ""
    b, a = rep["before"], rep["after"]
    return (f"<p>G's matches at the initial → refined poses ({a['n']} observations, both "
            f"directions, pixels whatever G's residual): median reprojection error "
            f"{b['median_px']:.2f} → {a['median_px']:.2f} px, 90th percentile "
            f"{b['p90_px']:.1f} → {a['p90_px']:.1f} px, inliers (&lt; {a['inlier_px']:g} px) "
            f"{100 * b['inlier_share']:.1f} % → {100 * a['inlier_share']:.1f} %; rms "
            f"{b['rms_px']:.1f} → {a['rms_px']:.1f} px (dominated by the outliers the robust loss "
            f"sets aside; {b.get('behind', 0)} → {a.get('behind', 0)} observations fall behind "
            "the other camera, counted as outliers, not in the rms).</p>")


def _solver_html(inp: ReportInput, figs: Path) -> list[str]:
    """Per-term costs and the solver table of each solved run."""
    from bimcap.evaluation import plots

    solved = [r for r in inp.rows if r.summary is not None]
    if not solved:
        return []
    parts = ["<h2>Solver</h2>",
             "<p>rms of the raw residuals in each term's unit: px for G as a reprojection error "
             "(m for FACaP's point error), m for the floor (F), ceiling (Ce), wall (W) and column "
             "(Co) distances, σ (whitened) for the pose prior and the odometry. Costs are Ceres "
             "costs ½ Σ ρ(‖r/σ‖²), without unit; the last stage is the one that placed the "
             "cameras.</p>"]
    for r in solved:
        parts.append(f"<h3>{html.escape(r.name)}</h3>")
        idle = idle_terms(r)
        if idle:
            parts.append("<p>" + html.escape("; ".join(idle)) + ".</p>")
        costs = term_costs(r.summary)
        if costs["cost_before"]:
            p = figs / f"costs_{_slug(r.name)}.png"
            plots.plot_term_costs(costs, p, title=f"Per-term cost of the last stage: {r.name}",
                                  notes=idle)
            parts.append(_img(p, f"per-term cost, {r.name}"))
        parts.append(solver_table_html(r))
        parts.append(reprojection_html(r))
    return parts


def _reproduce_html(inp: ReportInput) -> list[str]:
    """The command and the settings that reproduce the run, and the end of the document."""
    parts = ["<h2>Reproduce</h2>"]
    if inp.reproduce:
        parts.append(f"<pre>{html.escape(inp.reproduce)}</pre>")
    parts.append("<details><summary>every setting of the run, solver statistics and timings "
                 "(JSON)</summary>"
                 f"<pre>{html.escape(json.dumps(inp.settings, indent=2, default=str))}</pre>"
                 "</details>")
    parts.append("</body></html>")
    return parts


def write_report(inp: ReportInput, name: str = "report.html") -> Path:
    """Render ``inp`` into ``out_dir/name`` (and its figures into ``out_dir/figures/``)."""
    figs = inp.out_dir / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    parts = _head_html(inp) + _metrics_html(inp)
    parts += _limits_html(inp)
    parts += _trajectories_html(inp, figs)
    parts += _errors_html(inp, figs)
    parts += _maps_html(inp, figs)
    parts += _observability_html(inp, figs)
    parts += _deviations_html(inp)
    parts += _coarse_html(inp)
    parts += _solver_html(inp, figs)
    parts += _reproduce_html(inp)
    parts = _with_contents(parts, len(_head_html(inp)))
    path = inp.out_dir / name
    atomic_write_text(path, "\n".join(parts))
    return path


def _with_contents(parts: list[str], at: int) -> list[str]:
    """``parts`` with an id on every ``<h2>`` and a list of links to them (the contents) at
    index ``at`` (after the title and notes)."""
    import re

    links = []
    out = []
    for part in parts:
        m = re.fullmatch(r"<h2>(.*)</h2>", part)
        if m:
            anchor = _slug(html.unescape(m.group(1)))
            links.append(f"<a href='#{anchor}'>{m.group(1)}</a>")
            part = f"<h2 id='{anchor}'>{m.group(1)}</h2>"
        out.append(part)
    return [*out[:at], "<nav><b>Contents:</b> " + " ".join(links) + "</nav>", *out[at:]]


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


def _scan_aside(scan_samples: dict[str, int], pixel_counts: dict[str, int]) -> str:
    """", the LiDAR scan gave the solve N ceiling samples (not drawn)" for each class the pixels
    lack and the scan has; "" otherwise."""
    extra = [f"{int(scan_samples[c])} {c}" for c, n in pixel_counts.items()
             if not n and int(scan_samples.get(c, 0) or 0) > 0]
    if not extra:
        return ""
    return f"; the LiDAR scan gave the solve {' and '.join(extra)} samples (not drawn)"


def _scan_counts(scan_samples: dict[str, Any] | None) -> dict[str, int]:
    """The per-class counts of a run's ``scan_samples`` record (``frames_without_matches``
    and other entries left out)."""
    return {c: int(n) for c, n in (scan_samples or {}).items()
            if c in ("wall", "floor", "ceiling") and isinstance(n, int)}


def _scan_note(scan_samples: dict[str, Any] | None) -> list[str]:
    """A note on the LiDAR scan's samples (used by the solve, not in the maps): the count of
    each class, and the frames without a match that took them in the first solve stage."""
    if not scan_samples:
        return []
    counts = ", ".join(f"{n} {c}" for c, n in scan_samples.items() if isinstance(n, int))
    note = (f"The LiDAR scan added samples outside the camera's view ({counts}): the last solve "
            "stage used them; the semantic maps, their figures and MME/MPV/NND keep the "
            "camera pixels' samples alone.")
    unlinked = scan_samples.get("frames_without_matches") or []
    if unlinked:
        note += (f" Frames without a match ({len(unlinked)}: {list(unlinked)[:10]}) took them "
                 "in every stage.")
    return [note]


def write_refine_report(
    result: Any, prepared: Any, gt: Any, extra: list[RunRow] | None = None, g_unit: str = "px"
) -> Path:
    """The report of one ``bimcap refine`` run (``extra`` rows, e.g. FACaP, are shown beside;
    ``g_unit``: the unit of the run's G residual, :func:`bimcap.pipeline.refine.g_unit`)."""
    from bimcap.frontend.semantic_map import semantic_points

    rows = [RunRow("initial", result.init.poses, result.metrics_before, result.map_before)]
    rows += list(extra or [])
    rows.append(RunRow(f"{result.config.method.value} {result.config.effective_terms}",
                       result.refined.poses, result.metrics_after, result.map_after,
                       result.outcome.summary, result.outcome.seconds, outcome=result.outcome,
                       terms=result.config.effective_terms, g_unit=g_unit))
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
        notes=_scan_note(getattr(result, "scan_samples", None)),
        scan_samples=_scan_counts(getattr(result, "scan_samples", None)),
        observability=result.outcome.observability,
        deviations=getattr(result, "deviation_run", None),
    )
    return write_report(inp)
