"""The deviation picture: a storey's walls and columns over the floor plan, coloured by offset.

Each wall and column is drawn as the convex hull of its mesh's xy (a wall's rectangle); colour:
the offset on a diverging scale (blue −2 × tolerance … white … red +2 × tolerance; a column by the
length of its offset), grey hatched when unobserved, a red cross over a dashed outline when
missing; a datum element (declared as built right) outlined in green; the unexplained clusters as
orange boxes; the walk (sensor centres) as a thin line. A legend below the plan names each mark.
"""

from __future__ import annotations

from os import PathLike
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.deviations.analysis import DeviationReport, ElementStatus
from bimcap.labels import Label

#: edge colour of a datum element (declared as built right)
DATUM_COLOUR = "tab:green"


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _hull(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """(H, 2) convex hull of (M, 2) points, counter-clockwise (monotone chain)."""
    pts = np.unique(np.round(xy, 6), axis=0)
    if len(pts) < 3:
        return pts

    def half(points: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        out: list[NDArray[np.float64]] = []
        for p in points:
            while len(out) >= 2 and _cross(out[-1] - out[-2], p - out[-2]) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.asarray(lower[:-1] + upper[:-1])


def busiest_storey(report: DeviationReport) -> str | None:
    """The storey with the most observed elements (None when none is observed)."""
    counts: dict[str, int] = {}
    for e in report.elements:
        if e.status is not ElementStatus.UNOBSERVED and e.storey is not None:
            counts[e.storey] = counts.get(e.storey, 0) + 1
    return max(counts, key=lambda k: counts[k]) if counts else None


def plot_deviations_on_plan(model: Any, report: DeviationReport,
                            path: str | PathLike[str] | None = None, storey: str | None = None,
                            walk_xy: NDArray[np.float64] | None = None) -> Any:
    """Draw ``storey``'s (default: :func:`busiest_storey`) walls and columns coloured by offset.

    Parameters
    ----------
    model: the design (:class:`bimcap.bim.ingest.BimModel`): the elements' meshes, by GUID.
    report: the analysis.
    path: where to save the PNG (None: only return the figure).
    walk_xy: (N, 2) sensor positions to draw (metres), or None.

    Returns the matplotlib ``Figure``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon, Rectangle

    storey = storey if storey is not None else busiest_storey(report)
    meshes = {e.guid: e for e in model.elements}
    tol = report.options.tolerance_m
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-200 * tol, vmax=200 * tol)
    cmap = plt.get_cmap("coolwarm")
    shown = [(e, meshes[e.guid]) for e in report.elements if e.guid in meshes
             and meshes[e.guid].label in (Label.WALL, Label.COLUMN) and e.storey == storey]
    xy = np.concatenate([src.vertices[:, :2] for _, src in shown]) if shown else np.zeros((1, 2))
    span = np.maximum(xy.max(axis=0) - xy.min(axis=0), 1.0)
    width = 10.0
    fig, ax = plt.subplots(figsize=(width, float(np.clip(width * span[1] / span[0], 4, 12)) + 1))
    counts = {s.value: 0 for s in ElementStatus}
    for e, src in shown:
        counts[e.status.value] += 1
        poly = _hull(src.vertices[:, :2])
        if len(poly) < 3:
            continue
        if e.status is ElementStatus.MISSING:
            ax.add_patch(Polygon(poly, closed=True, fill=False, ls="--", ec="red", lw=1.2))
            c = poly.mean(axis=0)
            ax.plot(c[0], c[1], "x", color="red", ms=12, mew=2.5)
        elif e.status is ElementStatus.UNOBSERVED or e.offset_m is None:
            ax.add_patch(Polygon(poly, closed=True, fc="0.85", ec="0.6", hatch="///", lw=0.5))
        else:
            colour = cmap(norm(100 * e.offset_m))
            edge, lw = ("black", 1.2) if e.status is ElementStatus.DEVIATING else ("0.5", 0.5)
            if e.datum:
                edge, lw = DATUM_COLOUR, 1.6
            ax.add_patch(Polygon(poly, closed=True, fc=colour, ec=edge, lw=lw))
            if e.status is ElementStatus.DEVIATING:
                c = poly.mean(axis=0)
                ax.annotate(f"{100 * e.offset_m:+.1f} cm", c, xytext=(0, 8),
                            textcoords="offset points", fontsize=8, ha="center",
                            va="bottom", bbox={"boxstyle": "round,pad=0.15", "fc": "white",
                                               "ec": "none", "alpha": 0.8})
    for cl in report.clusters:
        ax.add_patch(Rectangle(cl.min[:2], cl.extent[0], cl.extent[1], fill=False, ec="orange",
                               lw=1.0, ls=":"))
    handles: list[Any] = [
        Patch(fc=cmap(norm(150 * tol)), ec="black", lw=1.2,
              label=f"deviating (beyond {100 * tol:.0f} cm; offset in cm)"),
        Patch(fc=cmap(norm(0.0)), ec="0.5", lw=0.5, label="ok"),
        Line2D([], [], ls="--", color="red", marker="x", ms=8, mew=2, label="missing"),
        Patch(fc="0.85", ec="0.6", hatch="///", lw=0.5, label="unobserved"),
    ]
    if any(e.datum for e, _ in shown):
        handles.append(Patch(fc="white", ec=DATUM_COLOUR, lw=1.6,
                             label="datum (declared as built right)"))
    if report.clusters:
        handles.append(Patch(fill=False, ec="orange", ls=":", label="points no element explains"))
    if walk_xy is not None and len(walk_xy):
        (line,) = ax.plot(walk_xy[:, 0], walk_xy[:, 1], "-", color="0.3", lw=0.6, label="walk")
        handles.append(line)
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=4,
              fontsize=8, frameon=False)
    ax.autoscale_view()
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"Deviations of the walls and columns of storey {storey}: "
                 + ", ".join(f"{n} {k}" for k, n in counts.items()), fontsize=10)
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=ax, label="offset along the normal [cm]", shrink=0.7)
    fig.tight_layout()
    if path is not None:
        fig.savefig(str(path), dpi=110)
        plt.close(fig)
    return fig
