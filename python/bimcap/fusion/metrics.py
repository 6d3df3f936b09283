"""Depth-map accuracy against ground truth."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from bimcap.fusion.projection import FusionInputError


@dataclass(frozen=True)
class DepthErrors:
    """Errors of a depth map on the evaluated pixels.

    Evaluated pixels: ``valid & gt > 0``. ``coverage`` = fraction of them where the prediction is
    > 0; all other numbers are over the covered ones (``n`` pixels).

    mae, rmse: metres. inlier_ratio: fraction with ``|pred - gt| < max(0.05 m, 0.05 · gt)``.
    delta1: fraction with ``max(pred/gt, gt/pred) < 1.25`` (the usual δ<1.25, reported apart).
    """

    mae: float
    rmse: float
    inlier_ratio: float
    delta1: float
    coverage: float
    n: int

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


def depth_errors(pred: ArrayLike, gt: ArrayLike, valid: ArrayLike | None = None) -> DepthErrors:
    """Compare a predicted depth map (H, W) with ground truth (H, W), metres, 0 = unknown.

    ``valid`` (H, W) bool restricts the evaluated pixels (e.g. to where a baseline has output too).
    Returns NaN errors (and n = 0) when no evaluated pixel is covered.
    """
    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.shape != g.shape or p.ndim != 2:
        raise FusionInputError(f"pred {p.shape} and gt {g.shape} must be equal (H, W)",
                               field="pred")
    ev = np.isfinite(g) & (g > 0)
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape != g.shape:
            raise FusionInputError(f"valid {v.shape} must be {g.shape}", field="valid")
        ev &= v
    n_ev = int(ev.sum())
    cov = ev & np.isfinite(p) & (p > 0)
    n = int(cov.sum())
    if n == 0:
        nan = float("nan")
        return DepthErrors(nan, nan, nan, nan, 0.0 if n_ev else nan, 0)
    e = p[cov] - g[cov]
    ae = np.abs(e)
    ratio = np.maximum(p[cov] / g[cov], g[cov] / p[cov])
    return DepthErrors(
        mae=float(ae.mean()),
        rmse=float(np.sqrt((e * e).mean())),
        inlier_ratio=float((ae < np.maximum(0.05, 0.05 * g[cov])).mean()),
        delta1=float((ratio < 1.25).mean()),
        coverage=n / n_ev,
        n=n,
    )
