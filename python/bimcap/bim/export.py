"""Pictures of the floor plan: one SVG and one PNG per storey, classes coloured.

The exact slice at the cut height is drawn thin in grey underneath, the detected segments on top
in their class colour (wall red, column green, :data:`bimcap.labels.LABEL_COLORS`); north (+y) is
up, a 1 m scale bar sits in the lower left, and the title gives the storey, the band and the
coverage / precision against the exact slice.
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


def storey_svg(sp: StoreyPlan, px_per_m: float = 40.0) -> str:
    """The SVG text of one storey's plan (1 SVG unit = 1 pixel at ``px_per_m``)."""
    lo, hi = _frame(sp)
    w, h = (hi - lo) * px_per_m
    head = 40.0

    def tx(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return (x - lo[0]) * px_per_m

    def ty(y: NDArray[np.float64]) -> NDArray[np.float64]:
        return head + (hi[1] - y) * px_per_m

    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.0f}" height="{h + head:.0f}" '
        f'viewBox="0 0 {w:.1f} {h + head:.1f}">',
        '<rect width="100%" height="100%" fill="white"/>',
        f'<text x="4" y="16" font-family="sans-serif" font-size="13">{_title(sp)[0]}</text>',
        f'<text x="4" y="32" font-family="sans-serif" font-size="11">{_title(sp)[1]}</text>',
    ]
    for cls in PLAN_CLASSES:
        ex = sp.exact.get(cls, np.zeros((0, 4)))
        for s in ex:
            out.append(
                f'<line x1="{tx(s[0]):.2f}" y1="{ty(s[1]):.2f}" x2="{tx(s[2]):.2f}" '
                f'y2="{ty(s[3]):.2f}" stroke="rgb{_EXACT_RGB}" stroke-width="1"/>'
            )
    for s, c in zip(sp.segments, sp.segment_class, strict=True):
        r, g, b = (int(v) for v in LABEL_COLORS[int(c)])
        out.append(
            f'<line x1="{tx(s[0]):.2f}" y1="{ty(s[1]):.2f}" x2="{tx(s[2]):.2f}" '
            f'y2="{ty(s[3]):.2f}" stroke="rgb({r},{g},{b})" stroke-width="2" '
            f'stroke-linecap="round"><title>{Label(int(c)).name.lower()}</title></line>'
        )
    y0 = head + h - 10
    out.append(f'<line x1="10" y1="{y0:.1f}" x2="{10 + px_per_m:.1f}" y2="{y0:.1f}" '
               'stroke="black" stroke-width="3"/>')
    out.append(f'<text x="10" y="{y0 - 5:.1f}" font-family="sans-serif" font-size="11">1 m</text>')
    out.append("</svg>\n")
    return "\n".join(out)


def storey_png(sp: StoreyPlan, px_per_m: float = 40.0, max_px: int = 2400) -> bytes:
    """PNG bytes of one storey's plan (scale reduced so that the larger side ≤ ``max_px``)."""
    import cv2

    lo, hi = _frame(sp)
    scale = min(px_per_m, max_px / max(float((hi - lo).max()), 1e-6))
    head = 44
    w, h = (np.ceil((hi - lo) * scale)).astype(int)
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
    y0 = head + h - 10
    cv2.line(img, (10, y0), (10 + round(scale), y0), (0, 0, 0), 3)
    cv2.putText(img, "1 m", (10, y0 - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for k, line in enumerate(_title(sp)):
        cv2.putText(img, line, (4, 17 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
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
