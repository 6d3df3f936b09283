"""Plots for the report (matplotlib ``Figure`` without pyplot, rendered by Agg; no display needed).

Every function returns the :class:`matplotlib.figure.Figure`; with ``path`` it also writes a PNG
atomically (rendered in memory, then :func:`bimcap.io.atomic.atomic_write_bytes`) and closes the
figure. World frame: z up, metres; the floor plan is drawn in x (right), y (up).
"""

from __future__ import annotations

import io
from collections.abc import Iterable, Mapping, Sequence
from os import PathLike
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.evaluation.errors import EvaluationError
from bimcap.evaluation.metrics import FrameErrors
from bimcap.io.atomic import atomic_write_bytes
from bimcap.labels import LABEL_COLORS, Label

if TYPE_CHECKING:
    from matplotlib.figure import Figure

_DPI = 120
#: Floor-plan colours: light and warm, behind the runs (whose palette is black, greys, colours).
_PLAN_COLORS = {int(Label.WALL): "#c4b49e", int(Label.COLUMN): "#8f8650"}
#: The fixed palette of the runs a report compares (:func:`run_colour`): the same run has the same
#: colour on every figure.
RUN_PALETTE: dict[str, str] = {
    "ground truth": "black",
    "initial": "0.6",
    "coarse": "tab:purple",
    "facap": "tab:orange",
    "bimcap": "tab:blue",
}
_OTHER_COLOURS = ("tab:green", "tab:red", "tab:brown", "tab:pink", "tab:cyan", "tab:olive")


def run_colour(name: str, index: int = 0) -> str:
    """The palette colour of a run named ``name`` (:data:`RUN_PALETTE`): ground truth black,
    the initial trajectory grey, FACaP orange, BIMCaP blue, the coarse stage purple; any other
    name takes the ``index``-th of a few further colours."""
    low = name.lower()
    if low in ("ground truth", "gt") or low.startswith("ground truth"):
        return RUN_PALETTE["ground truth"]
    if low.startswith(("initial", "before", "init")):
        return RUN_PALETTE["initial"]
    if "facap" in low:
        return RUN_PALETTE["facap"]
    if "bimcap" in low or low.startswith(("after", "refined")):
        return RUN_PALETTE["bimcap"]
    if "coarse" in low:
        return RUN_PALETTE["coarse"]
    return _OTHER_COLOURS[index % len(_OTHER_COLOURS)]


def _new_figure(
    ncols: int = 1, nrows: int = 1, size: tuple[float, float] = (7.0, 6.0)
) -> tuple[Figure, Any]:
    # a pyplot-free Figure renders with Agg and never touches the user's pyplot state or display
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=_DPI, layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def _finish(fig: Figure, path: str | PathLike[str] | None) -> Figure:
    if path is not None:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=_DPI)
        atomic_write_bytes(path, buf.getvalue())
    return fig


def _colour(label: int) -> tuple[float, float, float]:
    r, g, b = LABEL_COLORS[int(label)]
    return (r / 255.0, g / 255.0, b / 255.0)


def _plan_arrays(segments: ArrayLike, segment_class: ArrayLike
                 ) -> tuple[NDArray[np.float64], NDArray[Any]]:
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    cls = np.asarray(segment_class).reshape(-1)
    if len(cls) != len(seg):
        raise EvaluationError(f"{len(seg)} segments but {len(cls)} segment classes")
    return seg, cls


def _draw_plan(ax: Any, seg: NDArray[np.float64], cls: NDArray[Any], legend: bool = True) -> None:
    """The floor-plan segments, thin and underneath, one legend entry per class."""
    for label in np.unique(cls):
        sel = seg[cls == label]
        xs = np.stack([sel[:, 0], sel[:, 2], np.full(len(sel), np.nan)], axis=1).ravel()
        ys = np.stack([sel[:, 1], sel[:, 3], np.full(len(sel), np.nan)], axis=1).ravel()
        name = (
            Label(int(label)).name.lower() if int(label) in Label._value2member_map_ else str(label)
        )
        ax.plot(xs, ys, color=_PLAN_COLORS.get(int(label), "grey"), lw=2.0, zorder=1,
                label=f"plan: {name}" if legend else None)


def _xy(name: str, traj: ArrayLike) -> NDArray[np.float64]:
    xyz = np.asarray(traj, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] < 3:
        raise EvaluationError(f"trajectory {name!r} must be (N, 3) or (N, 7), got {xyz.shape}")
    return xyz


def _zoom(ax: Any, xy: NDArray[np.float64], margin_m: float = 1.0) -> tuple[float, float]:
    """Limit ``ax`` to the extent of ``xy`` (K, 2) plus ``margin_m`` (at least 15 % of the
    extent), equal aspect; returns the view's (width, height) in metres."""
    xy = xy[np.isfinite(xy).all(axis=1)]
    if not len(xy):
        return (1.0, 1.0)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = max(margin_m, 0.15 * float((hi - lo).max()))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal", adjustable="box")
    return (float(hi[0] - lo[0] + 2 * pad), float(hi[1] - lo[1] + 2 * pad))


def heading_step(n: int, ticks: int = 20) -> int:
    """Every how many frames a heading tick is drawn on a walk of ``n`` frames (about
    ``ticks`` ticks)."""
    return max(1, int(np.ceil(n / max(ticks, 1))))


def camera_forward_xy(poses: ArrayLike) -> NDArray[np.float64]:
    """(N, 2) unit xy direction of each camera's optical axis (camera +z) in the world, the
    heading seen from above; (0, 0) for a camera looking straight up or down.

    Parameters
    ----------
    poses: (N, 7) ``world_from_cam`` in TUM order.
    """
    from bimcap.geometry.poses import quat_to_rotmat

    p = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
    fwd = quat_to_rotmat(p[:, 3:7])[:, :2, 2]
    norm = np.linalg.norm(fwd, axis=1, keepdims=True)
    return np.where(norm > 1e-9, fwd / np.maximum(norm, 1e-12), 0.0)


def plot_trajectories_on_plan(
    segments: ArrayLike,
    segment_class: ArrayLike,
    trajectories: Mapping[str, ArrayLike],
    path: str | PathLike[str] | None = None,
    title: str = "Trajectories over the floor plan (top view)",
    margin_m: float = 1.0,
    heading_every: int | None = None,
) -> Figure:
    """Top view: the trajectories' xy positions and camera headings over the floor plan, zoomed
    to the walk.

    Parameters
    ----------
    segments: (S, 4) ``x1 y1 x2 y2`` metres.
    segment_class: (S,) label ids (``Label.WALL`` / ``Label.COLUMN``), coloured by label.
    trajectories: name → (N, 7) TUM poses ``world_from_cam`` (or (N, 3) positions, drawn without
        headings), world metres; colours from :func:`run_colour` (ground truth black, initial
        grey, FACaP orange, BIMCaP blue).
    path: PNG to write, or None.
    margin_m: the view is the walk's extent plus this margin (metres, at least 15 % of the
        extent); the plan is drawn behind, cut to the view.
    heading_every: a heading tick (the optical axis, seen from above) every this many frames;
        None: about 20 ticks along the walk.
    """
    seg, cls = _plan_arrays(segments, segment_class)
    fig, axes = _new_figure(size=(8.0, 6.5))
    ax = axes[0, 0]
    _draw_plan(ax, seg, cls)
    walks = {name: _xy(name, traj) for name, traj in trajectories.items()}
    extent = (1.0, 1.0)
    if walks:
        extent = _zoom(ax, np.concatenate([w[:, :2] for w in walks.values()]), margin_m)
    tick_len = 0.05 * max(extent)
    for i, (name, xyz) in enumerate(walks.items()):
        is_gt = run_colour(name) == RUN_PALETTE["ground truth"]
        colour = run_colour(name, i)
        # the ground truth is drawn wide, light and underneath, so a close estimate stays visible
        is_init = colour == RUN_PALETTE["initial"]
        ax.plot(xyz[:, 0], xyz[:, 1], "--" if is_init else "-", lw=3.0 if is_gt else 1.4,
                alpha=0.75 if is_gt else 1.0, color=colour, label=name, zorder=2 if is_gt else 3)
        ax.plot(xyz[:1, 0], xyz[:1, 1], "o", ms=5, color=colour, zorder=4)
        if xyz.shape[1] >= 7:
            k = heading_every or heading_step(len(xyz))
            sel = np.arange(0, len(xyz), k)
            d = camera_forward_xy(xyz[sel]) * tick_len
            ax.quiver(xyz[sel, 0], xyz[sel, 1], d[:, 0], d[:, 1], color=colour,
                      angles="xy", scale_units="xy", scale=1.0, width=0.004,
                      headwidth=3.0, headlength=3.5, zorder=4 if not is_gt else 2,
                      alpha=0.75 if is_gt else 1.0)
    if any(w.shape[1] >= 7 for w in walks.values()):
        n = max(len(w) for w in walks.values())
        k = heading_every or heading_step(n)
        ax.plot([], [], ls="none", marker=r"$\rightarrow$", ms=10, color="k",
                label="heading (optical axis)" + ("" if k == 1 else f", every {k} frames"))
    ax.plot([], [], ls="none", marker="o", ms=5, color="k", label="start")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.grid(True, lw=0.3)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside right upper", fontsize=9)
    return _finish(fig, path)


def error_limits(errors: Sequence[FrameErrors], pad: float = 1.05) -> tuple[float, float]:
    """Shared upper y-limits (translation m, rotation deg) for error figures of ``errors``, so
    that figures of several runs compare."""
    t = max((float(np.nanmax(e.trans_m)) for e in errors if len(e.trans_m)), default=1.0)
    r = max((float(np.nanmax(e.rot_deg)) for e in errors if len(e.rot_deg)), default=1.0)
    return (max(t, 1e-6) * pad, max(r, 1e-6) * pad)


def plot_errors_per_frame(
    errors_before: FrameErrors,
    errors_after: FrameErrors,
    path: str | PathLike[str] | None = None,
    names: tuple[str, str] = ("before", "after"),
    title: str | None = None,
    ylim: tuple[float, float] | None = None,
) -> Figure:
    """The paper's Fig. 5: translation (m) and rotation (deg) error per frame, before and after.

    Parameters
    ----------
    errors_before, errors_after: :class:`FrameErrors` (``TrajectoryMetrics.frame_errors``).
    path: PNG to write, or None.
    names: the two runs' names (legend; colours from :func:`run_colour`).
    title: the figure's title; None: "Error per frame: {before} vs {after}".
    ylim: upper limits (translation m, rotation deg), e.g. :func:`error_limits` of every run
        of a report, so that its error figures share their scale; None: each panel's own.
    """
    fig, axes = _new_figure(nrows=2, size=(8.0, 5.5))
    for i, (errs, name) in enumerate(zip((errors_before, errors_after), names, strict=True)):
        colour = run_colour(name, i)
        frames = np.arange(len(errs.trans_m))
        axes[0, 0].plot(
            frames,
            errs.trans_m,
            color=colour,
            lw=1.2,
            marker=".",
            label=f"{name} (RMSE {np.sqrt(np.mean(errs.trans_m**2)):.3f} m)",
        )
        axes[1, 0].plot(
            frames,
            errs.rot_deg,
            color=colour,
            lw=1.2,
            marker=".",
            label=f"{name} (RMSE {np.sqrt(np.mean(errs.rot_deg**2)):.2f}°)",
        )
    axes[0, 0].set_ylabel("translation error [m]")
    axes[1, 0].set_ylabel("rotation error [deg]")
    axes[1, 0].set_xlabel("frame")
    for k, ax in enumerate(axes[:, 0]):
        ax.grid(True, lw=0.3)
        ax.legend(loc="best", fontsize=8)
        ax.set_ylim(bottom=0.0, top=None if ylim is None else ylim[k])
    axes[0, 0].set_title(title or f"Error per frame: {names[0]} vs {names[1]} (lower is better)")
    return _finish(fig, path)


def plot_side_view(
    points: ArrayLike,
    labels: ArrayLike,
    heights: Mapping[str, float] | None = None,
    path: str | PathLike[str] | None = None,
    title: str = "Side views of floor and ceiling points",
) -> Figure:
    """The paper's Fig. 6: floor and ceiling points seen from the side (x–z and y–z).

    Parameters
    ----------
    points: (P, 3) world points, metres.
    labels: (P,) label ids; only ``Label.FLOOR`` and ``Label.CEILING`` points are drawn; a
        class without points has no legend entry and is named in the plot ("no ceiling
        samples").
    heights: optional name → z (metres) of reference planes (e.g. the BIM floor and ceiling),
        drawn as dashed horizontal lines.
    path: PNG to write, or None.
    """
    pts = np.asarray(points, dtype=np.float64)
    lab = np.asarray(labels).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(lab) != len(pts):
        raise EvaluationError(f"need (P, 3) points and (P,) labels, got {pts.shape}, {lab.shape}")
    fig, axes = _new_figure(ncols=2, size=(11.0, 4.9))
    for ax, axis, name in ((axes[0, 0], 0, "x"), (axes[0, 1], 1, "y")):
        missing = []
        for label in (Label.FLOOR, Label.CEILING):
            sel = lab == label
            if not sel.any():  # no legend entry for points that are not there: say so instead
                missing.append(label.name.lower())
                continue
            ax.scatter(
                pts[sel, axis],
                pts[sel, 2],
                s=1.0,
                color=_colour(label),
                label=f"{label.name.lower()} ({int(sel.sum())} samples)",
                rasterized=True,
            )
        if missing:
            ax.text(0.5, 0.5, "\n".join(f"no {m} samples" for m in missing),
                    transform=ax.transAxes, ha="center", va="center", fontsize=11,
                    color="0.3", bbox={"fc": "white", "ec": "0.6"})
        for i, (hname, z) in enumerate((heights or {}).items()):
            ax.axhline(float(z), ls="--", lw=1.0, color=f"C{i + 2}", label=hname)
        ax.set_xlabel(f"{name} [m]")
        ax.set_ylabel("z [m]")
        ax.grid(True, lw=0.3)
        if ax.get_legend_handles_labels()[0]:  # under the panel: it hides no point, no note
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, fontsize=9,
                      markerscale=5, frameon=False)
    fig.suptitle(title)
    return _finish(fig, path)


def _term_costs(summary: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    """Term → (cost before, cost after) from the shapes a solver summary may take."""
    out: dict[str, tuple[float, float]] = {}
    terms = summary.get("terms")
    if isinstance(terms, Mapping):
        for name, t in terms.items():
            if isinstance(t, Mapping):
                before = t.get("cost_before", t.get("initial_cost", t.get("initial")))
                after = t.get("cost_after", t.get("final_cost", t.get("final")))
                if before is not None and after is not None:
                    out[str(name)] = (float(before), float(after))
    for kb, ka in (
        ("cost_before", "cost_after"),
        ("initial_costs", "final_costs"),
        ("term_costs_before", "term_costs_after"),
    ):
        b, a = summary.get(kb), summary.get(ka)
        if isinstance(b, Mapping) and isinstance(a, Mapping):
            for name in b:
                if name in a:
                    out[str(name)] = (float(b[name]), float(a[name]))
    return out


#: Colours of the solver's terms (the BIM terms in their class's colour).
TERM_COLOURS: dict[str, Any] = {
    "G": "tab:cyan",
    "depth": "tab:brown",
    "F": tuple(c / 255.0 for c in LABEL_COLORS[int(Label.FLOOR)]),
    "Ce": tuple(c / 255.0 for c in LABEL_COLORS[int(Label.CEILING)]),
    "W": tuple(c / 255.0 for c in LABEL_COLORS[int(Label.WALL)]),
    "Co": tuple(c / 255.0 for c in LABEL_COLORS[int(Label.COLUMN)]),
    "prior": "0.45",
    "odometry": "0.75",
}


def _cost_text(cost: float, top: float) -> str:
    """A cost written beside the chart: ``0`` below a millionth of the largest cost (round-off
    of a term that starts at its minimum, e.g. the pose prior's 2e-31), else 2 digits."""
    return "0" if abs(cost) < 1e-6 * top else f"{cost:.2g}"


def plot_term_costs(
    summary: Mapping[str, Any],
    path: str | PathLike[str] | None = None,
    title: str = "Per-term cost before / after the solve",
    notes: Sequence[str] = (),
) -> Figure:
    """Each term's cost before and after the solve: its share of the total (left) and the costs
    on a linear scale (right); a term too small to see there (the pose prior, the odometry at
    the start) carries its value as text.

    Costs are Ceres costs, ½ Σ ρ(‖r / σ‖²): residuals divided by their noise scale, so the cost
    has no unit and the terms add up.

    Parameters
    ----------
    summary: a solver summary dict, with either ``{"terms": {name: {"cost_before": b,
        "cost_after": a}}}`` (``initial``/``final`` also accepted) or ``{"cost_before": {name: b},
        "cost_after": {name: a}}``.
    path: PNG to write, or None.
    title: the figure's title.
    notes: lines written under the chart (e.g. "Ce: 0 samples, the term did not act").

    Raises
    ------
    EvaluationError
        If no per-term costs are found.
    """
    costs = _term_costs(summary)
    if not costs:
        raise EvaluationError("the solver summary holds no per-term costs", field="terms")
    names = list(costs)
    before = np.array([costs[n][0] for n in names])
    after = np.array([costs[n][1] for n in names])
    colours = [TERM_COLOURS.get(n, _OTHER_COLOURS[i % len(_OTHER_COLOURS)])
               for i, n in enumerate(names)]
    fig, axes = _new_figure(ncols=2, size=(11.0, 4.2 + 0.22 * len(notes)))
    share_ax, ax = axes[0, 0], axes[0, 1]
    # left: shares of the total, one stacked bar before and one after
    for row, vals in enumerate((before, after)):
        total = float(vals.sum())
        left = 0.0
        for name, v, colour in zip(names, vals, colours, strict=True):
            share = 100.0 * v / total if total > 0 else 0.0
            share_ax.barh(row, share, left=left, color=colour, edgecolor="white",
                          label=name if row == 0 else None)
            if share >= 6.0:
                share_ax.text(left + share / 2, row, f"{name}\n{share:.0f}%", ha="center",
                              va="center", fontsize=9)
            left += share
        share_ax.text(101.0, row, f"total\n{total:.4g}", va="center", fontsize=9)
    share_ax.set_yticks([0, 1], ["before", "after"])
    share_ax.set_xlim(0.0, 125.0)
    share_ax.set_xticks([0, 25, 50, 75, 100])
    share_ax.invert_yaxis()
    share_ax.set_xlabel("share of the total cost [%]")
    share_ax.set_title("Each term's share of the cost")
    # under the panel, where it hides no bar
    share_ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), fontsize=9,
                    ncol=min(len(names), 6), frameon=False)
    # right: the costs themselves, linear
    x = np.arange(len(names))
    ax.bar(x - 0.2, before, width=0.4, color=colours, alpha=0.45, hatch="//", edgecolor="0.3",
           label="before")
    ax.bar(x + 0.2, after, width=0.4, color=colours, edgecolor="0.3", label="after")
    top = float(max(before.max(), after.max(), 1e-300))
    for k, (b, a) in enumerate(zip(before, after, strict=True)):
        if max(b, a) < 0.02 * top:  # invisible at this scale: write the values
            ax.text(k, 0.03 * top, f"{_cost_text(b, top)} →\n{_cost_text(a, top)}",
                    ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x, names)
    ax.set_ylabel("cost ½ Σ ρ(‖r/σ‖²) [no unit]")
    ax.set_title("Cost per term (linear; hatched = before)")
    ax.grid(True, axis="y", lw=0.3)
    ax.legend(fontsize=9)
    fig.suptitle(title)
    if notes:
        fig.supxlabel("\n".join(notes), fontsize=9, color="0.25")
    return _finish(fig, path)


def plot_observability(
    sigma: NDArray[np.float64],
    max_sigma_m: float,
    max_sigma_deg: float,
    path: str | PathLike[str] | None = None,
) -> Figure:
    """Per frame, how well the BIM terms alone pin each degree of freedom.

    Parameters
    ----------
    sigma: (N, 6) standard deviations of along, across, up (m) and roll, pitch, yaw (deg), ``inf``
        where the BIM does not observe the degree of freedom
        (``bimcap.optimize.observability.Observability.sigma()``).
    max_sigma_m, max_sigma_deg: the thresholds below which a degree of freedom counts as observed
        (drawn as dashed lines).
    path: PNG to write, or None.
    """
    from matplotlib.ticker import FuncFormatter, LogLocator

    fig, axes = _new_figure(nrows=2, size=(9.5, 5.5))
    s = np.asarray(sigma, dtype=np.float64).reshape(-1, 6)
    frames = np.arange(len(s))
    panels = ((axes[0, 0], slice(0, 3), ("along", "across", "up"), max_sigma_m, "m"),
              (axes[1, 0], slice(3, 6), ("roll", "pitch", "yaw"), max_sigma_deg, "deg"))
    for ax, cols, names, limit, unit in panels:
        ylabel = f"σ [{unit}]"
        block = s[:, cols]
        finite = block[np.isfinite(block)]
        top = max(float(finite.max()) if finite.size else limit, limit) * 3.0
        for k, (name, colour) in enumerate(zip(names, ("tab:blue", "tab:orange", "tab:green"),
                                               strict=True)):
            v = block[:, k]
            ok = np.isfinite(v)
            ax.semilogy(frames[ok], v[ok], "o-", ms=2.5, lw=0.8, color=colour, label=name)
            if (~ok).any():  # unobserved: a mark at the top of the panel
                ax.plot(frames[~ok], np.full(int((~ok).sum()), top * 1.4 ** k), "v", ms=4,
                        color=colour)
        ax.axhline(limit, color="k", ls="--", lw=0.8, label=f"observed below {limit:g} {unit}")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", lw=0.3)
        # plain numbers at 1-2-5 steps, not 4×10⁻²
        ax.yaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: ""))
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=9)
    axes[1, 0].set_xlabel("frame")
    axes[0, 0].set_title("What the BIM terms pin, per frame (lower is better; ▼ = not at all)")
    return _finish(fig, path)


def plot_errors_on_plan(
    segments: ArrayLike,
    segment_class: ArrayLike,
    runs: Mapping[str, tuple[ArrayLike, ArrayLike]],
    path: str | PathLike[str] | None = None,
    title: str = "Position error along the path (top view)",
    margin_m: float = 1.0,
) -> Figure:
    """One panel per run: its camera positions over the floor plan, coloured by that frame's
    position error, on one colour scale (centimetres) shared by every panel.

    Parameters
    ----------
    segments, segment_class: the floor plan, as :func:`plot_trajectories_on_plan`.
    runs: name → ((N, 3) or (N, 7) positions / poses in the world, metres; (N,) position error
        of each frame against the ground truth, metres).
    path: PNG to write, or None.
    margin_m: the view is every run's extent plus this margin (metres).
    """
    from matplotlib import rc_context

    seg, cls = _plan_arrays(segments, segment_class)
    if not runs:
        raise EvaluationError("no run to draw", field="runs")
    walks = {n: _xy(n, p) for n, (p, _) in runs.items()}
    errs = {n: 100.0 * np.asarray(e, dtype=np.float64).reshape(-1) for n, (_, e) in runs.items()}
    for n in runs:
        if len(errs[n]) != len(walks[n]):
            raise EvaluationError(f"run {n!r}: {len(walks[n])} positions but {len(errs[n])} errors")
    norm = _error_norm(errs.values())
    # the page shows this wide figure scaled down: text one size up, read at the report's width
    with rc_context({"font.size": 12, "axes.titlesize": 12, "axes.labelsize": 12}):
        return _errors_on_plan(seg, cls, walks, errs, norm, path, title, margin_m)


#: Errors spanning more than this ratio (largest / smallest) get a logarithmic colour scale.
LOG_SCALE_RATIO = 30.0
#: The smallest error a logarithmic colour scale resolves, centimetres.
LOG_SCALE_FLOOR_CM = 0.1


def _error_norm(errors_cm: Iterable[NDArray[np.float64]]) -> Any:
    """The colour scale of per-frame errors (cm) shared by every panel: linear from 0 to the
    largest, or logarithmic from the smallest (at least 0.1 cm) when they span more than
    :data:`LOG_SCALE_RATIO` — so that a run at 1 cm and one frame of another run 4 m off do not
    both come out in the bottom colour."""
    from matplotlib.colors import LogNorm, Normalize

    vals = np.concatenate([np.asarray(e, np.float64).reshape(-1) for e in errors_cm] or
                          [np.zeros(0)])
    vals = vals[np.isfinite(vals)]
    vmax = max(float(vals.max(initial=0.0)), 1e-3)
    positive = vals[vals > 0]
    vmin = max(float(positive.min(initial=vmax)), LOG_SCALE_FLOOR_CM)
    if vmax / vmin > LOG_SCALE_RATIO:
        return LogNorm(vmin, vmax, clip=True)
    return Normalize(0.0, vmax)


def _errors_on_plan(seg: NDArray[np.float64], cls: NDArray[Any],
                    walks: Mapping[str, NDArray[np.float64]],
                    errs: Mapping[str, NDArray[np.float64]], norm: Any,
                    path: str | PathLike[str] | None, title: str, margin_m: float) -> Figure:
    """:func:`plot_errors_on_plan`'s drawing (position errors ``errs`` in cm)."""
    fig, axes = _new_figure(ncols=len(walks), size=(4.2 * len(walks) + 1.2, 5.2))
    allxy = np.concatenate([w[:, :2] for w in walks.values()])
    sc = None
    for ax, (name, xyz) in zip(axes[0], walks.items(), strict=True):
        _draw_plan(ax, seg, cls, legend=False)
        ax.plot(xyz[:, 0], xyz[:, 1], "-", lw=0.8, color="0.5", zorder=2)
        sc = ax.scatter(xyz[:, 0], xyz[:, 1], c=errs[name], cmap="viridis", norm=norm, s=28,
                        edgecolors="k", linewidths=0.3, zorder=3)
        _zoom(ax, allxy, margin_m)
        e = errs[name]
        ax.set_title(f"{name}\nRMSE {np.sqrt(np.mean(e ** 2)):.1f} cm, max {e.max():.1f} cm",
                     color=run_colour(name))
        ax.set_xlabel("x [m]")
        ax.grid(True, lw=0.3)
    axes[0, 0].set_ylabel("y [m]")
    if sc is not None:
        scale = ", log scale" if type(norm).__name__ == "LogNorm" else ""
        fig.colorbar(sc, ax=list(axes[0]), label=f"position error [cm{scale}] (lower is better)",
                     shrink=0.9)
    fig.suptitle(title)
    return _finish(fig, path)


def _class_scatter(ax: Any, pts: NDArray[np.float64], lab: NDArray[Any], classes: Sequence[Label],
                   legend: bool, max_points: int, rng: np.random.Generator) -> int:
    """Top-view scatter of ``pts`` of ``classes`` in their class colours; returns how many
    points of those classes there were."""
    n = 0
    for label in classes:
        sel = np.flatnonzero(lab == int(label))
        n += len(sel)
        if not len(sel):
            continue
        if len(sel) > max_points:
            sel = rng.choice(sel, max_points, replace=False)
        ax.scatter(pts[sel, 0], pts[sel, 1], s=1.5, color=_colour(label), rasterized=True,
                   zorder=3, label=label.name.lower() if legend else None)
    return n


def plot_maps_on_plan(
    segments: ArrayLike,
    segment_class: ArrayLike,
    maps: Mapping[str, tuple[ArrayLike, ArrayLike]],
    path: str | PathLike[str] | None = None,
    title: str = "Semantic map over the floor plan (top view): wall and column samples",
    classes: Sequence[Label] = (Label.WALL, Label.COLUMN),
    margin_m: float = 1.0,
    max_points: int = 20000,
    seed: int = 0,
) -> Figure:
    """One panel per map (e.g. before / after): its samples of ``classes`` from above, in their
    class colours, over the floor plan; where a map's walls leave the plan's lines, the poses
    that placed them are off.

    Parameters
    ----------
    segments, segment_class: the floor plan, as :func:`plot_trajectories_on_plan`.
    maps: name → ((P, 3) world points in metres, (P,) label ids).
    path: PNG to write, or None.
    classes: the classes drawn (walls and columns: what the plan shows).
    margin_m: the view is every map's extent of those classes plus this margin (metres).
    max_points: at most this many points per class and panel (a seeded random subset).
    seed: the subset's seed.
    """
    seg, cls = _plan_arrays(segments, segment_class)
    if not maps:
        raise EvaluationError("no map to draw", field="maps")
    arrays = {}
    for name, (p, lab) in maps.items():
        pts, labs = np.asarray(p, np.float64).reshape(-1, 3), np.asarray(lab).reshape(-1)
        if len(pts) != len(labs):
            raise EvaluationError(f"map {name!r}: {len(pts)} points but {len(labs)} labels")
        arrays[name] = (pts, labs)
    fig, axes = _new_figure(ncols=len(maps), size=(4.6 * len(maps) + 0.8, 5.0))
    keep = [pts[np.isin(labs, [int(c) for c in classes]), :2] for pts, labs in arrays.values()]
    allxy = np.concatenate(keep) if sum(len(k) for k in keep) else seg.reshape(-1, 2)
    rng = np.random.default_rng(seed)
    for k, (ax, (name, (pts, labs))) in enumerate(zip(axes[0], arrays.items(), strict=True)):
        _draw_plan(ax, seg, cls, legend=k == 0)
        n = _class_scatter(ax, pts, labs, classes, k == 0, max_points, rng)
        if n == 0:
            ax.text(0.5, 0.5, "no " + " or ".join(c.name.lower() for c in classes) + " samples",
                    transform=ax.transAxes, ha="center", va="center", color="0.3")
        _zoom(ax, allxy, margin_m)
        ax.set_title(f"{name} ({n} samples)", fontsize=10, color=run_colour(name))
        ax.set_xlabel("x [m]")
        ax.grid(True, lw=0.3)
    axes[0, 0].set_ylabel("y [m]")
    if axes[0, 0].get_legend_handles_labels()[0]:
        fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center",
                   ncol=4, fontsize=9, markerscale=5)
    fig.suptitle(title)
    return _finish(fig, path)


def plot_map_3d(
    points: ArrayLike,
    labels: ArrayLike,
    trajectories: Mapping[str, ArrayLike],
    path: str | PathLike[str] | None = None,
    title: str = "Refined map and cameras (3-D)",
    max_points: int = 15000,
    seed: int = 0,
    elev_deg: float = 35.0,
    azim_deg: float = -60.0,
) -> Figure:
    """A static 3-D view: the map points in their class colours and each trajectory's camera
    centres with their optical axes.

    Parameters
    ----------
    points: (P, 3) world points, metres. labels: (P,) label ids.
    trajectories: name → (N, 7) ``world_from_cam`` TUM poses (colours from :func:`run_colour`;
        the ground truth dotted, without cameras).
    path: PNG to write, or None.
    max_points: at most this many points are drawn (a seeded random subset).
    seed: the subset's seed. elev_deg, azim_deg: the view direction.
    """
    from bimcap.geometry.poses import quat_to_rotmat

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lab = np.asarray(labels).reshape(-1)
    if len(lab) != len(pts):
        raise EvaluationError(f"{len(pts)} points but {len(lab)} labels")
    from matplotlib.figure import Figure as _Figure

    fig = _Figure(figsize=(8.0, 6.5), dpi=_DPI, layout="constrained")
    ax = fig.add_subplot(projection="3d")
    rng = np.random.default_rng(seed)
    sel = np.arange(len(pts))
    if len(sel) > max_points:
        sel = np.sort(rng.choice(sel, max_points, replace=False))
    for label in np.unique(lab[sel]):
        s = sel[lab[sel] == label]
        name = Label(int(label)).name.lower() if int(label) in Label._value2member_map_ else "?"
        ax.scatter(pts[s, 0], pts[s, 1], pts[s, 2], s=0.6, color=_colour(int(label)),
                   label=f"{name} ({int((lab == label).sum())})", depthshade=False,
                   rasterized=True)
    span = [pts[sel]] if len(sel) else []
    for i, (name, traj) in enumerate(trajectories.items()):
        p = _xy(name, traj)
        colour = run_colour(name, i)
        if colour == RUN_PALETTE["ground truth"]:  # thin, so the estimate on it stays visible
            ax.plot(p[:, 0], p[:, 1], p[:, 2], ":", color=colour, lw=1.0, label=name)
            continue
        ax.plot(p[:, 0], p[:, 1], p[:, 2], "-", color=colour, lw=1.5, label=name)
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], color=colour, s=10, depthshade=False)
        if p.shape[1] >= 7:
            fwd = quat_to_rotmat(p[:, 3:7])[:, :, 2] * 0.4
            ax.quiver(p[:, 0], p[:, 1], p[:, 2], fwd[:, 0], fwd[:, 1], fwd[:, 2], color=colour,
                      lw=0.8, arrow_length_ratio=0.3)
        span.append(p[:, :3])
    if span:
        xyz = np.concatenate(span)
        lo, hi = xyz.min(axis=0), xyz.max(axis=0)
        ax.set_box_aspect(tuple(np.maximum(hi - lo, 1e-3)))
    ax.view_init(elev=elev_deg, azim=azim_deg)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", fontsize=9, markerscale=6)
    return _finish(fig, path)
