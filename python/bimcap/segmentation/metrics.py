"""Per-class intersection over union of label images."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike

from bimcap.labels import Label
from bimcap.segmentation.errors import SegmentationInputError


def iou_per_class(
    pred: ArrayLike, gt: ArrayLike, classes: Iterable[Label] | None = None
) -> dict[Label, float]:
    """IoU of each class between two (H, W) label images.

    Parameters
    ----------
    pred, gt: (H, W) integer label ids.
    classes: classes to score; default every class present in ``gt`` or ``pred`` except UNKNOWN.

    Returns
    -------
    ``{label: |pred==c ∧ gt==c| / |pred==c ∨ gt==c|}``; classes absent from both are left out.
    Pixels whose ground truth is UNKNOWN (e.g. no surface) are ignored.
    """
    p = np.asarray(pred)
    g = np.asarray(gt)
    if p.shape != g.shape or p.ndim != 2:
        raise SegmentationInputError(
            f"pred {p.shape} and gt {g.shape} must be equal (H, W)", field="pred"
        )
    known = g != int(Label.UNKNOWN)
    p, g = p[known], g[known]
    if classes is None:
        present = set(np.unique(g).tolist()) | set(np.unique(p).tolist())
        classes = [Label(c) for c in sorted(present)
                   if c != int(Label.UNKNOWN) and c in Label._value2member_map_]
    out: dict[Label, float] = {}
    for c in classes:
        a, b = p == int(c), g == int(c)
        union = int((a | b).sum())
        if union:
            out[Label(c)] = float((a & b).sum()) / union
    return out
