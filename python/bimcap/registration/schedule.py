"""The refinement schedule that follows the coarse stage, as data the pipeline maps onto the
solver's options (``bimcap.optimize.SolverOptions``).

Issue 7 asks for: coarse → BIM terms only with large robust-loss scales → all terms, and the
option (motivated by the paper's Exp 3, where optimising rotation and translation together
invented 7 cm of translation) to refine rotation first and translation after. A
:class:`Schedule` is an ordered tuple of :class:`ScheduleStage`; each says which pose
parameters are free (the solver's :class:`~bimcap.optimize.RefineMode`), which cost terms are on
(term names of the solver's registry, ``bimcap.optimize.options.terms()``), how much to
widen the robust losses' scales, and an iteration cap. The pipeline runs the stages in order,
feeding each one's poses to the next; a stage of kind :attr:`StageKind.COARSE` means
:func:`bimcap.registration.coarse_register`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Any

from bimcap.optimize.options import RefineMode
from bimcap.optimize.options import terms as registry_terms
from bimcap.registration.errors import RegistrationInputError


class StageKind(str, Enum):
    """What a stage runs."""

    COARSE = "coarse"        #: :func:`bimcap.registration.coarse_register` (no solver)
    BIM_ONLY = "bim_only"    #: the solver with the BIM terms only (F, Ce, W, Co)
    ALL_TERMS = "all_terms"  #: the solver with every term (G as well)


#: The terms that tie poses to the BIM (the registry's ``bim_term``: F, Ce, W, Co).
BIM_TERMS: frozenset[str] = frozenset(t.name for t in registry_terms() if t.bim_term)
#: Every paper term (G, its landmark depth prior, F, Ce, W, Co).
ALL_TERMS: frozenset[str] = frozenset(t.name for t in registry_terms() if t.paper_term)


@dataclass(frozen=True)
class ScheduleStage:
    """One step of a schedule.

    Attributes
    ----------
    name: a label for logs and reports.
    kind: what runs.
    pose_block: free pose parameters (ignored for COARSE).
    terms: the names of the cost terms switched on (empty for COARSE).
    loss_scale_factor: multiplies every robust loss scale of the solver's robust mode (> 1
        widens the basin while far from the optimum; 1 = the configured scales).
    max_iterations: solver iteration cap for this stage (None = the solver's default).
    """

    name: str
    kind: StageKind
    pose_block: RefineMode = RefineMode.FULL
    terms: frozenset[str] = ALL_TERMS
    loss_scale_factor: float = 1.0
    max_iterations: int | None = None

    def __post_init__(self) -> None:
        if not self.loss_scale_factor > 0:
            raise RegistrationInputError("must be > 0", None, f"{self.name}.loss_scale_factor")
        if self.max_iterations is not None and self.max_iterations < 1:
            raise RegistrationInputError("must be >= 1", None, f"{self.name}.max_iterations")
        unknown = self.terms - ALL_TERMS
        if unknown:
            raise RegistrationInputError(f"unknown term(s) {sorted(unknown)}", None,
                                         f"{self.name}.terms")
        if self.kind is not StageKind.COARSE and not self.terms:
            raise RegistrationInputError("a solver stage needs at least one term", None,
                                         f"{self.name}.terms")
        if self.kind is StageKind.BIM_ONLY and not self.terms <= BIM_TERMS:
            raise RegistrationInputError("BIM_ONLY stages take only F, Ce, W, Co", None,
                                         f"{self.name}.terms")

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind.value,
                "pose_block": self.pose_block.value.lower(), "terms": sorted(self.terms),
                "loss_scale_factor": self.loss_scale_factor,
                "max_iterations": self.max_iterations}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ScheduleStage:
        try:
            return cls(str(d["name"]), StageKind(d["kind"]),
                       RefineMode(str(d.get("pose_block", "full")).upper()),
                       frozenset(str(t) for t in d.get("terms", sorted(ALL_TERMS))),
                       float(d.get("loss_scale_factor", 1.0)), d.get("max_iterations"))
        except (KeyError, ValueError) as exc:
            raise RegistrationInputError(f"bad schedule stage: {exc}", None, "schedule") from exc


@dataclass(frozen=True)
class Schedule:
    """An ordered list of stages (see the module docstring)."""

    stages: tuple[ScheduleStage, ...]

    def __post_init__(self) -> None:
        if not self.stages:
            raise RegistrationInputError("a schedule needs at least one stage", None, "stages")
        if any(s.kind is StageKind.COARSE for s in self.stages[1:]):
            raise RegistrationInputError("the coarse stage can only come first", None, "stages")

    @property
    def has_coarse(self) -> bool:
        return self.stages[0].kind is StageKind.COARSE

    @classmethod
    def default(cls, coarse: bool = True, rotation_first: bool = False, staged: bool = True,
                bim_loss_scale_factor: float = 4.0) -> Schedule:
        """The issue's schedule: [coarse →] [BIM terms with wide losses →] all terms.

        ``staged`` includes the BIM-only stage. With ``rotation_first`` the first solver stage
        is preceded by a ROTATION stage and a TRANSLATION stage with the same terms (the paper's
        Exp 3 motivation: rotations first, translations after), then solved in FULL; e.g.
        coarse, bim_rotation, bim_translation, bim, all. (Rotation then translation alone, with
        no joint stage after, leaves the rotations to absorb the translation drift: measured
        4.9° instead of 0.17° on the tiny demo world.)
        """
        stages: list[ScheduleStage] = []
        if coarse:
            stages.append(ScheduleStage("coarse", StageKind.COARSE, terms=frozenset()))
        solver = [("bim", StageKind.BIM_ONLY, BIM_TERMS, bim_loss_scale_factor)] if staged else []
        solver.append(("all", StageKind.ALL_TERMS, ALL_TERMS, 1.0))
        for k, (name, kind, terms, scale) in enumerate(solver):
            if rotation_first and k == 0:
                for b in (RefineMode.ROTATION, RefineMode.TRANSLATION):
                    stages.append(ScheduleStage(f"{name}_{b.value.lower()}", kind, b, terms, scale))
            stages.append(ScheduleStage(name, kind, RefineMode.FULL, terms, scale))
        return cls(tuple(stages))

    @classmethod
    def single(cls) -> Schedule:
        """No schedule: one solve with every term (the paper's BIMCaP)."""
        return cls((ScheduleStage("all", StageKind.ALL_TERMS),))

    def to_dict(self) -> dict[str, Any]:
        return {"stages": [s.to_dict() for s in self.stages]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Schedule:
        if not isinstance(d, dict) or not isinstance(d.get("stages"), list):
            raise RegistrationInputError("expected {'stages': [...]}", None, "schedule")
        return cls(tuple(ScheduleStage.from_dict(s) for s in d["stages"]))
