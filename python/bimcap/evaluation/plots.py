"""Plots for the report (matplotlib ``Figure`` without pyplot, rendered by Agg; no display needed).

Every function returns the :class:`matplotlib.figure.Figure`; with ``path`` it also writes a PNG
atomically (rendered in memory, then :func:`bimcap.io.atomic.atomic_write_bytes`) and closes the
figure. World frame: z up, metres; the floor plan is drawn in x (right), y (up).
"""

from __future__ import annotations

import io
from collections.abc import Mapping
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
#: Line colours of well-known trajectory names; others cycle through matplotlib's defaults.
_PLAN_COLORS = {int(Label.WALL): "dimgray", int(Label.COLUMN): "tab:olive"}
_TRAJ_COLORS = {
    "ground truth": "tab:green",
    "gt": "tab:green",
    "before": "tab:red",
    "after": "tab:blue",
}


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


def plot_trajectories_on_plan(
    segments: ArrayLike,
    segment_class: ArrayLike,
    trajectories: Mapping[str, ArrayLike],
    path: str | PathLike[str] | None = None,
    title: str = "Trajectories over the floor plan (top view)",
) -> Figure:
    """Top view: floor-plan segments and the trajectories' xy positions.

    Parameters
    ----------
    segments: (S, 4) ``x1 y1 x2 y2`` metres.
    segment_class: (S,) label ids (``Label.WALL`` / ``Label.COLUMN``), coloured by label.
    trajectories: name → (N, 3) (or (N, 7) TUM poses) positions in the world, metres; names
        "ground truth", "before", "after" get fixed colours.
    path: PNG to write, or None.
    """
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    cls = np.asarray(segment_class).reshape(-1)
    if len(cls) != len(seg):
        raise EvaluationError(f"{len(seg)} segments but {len(cls)} segment classes")
    fig, axes = _new_figure()
    ax = axes[0, 0]
    for label in np.unique(cls):
        sel = seg[cls == label]
        xs = np.stack([sel[:, 0], sel[:, 2], np.full(len(sel), np.nan)], axis=1).ravel()
        ys = np.stack([sel[:, 1], sel[:, 3], np.full(len(sel), np.nan)], axis=1).ravel()
        name = (
            Label(int(label)).name.lower() if int(label) in Label._value2member_map_ else str(label)
        )
        ax.plot(xs, ys, color=_PLAN_COLORS.get(int(label), "grey"), lw=2.0, label=f"plan: {name}")
    for name, traj in trajectories.items():
        xyz = np.asarray(traj, dtype=np.float64)
        if xyz.ndim != 2 or xyz.shape[1] < 3:
            raise EvaluationError(f"trajectory {name!r} must be (N, 3) or (N, 7), got {xyz.shape}")
        is_gt = name.lower() in ("ground truth", "gt")
        # the ground truth is drawn wide and underneath, so a close estimate stays visible on it
        ax.plot(
            xyz[:, 0],
            xyz[:, 1],
            "-",
            lw=3.0 if is_gt else 1.2,
            alpha=0.6 if is_gt else 1.0,
            color=_TRAJ_COLORS.get(name.lower()),
            label=name,
            zorder=2 if is_gt else 3,
        )
        ax.plot(xyz[:1, 0], xyz[:1, 1], "o", ms=4, color=ax.lines[-1].get_color())
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.grid(True, lw=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    return _finish(fig, path)


def plot_errors_per_frame(
    errors_before: FrameErrors,
    errors_after: FrameErrors,
    path: str | PathLike[str] | None = None,
) -> Figure:
    """The paper's Fig. 5: translation (m) and rotation (deg) error per frame, before and after.

    Parameters
    ----------
    errors_before, errors_after: :class:`FrameErrors` (``TrajectoryMetrics.frame_errors``).
    path: PNG to write, or None.
    """
    fig, axes = _new_figure(nrows=2, size=(8.0, 5.5))
    for errs, name, colour in (
        (errors_before, "before", "tab:red"),
        (errors_after, "after", "tab:blue"),
    ):
        frames = np.arange(len(errs.trans_m))
        axes[0, 0].plot(
            frames,
            errs.trans_m,
            color=colour,
            lw=1.0,
            label=f"{name} (RMSE {np.sqrt(np.mean(errs.trans_m**2)):.3f} m)",
        )
        axes[1, 0].plot(
            frames,
            errs.rot_deg,
            color=colour,
            lw=1.0,
            label=f"{name} (RMSE {np.sqrt(np.mean(errs.rot_deg**2)):.2f}°)",
        )
    axes[0, 0].set_ylabel("translation error [m]")
    axes[1, 0].set_ylabel("rotation error [deg]")
    axes[1, 0].set_xlabel("frame")
    for ax in axes[:, 0]:
        ax.grid(True, lw=0.3)
        ax.legend(loc="best", fontsize=8)
        ax.set_ylim(bottom=0.0)
    axes[0, 0].set_title("Error per frame before / after refinement")
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
    labels: (P,) label ids; only ``Label.FLOOR`` and ``Label.CEILING`` points are drawn.
    heights: optional name → z (metres) of reference planes (e.g. the BIM floor and ceiling),
        drawn as dashed horizontal lines.
    path: PNG to write, or None.
    """
    pts = np.asarray(points, dtype=np.float64)
    lab = np.asarray(labels).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(lab) != len(pts):
        raise EvaluationError(f"need (P, 3) points and (P,) labels, got {pts.shape}, {lab.shape}")
    fig, axes = _new_figure(ncols=2, size=(11.0, 4.5))
    for ax, axis, name in ((axes[0, 0], 0, "x"), (axes[0, 1], 1, "y")):
        for label in (Label.FLOOR, Label.CEILING):
            sel = lab == label
            ax.scatter(
                pts[sel, axis],
                pts[sel, 2],
                s=1.0,
                color=_colour(label),
                label=label.name.lower(),
                rasterized=True,
            )
        for i, (hname, z) in enumerate((heights or {}).items()):
            ax.axhline(float(z), ls="--", lw=1.0, color=f"C{i + 2}", label=hname)
        ax.set_xlabel(f"{name} [m]")
        ax.set_ylabel("z [m]")
        ax.grid(True, lw=0.3)
        ax.legend(loc="best", fontsize=8, markerscale=5)
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


def plot_term_costs(summary: Mapping[str, Any], path: str | PathLike[str] | None = None) -> Figure:
    """Bar chart of each term's cost before and after the solve (log scale).

    Parameters
    ----------
    summary: a solver summary dict, with either ``{"terms": {name: {"cost_before": b,
        "cost_after": a}}}`` (``initial``/``final`` also accepted) or ``{"cost_before": {name: b},
        "cost_after": {name: a}}``.
    path: PNG to write, or None.

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
    fig, axes = _new_figure(size=(7.0, 4.0))
    ax = axes[0, 0]
    x = np.arange(len(names))
    ax.bar(x - 0.2, before, width=0.4, color="tab:red", label="before")
    ax.bar(x + 0.2, after, width=0.4, color="tab:blue", label="after")
    ax.set_xticks(x, names)
    if (before > 0).all() and (after > 0).all():
        ax.set_yscale("log")
    ax.set_ylabel("cost")
    ax.set_title("Per-term cost before / after")
    ax.grid(True, axis="y", lw=0.3)
    ax.legend(fontsize=8)
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
    fig, axes = _new_figure(nrows=2, size=(8.0, 5.5))
    s = np.asarray(sigma, dtype=np.float64).reshape(-1, 6)
    frames = np.arange(len(s))
    panels = ((axes[0, 0], slice(0, 3), ("along", "across", "up"), max_sigma_m, "σ [m]"),
              (axes[1, 0], slice(3, 6), ("roll", "pitch", "yaw"), max_sigma_deg, "σ [deg]"))
    for ax, cols, names, limit, ylabel in panels:
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
        ax.axhline(limit, color="k", ls="--", lw=0.8, label=f"observed below {limit:g}")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", lw=0.3)
        ax.legend(loc="upper left", fontsize=7, ncol=4)
    axes[1, 0].set_xlabel("frame")
    axes[0, 0].set_title("What the BIM terms pin, per frame (lower is better; ▼ = not at all)")
    return _finish(fig, path)
