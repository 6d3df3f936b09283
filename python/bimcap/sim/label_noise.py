"""Label noise: turn ground-truth label images into what an imperfect segmenter gives.

A real segmenter is wrong in two ways, and both are simulated:

* **Near class boundaries.** Its boundaries wander by a few pixels. With ``boundary_px`` > 0 a
  smooth random displacement field ``d(p)`` (each component Gaussian-smoothed white noise,
  scaled so that its standard deviation is ``boundary_px / 2`` and clipped to ±``boundary_px``)
  moves the true label image: the label at pixel ``p`` becomes the true label at ``p + d(p)``
  (nearest pixel; where that is UNKNOWN the true label stays). Every such error lies within
  ``√2 · boundary_px`` of a true class boundary.
* **Blobs.** Whole patches get a wrong class (a wall patch called floor, a door called wall),
  never salt-and-pepper: a smooth random field (white noise Gaussian-smoothed with
  ``blob_sigma`` × the image width) is thresholded so that, together with the boundary errors,
  exactly ``fraction`` of the labelled pixels are wrong. Each connected blob takes one wrong
  class, drawn among the other classes of the frame in proportion to their area (so confusions
  are between classes that are there), or any other class when the frame has one only; where a
  blob covers two true classes, the pixels of its chosen class take a second wrong class.

``fraction`` counts over the labelled pixels (label ≠ UNKNOWN; UNKNOWN pixels, e.g. sky through
a window, are never changed). When the boundary errors alone exceed ``fraction`` no blob is
added and the result has more wrong pixels than asked (reported by :func:`corrupt_labels`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.labels import Label
from bimcap.sim.render import SimConfigError

U8 = NDArray[np.uint8]

#: The classes a wrong label is drawn from.
SEMANTIC_CLASSES: tuple[int, ...] = tuple(int(x) for x in Label if x != Label.UNKNOWN)


@dataclass(frozen=True)
class LabelNoiseConfig:
    """How wrong the written labels are (module docstring).

    Attributes
    ----------
    fraction: fraction of the labelled pixels given a wrong class, in [0, 1).
    boundary_px: how far (pixels) class boundaries wander; 0 = no boundary errors.
    blob_sigma: smoothing of the blob field, as a fraction of the image width (blob size).
    """

    fraction: float = 0.0
    boundary_px: float = 0.0
    blob_sigma: float = 0.03

    def __post_init__(self) -> None:
        if not (np.isfinite(self.fraction) and 0.0 <= self.fraction < 1.0):
            raise SimConfigError(f"must be in [0, 1) (got {self.fraction!r})", None,
                                 "label_noise.fraction")
        if not (np.isfinite(self.boundary_px) and 0.0 <= self.boundary_px <= 100.0):
            raise SimConfigError(f"must be in [0, 100] pixels (got {self.boundary_px!r})", None,
                                 "label_noise.boundary_px")
        if not (np.isfinite(self.blob_sigma) and 0.0 < self.blob_sigma <= 0.5):
            raise SimConfigError(f"must be in (0, 0.5] (got {self.blob_sigma!r})", None,
                                 "label_noise.blob_sigma")

    @property
    def enabled(self) -> bool:
        return self.fraction > 0 or self.boundary_px > 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _smooth_field(rng: np.random.Generator, shape: tuple[int, int], sigma_px: float
                  ) -> NDArray[np.float32]:
    """White noise Gaussian-smoothed with ``sigma_px``, scaled to unit standard deviation."""
    from scipy.ndimage import gaussian_filter

    f = gaussian_filter(rng.standard_normal(shape).astype(np.float32), sigma_px, mode="wrap")
    std = float(f.std())
    return f / std if std > 0 else f


def corrupt_labels(labels: U8, config: LabelNoiseConfig, rng: np.random.Generator
                   ) -> tuple[U8, dict[str, float]]:
    """A noisy copy of the true label image ``labels`` (H, W) uint8.

    Parameters
    ----------
    labels: (H, W) uint8 :class:`~bimcap.labels.Label` ids, the truth.
    config: the noise model. rng: draws every random choice (same state, same output).

    Returns
    -------
    noisy: (H, W) uint8, the corrupted labels.
    stats: ``wrong_fraction`` (of the labelled pixels), ``boundary_fraction`` (wrong by the
        boundary wobble), ``blob_fraction`` (wrong in blobs), ``labelled`` (pixel count).
    """
    from scipy.ndimage import label as connected

    truth = np.asarray(labels, dtype=np.uint8)
    h, w = truth.shape
    noisy = truth.copy()
    labelled = truth != Label.UNKNOWN
    n_lab = int(labelled.sum())
    stats = {"wrong_fraction": 0.0, "boundary_fraction": 0.0, "blob_fraction": 0.0,
             "labelled": float(n_lab)}
    if n_lab == 0 or not config.enabled:
        return noisy, stats
    # all three fields are drawn whatever the settings: a fixed-size random stream
    corr = max(2.0, 2.0 * config.boundary_px)
    dx = _smooth_field(rng, (h, w), corr)
    dy = _smooth_field(rng, (h, w), corr)
    blob = _smooth_field(rng, (h, w), max(1.0, config.blob_sigma * w))
    if config.boundary_px > 0:
        b = config.boundary_px
        rows, cols = np.mgrid[0:h, 0:w]
        src_c = np.clip(np.rint(cols + np.clip(0.5 * b * dx, -b, b)), 0, w - 1).astype(np.intp)
        src_r = np.clip(np.rint(rows + np.clip(0.5 * b * dy, -b, b)), 0, h - 1).astype(np.intp)
        moved = truth[src_r, src_c]
        take = labelled & (moved != Label.UNKNOWN)
        noisy[take] = moved[take]
    wrong = noisy != truth
    n_boundary = int(wrong.sum())
    want = round(config.fraction * n_lab) - n_boundary
    cand = labelled & ~wrong
    n_cand = int(cand.sum())
    if want > 0 and n_cand > 0:
        want = min(want, n_cand)
        vals = blob[cand]
        thr = np.partition(vals, n_cand - want)[n_cand - want]
        mask = cand & (blob >= thr)
        comp, n_comp = connected(mask)
        hist = np.bincount(truth[labelled], minlength=len(Label)).astype(np.float64)
        # per blob: its majority true class and two different wrong classes
        maj = np.zeros(n_comp + 1, np.uint8)
        first = np.zeros(n_comp + 1, np.uint8)
        second = np.zeros(n_comp + 1, np.uint8)
        ids = comp[mask]
        pair = np.bincount(ids * len(Label) + truth[mask], minlength=(n_comp + 1) * len(Label))
        maj[:] = pair.reshape(n_comp + 1, len(Label)).argmax(axis=1)
        for c in range(1, n_comp + 1):
            others = [k for k in SEMANTIC_CLASSES if k != maj[c]]
            p = hist[others]
            if p.sum() <= 0:
                p = np.ones(len(others))
            p = p / p.sum()
            a = int(rng.choice(others, p=p))
            rest = [k for k in SEMANTIC_CLASSES if k != a]
            first[c], second[c] = a, int(rng.choice(rest))
        a, b2 = first[ids], second[ids]
        noisy[mask] = np.where(truth[mask] == a, b2, a)
    wrong = noisy != truth
    n_wrong = int(wrong.sum())
    stats.update(wrong_fraction=n_wrong / n_lab, boundary_fraction=n_boundary / n_lab,
                 blob_fraction=(n_wrong - n_boundary) / n_lab)
    return noisy, stats
