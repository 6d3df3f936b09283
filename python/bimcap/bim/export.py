"""Pictures of the floor plan: one SVG and one PNG per storey, classes coloured.

The exact slice at the cut height is drawn thin in grey underneath, the detected segments on top
in their class colour (wall red, column green, :data:`bimcap.labels.LABEL_COLORS`); north (+y) is
up, a legend names the colours, a scale bar (1, 2, 5, 10 ... m) sits in the lower left, and the
title gives the storey, the band and the coverage / precision against the exact slice. The SVG
is in metres (viewBox and coordinates; world y drawn as SVG -y).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bimcap.bim.floorplan import PLAN_CLASSES, FloorPlan, StoreyPlan
from bimcap.io.atomic import atomic_write_bytes, atomic_write_text
from bimcap.labels import LABEL_COLORS, Label

_EXACT_RGB = (170, 170, 170)


def _title(sp: StoreyPlan) -> tuple[str, str]:
    """Two title lines: storey, band and segment count; agreement with the exact slice."""
    a = sp.agreement.get("all")
    q = "" if a is None else (f"coverage {a.coverage:.3f}, precision {a.precision:.3f} "
                              f"(tol {a.tol_m:.2f} m; grey = exact slice)")
    return (f"{sp.storey}: z {sp.band[0]:.2f}..{sp.band[1]:.2f} m, "
            f"{len(sp.segments)} segments", q)


def _frame(sp: StoreyPlan, margin: float = 0.5) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    parts = [sp.segments] + [e for e in sp.exact_band.values() if len(e)]
    allseg = np.concatenate([p for p in parts if len(p)]) if any(len(p) for p in parts) else \
        np.zeros((1, 4))
    xy = allseg.reshape(-1, 2)
    return xy.min(axis=0) - margin, xy.max(axis=0) + margin


#: The classes drawn and their legend names (gaps in the walls are doors and openings).
_LEGEND = ((Label.WALL, "wall"), (Label.COLUMN, "column"))


def scale_bar_m(width_m: float) -> float:
    """A round scale-bar length (1, 2, 5, 10, ... m) about a fifth of ``width_m``."""
    target = max(width_m / 5.0, 1e-3)
    base = 10.0 ** np.floor(np.log10(target))
    return float(max((m * base for m in (1.0, 2.0, 5.0) if m * base <= target), default=base))


def svg_frame(sp: StoreyPlan) -> tuple[float, float, float, float, float]:
    """The SVG's frame of one storey, metres: ``(x0, y0, width, height, head)`` where the
    plan spans x ``x0..x0+width`` and world y ``y0..y0+height`` and a band of ``head`` metres
    above it holds the titles and the legend (the viewBox is ``x0, -(y0+height+head), width,
    height+head``: SVG's y points down, so world y is negated)."""
    lo, hi = _frame(sp)
    w, h = float(hi[0] - lo[0]), float(hi[1] - lo[1])
    return float(lo[0]), float(lo[1]), w, h, 4.6 * _font_m(w)


def _font_m(width_m: float) -> float:
    """The text size in metres: a title line of about 60 characters fits the plan's width."""
    return min(0.35, max(width_m, 1e-3) / 36.0)


def storey_svg(sp: StoreyPlan, px_per_m: float = 40.0) -> str:
    """The SVG text of one storey's plan in metres: the viewBox and every coordinate are world
    metres, x right and y up (drawn as ``-y``, SVG's y pointing down; :func:`svg_frame`), shown
    at ``px_per_m`` pixels per metre (at least 480 pixels wide); lines keep their width in
    pixels when zoomed. A legend (wall, column, exact slice) and a scale bar are part of the
    picture."""
    x0, y0, w, h, head = svg_frame(sp)
    px_per_m = max(px_per_m, 480.0 / max(w, 1e-3))
    font = _font_m(w)
    top = -(y0 + h + head)  # the viewBox's top edge (SVG y = -world y)

    def line(s: NDArray[np.float64], rgb: tuple[int, ...], width_px: float,
             extra: str = "") -> str:
        return (f'<line x1="{s[0]:.4f}" y1="{-s[1]:.4f}" x2="{s[2]:.4f}" y2="{-s[3]:.4f}" '
                f'stroke="rgb({rgb[0]},{rgb[1]},{rgb[2]})" stroke-width="{width_px:g}" '
                f'vector-effect="non-scaling-stroke"{extra}')

    def text(x: float, y: float, body: str, size: float) -> str:
        return (f'<text x="{x:.4f}" y="{y:.4f}" font-family="sans-serif" '
                f'font-size="{size:.4f}">{body}</text>')

    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{w * px_per_m:.0f}" '
        f'height="{(h + head) * px_per_m:.0f}" viewBox="{x0:.4f} {top:.4f} {w:.4f} '
        f'{h + head:.4f}">',
        "<desc>Units: metres (world x right, world y up = SVG -y).</desc>",
        f'<rect x="{x0:.4f}" y="{top:.4f}" width="{w:.4f}" height="{h + head:.4f}" '
        'fill="white"/>',
        text(x0 + 0.3 * font, top + 1.2 * font, _title(sp)[0], font),
        text(x0 + 0.3 * font, top + 2.4 * font, _title(sp)[1], 0.85 * font),
    ]
    # legend: a short line of each class's colour and its name
    lx, ly = x0 + 0.3 * font, top + 3.8 * font
    entries = [(tuple(int(v) for v in LABEL_COLORS[int(c)]), n) for c, n in _LEGEND]
    entries.append((_EXACT_RGB, "exact slice"))
    for rgb, name in entries:
        seg = np.array([lx, -ly, lx + 1.5 * font, -ly])
        out.append(line(seg, rgb, 3, "/>"))
        out.append(text(lx + 1.9 * font, ly + 0.35 * font, name, 0.85 * font))
        lx += (2.4 + 0.55 * len(name)) * font
    out.append(text(lx, ly + 0.35 * font, "(gaps: doors and openings)", 0.85 * font))
    for cls in PLAN_CLASSES:
        for s in sp.exact.get(cls, np.zeros((0, 4))):
            out.append(line(s, _EXACT_RGB, 1, "/>"))
    for s, c in zip(sp.segments, sp.segment_class, strict=True):
        rgb = tuple(int(v) for v in LABEL_COLORS[int(c)])
        out.append(line(s, rgb, 2, ' stroke-linecap="round">'
                        f"<title>{Label(int(c)).name.lower()}</title></line>"))
    bar = scale_bar_m(w)
    bx, by = x0 + 0.5 * font, y0 + 0.8 * font
    out.append(line(np.array([bx, by, bx + bar, by]), (0, 0, 0), 3, "/>"))
    out.append(text(bx, -(by + 0.4 * font), f"{bar:g} m", 0.85 * font))
    out.append("</svg>\n")
    return "\n".join(out)


def storey_png(sp: StoreyPlan, px_per_m: float = 40.0, max_px: int = 2400) -> bytes:
    """PNG bytes of one storey's plan (scale reduced so that the larger side ≤ ``max_px``),
    with its titles, a legend (wall, column, exact slice) and a scale bar."""
    import cv2

    lo, hi = _frame(sp)
    scale = min(px_per_m, max_px / max(float((hi - lo).max()), 1e-6))
    head = 66
    w, h = (np.ceil((hi - lo) * scale)).astype(int)
    w = max(int(w), 420)  # room for the titles and the legend
    img = np.full((h + head, w, 3), 255, dtype=np.uint8)

    def pix(seg: NDArray[np.float64]) -> tuple[tuple[int, int], tuple[int, int]]:
        x = (seg[[0, 2]] - lo[0]) * scale
        y = head + (hi[1] - seg[[1, 3]]) * scale
        return ((int(round(x[0])), int(round(y[0]))),  # noqa: RUF046 (numpy < 2)
                (int(round(x[1])), int(round(y[1]))))  # noqa: RUF046 (numpy < 2)

    for cls in PLAN_CLASSES:
        for s in sp.exact.get(cls, np.zeros((0, 4))):
            a, b = pix(s)
            cv2.line(img, a, b, _EXACT_RGB[::-1], 1, cv2.LINE_AA)
    for s, c in zip(sp.segments, sp.segment_class, strict=True):
        a, b = pix(s)
        r, g, bl = (int(v) for v in LABEL_COLORS[int(c)])
        cv2.line(img, a, b, (bl, g, r), 2, cv2.LINE_AA)
    bar = scale_bar_m(float((hi - lo)[0]))
    y0 = head + h - 10
    cv2.line(img, (10, y0), (10 + round(bar * scale), y0), (0, 0, 0), 3)
    cv2.putText(img, f"{bar:g} m", (10, y0 - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                cv2.LINE_AA)
    for k, line in enumerate(_title(sp)):
        cv2.putText(img, line, (4, 17 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
    x = 6
    entries = [(tuple(int(v) for v in LABEL_COLORS[int(c)]), n) for c, n in _LEGEND]
    for rgb, name in [*entries, (_EXACT_RGB, "exact slice")]:
        cv2.line(img, (x, 56), (x + 22, 56), rgb[::-1], 3, cv2.LINE_AA)
        cv2.putText(img, name, (x + 27, 60), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1,
                    cv2.LINE_AA)
        x += 40 + 9 * len(name)
    ok, buf = cv2.imencode(".png", img)
    if not ok:  # pragma: no cover - cv2 only fails on empty images
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def write_pictures(fp: FloorPlan, directory: str | PathLike[str]) -> list[Path]:
    """Write ``floorplan_NN_<storey>.svg`` and ``.png`` for every storey; returns the paths."""

    d = Path(directory)
    out = []
    for i, sp in enumerate(fp.storeys):
        stem = d / f"floorplan_{i:02d}_{slug(sp.storey)}"
        atomic_write_text(stem.with_suffix(".svg"), storey_svg(sp))
        atomic_write_bytes(stem.with_suffix(".png"), storey_png(sp))
        out += [stem.with_suffix(".svg"), stem.with_suffix(".png")]
    return out


def slug(name: str) -> str:
    """A file-name-safe version of a storey name."""
    import re

    return re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_") or "storey"
