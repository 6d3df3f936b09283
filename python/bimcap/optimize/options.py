"""Solver options: which terms, how they are weighted, how Ceres runs.

The options cross into C++ as a flat ``{key: str}`` dict (:meth:`SolverOptions.to_flat`), the same
``key=value`` text that a problem file stores. Keys: ``geometric_mode``, ``weighting``,
``plane_mode``, ``refine_mode``, per term ``<term>.enabled|paper_weight|weight|sigma|loss|
loss_scale`` with ``<term>`` in ``geometric, depth, floor, ceiling, wall, column, prior,
odometry``, then ``prior_sigma_r_deg``, ``odometry_sigma_r_deg``, ``pixel_sigma``, ``association_gate``, ``outer_iterations``, ``association_change_tolerance``, ``max_iterations``,
``function_tolerance``, ``gradient_tolerance``, ``parameter_tolerance``, ``max_time_s``,
``num_threads``, ``linear_solver``, ``compute_covariance``, ``verbose``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from enum import Enum
from typing import Any

from bimcap.optimize.errors import SolverInputError


class GeometricMode(str, Enum):
    """The G term's residual."""

    POINT = "POINT"  #: FACaP point error: two back-projected points must coincide (3, metres)
    REPROJECTION = "REPROJECTION"  #: back-project in a, project into b (2, pixels)
    LANDMARK = "LANDMARK"  #: bundle adjustment with one point per track (2, pixels) + depth prior


class Weighting(str, Enum):
    """How the terms are weighted."""

    PAPER = "PAPER"  #: the peers' objective: Σ λ · mean ‖r‖², plain L2
    ROBUST = "ROBUST"  #: whitened by sigma, times weight, under a robust loss per term


class Loss(str, Enum):
    NONE = "NONE"
    HUBER = "HUBER"
    CAUCHY = "CAUCHY"
    SOFT_L1 = "SOFT_L1"
    ARCTAN = "ARCTAN"
    TUKEY = "TUKEY"


class PlaneMode(str, Enum):
    BIM = "BIM"  #: floor / ceiling points against the fixed BIM planes
    FACAP = "FACAP"  #: one free plane per term, fitted to the scan (flatness only)


class RefineMode(str, Enum):
    FULL = "FULL"
    ROTATION = "ROTATION"  #: translations held, rotations refined
    TRANSLATION = "TRANSLATION"  #: rotations held, translations refined


class LinearSolver(str, Enum):
    AUTO = "AUTO"  #: SPARSE_SCHUR with landmarks, else SPARSE_NORMAL_CHOLESKY
    DENSE_QR = "DENSE_QR"
    DENSE_NORMAL_CHOLESKY = "DENSE_NORMAL_CHOLESKY"
    SPARSE_NORMAL_CHOLESKY = "SPARSE_NORMAL_CHOLESKY"
    DENSE_SCHUR = "DENSE_SCHUR"
    SPARSE_SCHUR = "SPARSE_SCHUR"
    ITERATIVE_SCHUR = "ITERATIVE_SCHUR"


@dataclass
class TermOptions:
    """Options of one term.

    Attributes
    ----------
    enabled: switch the term on or off (the paper's ablations).
    paper_weight: λ of the term's mean in PAPER weighting (G 1, F/Ce 0.02, W/Co 0.0007); also
        used for the ``paper_objective`` the summary reports in every mode.
    weight: multiplier of the whitened squared residual in ROBUST weighting.
    sigma: noise scale in ROBUST weighting, in the residual's unit (metres; for G in
        REPROJECTION / LANDMARK mode ``SolverOptions.pixel_sigma`` is used instead).
    loss: robust loss in ROBUST weighting (PAPER is always plain L2).
    loss_scale: the loss's scale, in sigmas.
    """

    enabled: bool = True
    paper_weight: float = 1.0
    weight: float = 1.0
    sigma: float = 0.05
    loss: Loss = Loss.HUBER
    loss_scale: float = 1.0


#: Term names of the paper, mapped to the option attribute.
TERM_ATTRIBUTES: dict[str, str] = {
    "G": "geometric",
    "depth": "depth",
    "F": "floor",
    "Ce": "ceiling",
    "W": "wall",
    "Co": "column",
}
#: The pose prior's name (in the summary) and option attribute: not one of the paper's terms, so
#: :meth:`SolverOptions.with_terms` leaves it as it is.
PRIOR_TERM = "prior"
#: The odometry's name and option attribute: not a paper term either.
ODOMETRY_TERM = "odometry"
#: Every attribute that holds a :class:`TermOptions`.
_TERM_OPTION_ATTRIBUTES: tuple[str, ...] = (*TERM_ATTRIBUTES.values(), PRIOR_TERM, ODOMETRY_TERM)


@dataclass
class SolverOptions:
    """How to solve. Validated by :meth:`check` (and again by the C++ core)."""

    geometric_mode: GeometricMode = GeometricMode.POINT
    weighting: Weighting = Weighting.ROBUST
    plane_mode: PlaneMode = PlaneMode.BIM
    refine_mode: RefineMode = RefineMode.FULL
    geometric: TermOptions = field(default_factory=lambda: TermOptions(True, 1.0, 1.0, 0.05))
    depth: TermOptions = field(default_factory=lambda: TermOptions(True, 1.0, 1.0, 0.05))
    floor: TermOptions = field(default_factory=lambda: TermOptions(True, 0.02, 1.0, 0.02))
    ceiling: TermOptions = field(default_factory=lambda: TermOptions(True, 0.02, 1.0, 0.02))
    wall: TermOptions = field(default_factory=lambda: TermOptions(True, 0.0007, 1.0, 0.05))
    column: TermOptions = field(default_factory=lambda: TermOptions(True, 0.0007, 1.0, 0.05))
    #: Pose prior (ROBUST weighting only; never added in PAPER weighting): each free pose held
    #: near its initial value by r = [(t - t0) / sigma ; 2 vec(q0^-1 q) / prior_sigma_r_deg (rad)],
    #: plain L2. ``sigma`` is the translation scale (m); ``paper_weight`` must stay 0. It anchors
    #: the degrees of freedom the enabled terms leave unobserved (e.g. x, y, yaw under F alone).
    prior: TermOptions = field(
        default_factory=lambda: TermOptions(True, 0.0, 1.0, 2.0, Loss.NONE, 1.0)
    )
    #: The pose prior's rotation scale, degrees.
    prior_sigma_r_deg: float = 20.0
    #: Odometry (ROBUST weighting only, like the prior): each pair of consecutive frames keeps the
    #: input's relative motion, r = [(t_ab - t_ab0) / sigma (m, in frame a) ;
    #: 2 vec(q_ab0^-1 q_ab) / odometry_sigma_r_deg (rad)], plain L2. A frame that neither the BIM
    #: nor G can place follows its neighbours instead of staying where the drift put it.
    odometry: TermOptions = field(
        default_factory=lambda: TermOptions(True, 0.0, 1.0, 0.3, Loss.NONE, 1.0)
    )
    #: The odometry's rotation scale, degrees.
    odometry_sigma_r_deg: float = 15.0
    #: G's noise scale in pixels (REPROJECTION, LANDMARK).
    pixel_sigma: float = 1.0
    #: W / Co: the largest xy distance (m) at which a point is associated with a segment.
    association_gate: float = 0.5
    #: W / Co: at most this many Ceres runs, re-associating in between.
    outer_iterations: int = 5
    #: W / Co: stop re-associating once at most this fraction of the points changed segment.
    association_change_tolerance: float = 1e-3
    max_iterations: int = 100
    function_tolerance: float = 1e-6
    gradient_tolerance: float = 1e-10
    parameter_tolerance: float = 1e-8
    max_time_s: float = 1e6
    num_threads: int = 2
    linear_solver: LinearSolver = LinearSolver.AUTO
    #: Pose covariance (N, 6, 6) in the tangent space [dt, dtheta] via ceres::Covariance.
    compute_covariance: bool = False
    verbose: bool = False

    # ------------------------------------------------------------------ helpers
    @classmethod
    def paper(cls, **kwargs: Any) -> SolverOptions:
        """The peers' objective: PAPER weighting, plain L2, λ = G 1, F/Ce 0.02, W/Co 0.0007."""
        return cls(weighting=Weighting.PAPER, **kwargs)

    def with_terms(self, terms: str) -> SolverOptions:
        """A copy with exactly the listed terms on, e.g. ``"G+F+W"`` or ``"G,F,Ce,W,Co"``.

        ``depth`` follows G. The pose prior (``prior``) and the odometry are not paper terms and
        keep their settings.
        """
        wanted = {t.strip() for t in terms.replace("+", ",").split(",") if t.strip()}
        unknown = wanted - set(TERM_ATTRIBUTES)
        if unknown:
            raise SolverInputError(
                f"unknown term(s) {sorted(unknown)}; use {sorted(TERM_ATTRIBUTES)}", field="terms"
            )
        out = replace(self)
        for name, attr in TERM_ATTRIBUTES.items():
            on = name in wanted or (name == "depth" and "G" in wanted)
            setattr(out, attr, replace(getattr(self, attr), enabled=on))
        return out

    def term(self, name: str) -> TermOptions:
        """The options of term ``name`` (``"G"``, ``"F"`` ..., ``"prior"`` or ``"odometry"``)."""
        if name == PRIOR_TERM:
            return self.prior
        if name == ODOMETRY_TERM:
            return self.odometry
        options: TermOptions = getattr(self, TERM_ATTRIBUTES[name])
        return options

    # --------------------------------------------------------------- validation
    def check(self) -> None:
        """Raise :class:`SolverInputError` naming the option if a value is out of range."""

        def positive(name: str, v: float) -> None:
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise SolverInputError(f"must be a finite number > 0, got {v!r}", field=name)

        def non_negative(name: str, v: float) -> None:
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SolverInputError(f"must be a finite number >= 0, got {v!r}", field=name)

        for attr in _TERM_OPTION_ATTRIBUTES:
            t = getattr(self, attr)
            non_negative(f"{attr}.paper_weight", t.paper_weight)
            non_negative(f"{attr}.weight", t.weight)
            positive(f"{attr}.sigma", t.sigma)
            positive(f"{attr}.loss_scale", t.loss_scale)
            if not isinstance(t.loss, Loss):
                try:
                    t.loss = Loss(t.loss)
                except ValueError:
                    raise SolverInputError(f"unknown loss {t.loss!r}", field=f"{attr}.loss") from None
        if self.prior.paper_weight != 0:
            raise SolverInputError(
                "must be 0: the pose prior is not part of the paper's objective",
                field="prior.paper_weight",
            )
        positive("prior_sigma_r_deg", self.prior_sigma_r_deg)
        if self.odometry.paper_weight != 0:
            raise SolverInputError(
                "must be 0: the odometry is not part of the paper's objective",
                field="odometry.paper_weight",
            )
        positive("odometry_sigma_r_deg", self.odometry_sigma_r_deg)
        positive("pixel_sigma", self.pixel_sigma)
        positive("association_gate", self.association_gate)
        positive("max_time_s", self.max_time_s)
        non_negative("association_change_tolerance", self.association_change_tolerance)
        for name in ("function_tolerance", "gradient_tolerance", "parameter_tolerance"):
            non_negative(name, getattr(self, name))
        if int(self.outer_iterations) < 1:
            raise SolverInputError("must be >= 1", field="outer_iterations")
        if int(self.max_iterations) < 0:
            raise SolverInputError("must be >= 0", field="max_iterations")
        if int(self.num_threads) < 1:
            raise SolverInputError("must be >= 1", field="num_threads")

    # ------------------------------------------------------------ serialisation
    def to_flat(self) -> dict[str, str]:
        """The flat ``key → str`` form the C++ core and problem files use."""
        self.check()
        out: dict[str, str] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, TermOptions):
                for tf in fields(value):
                    out[f"{f.name}.{tf.name}"] = _to_text(getattr(value, tf.name))
            else:
                out[f.name] = _to_text(value)
        return out

    @classmethod
    def from_flat(cls, flat: dict[str, str]) -> SolverOptions:
        """Inverse of :meth:`to_flat`; unknown keys and bad values raise SolverInputError."""
        out = cls()
        for key, text in flat.items():
            head, _, sub = key.partition(".")
            target: Any = out
            name = head
            if sub:
                if head not in _TERM_OPTION_ATTRIBUTES:
                    raise SolverInputError("unknown option", field=key)
                target, name = getattr(out, head), sub
            known = {f.name: f for f in fields(target)}
            if name not in known or isinstance(getattr(target, name), TermOptions):
                raise SolverInputError("unknown option", field=key)
            current = getattr(target, name)
            try:
                setattr(target, name, _from_text(text, current))
            except ValueError as exc:
                raise SolverInputError(f"bad value {text!r}: {exc}", field=key) from None
        out.check()
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready nested dict (enums as their names)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, TermOptions):
                out[f.name] = {tf.name: _plain(getattr(value, tf.name)) for tf in fields(value)}
            else:
                out[f.name] = _plain(value)
        return out


def _plain(value: Any) -> Any:
    return value.value if isinstance(value, Enum) else value


def _to_text(value: Any) -> str:
    if isinstance(value, Enum):
        return str(value.value)
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _from_text(text: str, current: Any) -> Any:
    if isinstance(current, Enum):
        return type(current)(text)
    if isinstance(current, bool):
        if text in ("1", "true", "True"):
            return True
        if text in ("0", "false", "False"):
            return False
        raise ValueError("expected 0 or 1")
    if isinstance(current, int):
        return int(text)
    return float(text)
