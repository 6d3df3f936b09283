"""Score a deviation report against known deviations (the simulator's truth sidecar).

The truth is passed as plain mappings by element ``Name`` (the generator's ids:
``bimcap.sim.building_truth.Deviations.wall_shifts`` / ``column_offsets`` / ``missing``), so
that this stage does not depend on the simulator. Definitions (``tol`` = the report's tolerance):

* **observed**: status ``ok``, ``deviating`` or ``missing`` (not ``unobserved``);
* **recall ≥ 3 cm**: of the observed walls and columns whose applied shift is ≥ ``recall_min_m``
  (3 cm), the share reported ``deviating``;
* **false alarms**: observed elements flagged ``deviating`` or ``missing`` although present and
  shifted by less than ``tol`` (slabs and coverings count as unshifted), as a share of the
  observed elements; elements shifted between ``tol`` and 3 cm count neither way;
* **missing**: the missing walls and columns the walk looks at (at least ``min_rays`` of its rays
  reach them in the model), and the share of them reported ``missing``; ``false_missing``
  counts elements reported ``missing`` that are present;
* **offset RMSE**: over walls and columns with an offset, ``offset_m`` − the applied shift (walls,
  along the same normal) or the length of ``offset_xy_m`` − the applied ``(dx, dy)`` (columns).

Elements named in ``exclude`` (e.g. a datum: declared as built right, so not judged) are left out
of every count.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass

import numpy as np

from bimcap.deviations.analysis import DeviationReport, ElementStatus


@dataclass
class DeviationScore:
    """Counts and rates of one report against the truth (see the module doc)."""

    elements: int
    observed: int
    shifted: int
    detected: int
    false_alarms: int
    missing_seen: int
    missing_found: int
    false_missing: int
    offset_errors_m: list[float]

    @property
    def recall(self) -> float:
        return self.detected / self.shifted if self.shifted else float("nan")

    @property
    def false_alarm_rate(self) -> float:
        return self.false_alarms / self.observed if self.observed else float("nan")

    @property
    def missing_recall(self) -> float:
        return self.missing_found / self.missing_seen if self.missing_seen else float("nan")

    @property
    def offset_rmse_m(self) -> float:
        e = np.asarray(self.offset_errors_m)
        return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")

    def to_dict(self) -> dict[str, object]:
        d: dict[str, object] = asdict(self)
        d.update(recall=self.recall, false_alarm_rate=self.false_alarm_rate,
                 missing_recall=self.missing_recall, offset_rmse_m=self.offset_rmse_m)
        return d


def score_deviations(report: DeviationReport, wall_shifts: Mapping[str, float],
                     column_offsets: Mapping[str, tuple[float, float]],
                     missing: Iterable[str], recall_min_m: float = 0.03,
                     exclude: Iterable[str] = ()) -> DeviationScore:
    """Score ``report`` against the applied deviations (by element name; see the module doc),
    leaving out the elements named in ``exclude``."""
    tol = report.options.tolerance_m
    gone = set(missing)
    skip = set(exclude)
    observed = shifted = detected = false_alarms = 0
    missing_seen = missing_found = false_missing = 0
    errors: list[float] = []
    n_elements = 0
    for e in report.elements:
        if e.name in skip:
            continue
        n_elements += 1
        flagged = e.status in (ElementStatus.DEVIATING, ElementStatus.MISSING)
        if e.name in gone:
            if e.rays >= report.options.min_rays:
                missing_seen += 1
                missing_found += e.status is ElementStatus.MISSING
            if e.status is not ElementStatus.UNOBSERVED:
                observed += 1
            continue
        if e.status is ElementStatus.MISSING:
            false_missing += 1
        if e.status is ElementStatus.UNOBSERVED:
            continue
        observed += 1
        if e.name in wall_shifts:
            true_size = abs(wall_shifts[e.name])
            if e.offset_m is not None:
                errors.append(e.offset_m - wall_shifts[e.name])
        elif e.name in column_offsets:
            dx, dy = column_offsets[e.name]
            true_size = float(np.hypot(dx, dy))
            if e.offset_xy_m is not None:
                errors.append(float(np.hypot(e.offset_xy_m[0] - dx, e.offset_xy_m[1] - dy)))
        else:
            true_size = 0.0
        if true_size >= recall_min_m:
            shifted += 1
            detected += e.status is ElementStatus.DEVIATING
        elif true_size < tol and flagged:
            false_alarms += 1
    return DeviationScore(n_elements, observed, shifted, detected, false_alarms,
                          missing_seen, missing_found, false_missing, errors)
