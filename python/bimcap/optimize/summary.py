"""The solve summary: costs per term before and after, counts, iterations, time, termination.

The same JSON comes from ``bimcap_solve`` (``summary.json``) and from :func:`bimcap.optimize.solve`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from typing import Any


@dataclass
class TermSummary:
    """One term (``G``, ``depth``, ``F``, ``Ce``, ``W``, ``Co``, then the pose prior ``prior`` and
    the ``odometry``).

    Costs are Ceres costs (½ Σ ρ(‖s r‖²)); rms values are of the raw residuals in the term's unit
    (m, or px for reprojection / landmark G; the prior's and odometry's are whitened, in sigmas);
    ``*_paper_objective`` is λ · mean ‖r‖², the term's share of the peers' objective (always 0
    for the prior).
    """

    name: str
    active: bool = False
    num_residual_blocks: int = 0
    num_residuals: int = 0
    num_skipped: int = 0
    sqrt_weight: float = 0.0
    paper_weight: float = 0.0
    initial_cost: float = 0.0
    final_cost: float = 0.0
    initial_rms: float = 0.0
    final_rms: float = 0.0
    initial_paper_objective: float = 0.0
    final_paper_objective: float = 0.0


@dataclass
class AssociationStats:
    num_points: int = 0
    num_associated: int = 0
    num_rejected: int = 0  #: no same-class segment within the gate and z range
    num_changed: int = 0
    mean_distance: float = 0.0  #: metres, over associated points


@dataclass
class AssociationSummary:
    name: str  #: "W" or "Co"
    num_segments: int = 0
    initial: AssociationStats = field(default_factory=AssociationStats)
    final: AssociationStats = field(default_factory=AssociationStats)


@dataclass
class SolveSummary:
    """What one solve did. ``success`` is False when Ceres reported an unusable solution."""

    success: bool = False
    termination: str = ""
    message: str = ""
    linear_solver: str = ""
    iterations: int = 0
    outer_iterations: int = 0
    time_s: float = 0.0
    ceres_time_s: float = 0.0
    initial_cost: float = 0.0
    final_cost: float = 0.0
    initial_paper_objective: float = 0.0
    final_paper_objective: float = 0.0
    num_poses: int = 0
    num_free_poses: int = 0
    num_residual_blocks: int = 0
    num_residuals: int = 0
    terms: list[TermSummary] = field(default_factory=list)
    association: list[AssociationSummary] = field(default_factory=list)
    covariance_requested: bool = False
    covariance_ok: bool = False
    covariance_message: str = ""

    def term(self, name: str) -> TermSummary:
        """The summary of term ``name``."""
        for t in self.terms:
            if t.name == name:
                return t
        raise KeyError(name)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SolveSummary:
        known = {f.name for f in fields(cls)}
        kw = {k: v for k, v in d.items() if k in known and k not in ("terms", "association")}
        # JSON null (a non-finite number) comes back as NaN.
        kw = {k: (float("nan") if v is None else v) for k, v in kw.items()}
        terms = [TermSummary(**_nan(t)) for t in d.get("terms", [])]
        assoc = [
            AssociationSummary(
                name=a["name"],
                num_segments=a["num_segments"],
                initial=AssociationStats(**_nan(a["initial"])),
                final=AssociationStats(**_nan(a["final"])),
            )
            for a in d.get("association", [])
        ]
        return cls(**kw, terms=terms, association=assoc)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def to_json(self) -> str:
        """JSON text (NaN written as null)."""
        return json.dumps(_null(self.to_dict()), indent=2, allow_nan=False)

    def table(self) -> str:
        """A small text table of the terms, for the CLI."""
        lines = [f"{'term':6} {'n':>9} {'rms before':>12} {'rms after':>12} "
                 f"{'cost before':>12} {'cost after':>12}"]
        for t in self.terms:
            if t.active:
                lines.append(
                    f"{t.name:6} {t.num_residual_blocks:9d} {t.initial_rms:12.5g} "
                    f"{t.final_rms:12.5g} {t.initial_cost:12.5g} {t.final_cost:12.5g}"
                )
        lines.append(
            f"{self.termination}: {self.iterations} iterations, {self.outer_iterations} rounds, "
            f"{self.time_s:.3f} s, cost {self.initial_cost:.6g} -> {self.final_cost:.6g}"
        )
        return "\n".join(lines)


def _nan(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (float("nan") if v is None else v) for k, v in d.items()}


def _null(obj: Any) -> Any:
    if isinstance(obj, float) and obj != obj:
        return None
    if isinstance(obj, dict):
        return {k: _null(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_null(v) for v in obj]
    return obj
