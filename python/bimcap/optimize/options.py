"""Solver options: which terms, how they are weighted, how Ceres runs.

One implementation: the C++ core's (``cpp/bimcap/options.h`` and its term registry
``cpp/bimcap/terms.h``). Defaults, validation and the flat ``key=value`` form that a problem
file stores all come from ``bimcap._core``; this module is their typed Python view. Keys:
``geometric_mode``, ``weighting``, ``plane_mode``, ``refine_mode``, per term
``<key>.enabled|paper_weight|weight|sigma|loss|loss_scale`` and the term's own parameters
(``prior.sigma_r_deg``), then ``pixel_sigma``, ``association_gate``, ``outer_iterations``,
``association_change_tolerance``, ``round_function_tolerance``, ``max_iterations``,
``function_tolerance``, ``gradient_tolerance``, ``parameter_tolerance``, ``max_time_s``,
``num_threads``, ``batch_size``, ``compress_batches``, ``linear_solver``,
``compute_covariance``, ``verbose``; ``bimcap._core.option_specs()`` lists them with their kinds
and defaults.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from enum import Enum
from functools import cache
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


class Preset(str, Enum):
    """A named starting point of every option (the C++ ``SolverOptions::Preset``)."""

    #: what ``bimcap refine`` uses for BIMCaP: ROBUST weighting, G as the reprojection error
    #: (pixel_sigma 2 px, depth.sigma 2 cm), floor/ceiling sigma 5 cm, Cauchy on the paper's terms
    ROBUST = "robust"
    #: the peers' objective: PAPER weighting (λ · mean of squared residuals, plain L2), G as
    #: FACaP's point error; the noise scales and losses of ROBUST (used by diagnostics only)
    PAPER = "paper"


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


@dataclass(frozen=True)
class TermInfo:
    """One entry of the C++ term registry (``bimcap._core.terms()``)."""

    name: str  #: in summaries and term lists: "G", "F", "prior" ...
    key: str  #: option prefix and :class:`SolverOptions` attribute: "geometric", "floor" ...
    what: str  #: in messages
    doc: str  #: the residual and its unit
    paper_term: bool  #: one of the paper's terms (``with_terms``; PAPER weighting)
    bim_term: bool  #: ties poses to the BIM (the schedule's BIM-only stage)
    arrays: tuple[str, ...]  #: the problem arrays it reads
    params: dict[str, float]  #: its own parameters and their defaults


@cache
def terms() -> tuple[TermInfo, ...]:
    """The term registry of the C++ core, in summary order."""
    from bimcap.optimize.core import core

    _core = core()

    return tuple(
        TermInfo(t["name"], t["key"], t["what"], t["doc"], bool(t["paper_term"]),
                 bool(t["bim_term"]), tuple(t["arrays"]), dict(t["params"]))
        for t in _core.terms()
    )


def term_info(name_or_key: str) -> TermInfo:
    """The registry entry of a term, by name (``"F"``) or key (``"floor"``)."""
    for t in terms():
        if name_or_key in (t.name, t.key):
            return t
    known = ", ".join(t.name for t in terms())
    raise SolverInputError(f"unknown term {name_or_key!r} (known: {known})", field="terms")


@cache
def _defaults() -> dict[str, str]:
    from bimcap.optimize.core import core

    _core = core()

    return dict(_core.default_options())


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
    params: the term's own parameters (the registry's ``params``), e.g. the pose prior's
        rotation scale ``sigma_r_deg``.
    """

    enabled: bool = True
    paper_weight: float = 1.0
    weight: float = 1.0
    sigma: float = 0.05
    loss: Loss = Loss.HUBER
    loss_scale: float = 1.0
    params: dict[str, float] = field(default_factory=dict)

    @classmethod
    def default(cls, key: str) -> TermOptions:
        """Term ``key``'s defaults, from the C++ registry."""
        flat = _defaults()
        return cls(
            enabled=flat[f"{key}.enabled"] == "1",
            paper_weight=float(flat[f"{key}.paper_weight"]),
            weight=float(flat[f"{key}.weight"]),
            sigma=float(flat[f"{key}.sigma"]),
            loss=Loss(flat[f"{key}.loss"]),
            loss_scale=float(flat[f"{key}.loss_scale"]),
            params={p: float(flat[f"{key}.{p}"]) for p in term_info(key).params},
        )


def _default(key: str) -> Any:
    """A field whose default is the C++ default of global option ``key``, as its Python type."""
    return field(default_factory=lambda: _parse(_defaults()[key], _GLOBAL_TYPES[key]))


def _default_terms() -> dict[str, TermOptions]:
    return {t.key: TermOptions.default(t.key) for t in terms()}


@dataclass
class SolverOptions:
    """How to solve. Every default comes from the C++ core; :meth:`check` is the core's check.

    The terms are in :attr:`terms` by key, and read as attributes too: ``options.floor.sigma``.
    """

    geometric_mode: GeometricMode = _default("geometric_mode")
    weighting: Weighting = _default("weighting")
    plane_mode: PlaneMode = _default("plane_mode")
    refine_mode: RefineMode = _default("refine_mode")
    #: G's noise scale in pixels (REPROJECTION, LANDMARK).
    pixel_sigma: float = _default("pixel_sigma")
    #: W / Co: the largest xy distance (m) at which a point is associated with a segment.
    association_gate: float = _default("association_gate")
    #: W / Co: at most this many Ceres runs, re-associating in between.
    outer_iterations: int = _default("outer_iterations")
    #: W / Co: stop re-associating once at most this fraction of the points changed segment.
    association_change_tolerance: float = _default("association_change_tolerance")
    #: W / Co: Ceres' function tolerance in a round whose poses only seed the next association;
    #: the round on the settled association (or the last) runs to ``function_tolerance``.
    #: 0: ``function_tolerance`` in every round.
    round_function_tolerance: float = _default("round_function_tolerance")
    max_iterations: int = _default("max_iterations")
    function_tolerance: float = _default("function_tolerance")
    gradient_tolerance: float = _default("gradient_tolerance")
    parameter_tolerance: float = _default("parameter_tolerance")
    max_time_s: float = _default("max_time_s")
    num_threads: int = _default("num_threads")
    #: Observations of a term that share their poses per Ceres residual block, the term's loss
    #: applied to each (the same cost and gradient, less of Ceres' per-block work); 1: one
    #: block per observation with Ceres' loss.
    batch_size: int = _default("batch_size")
    #: A batch of more residuals than its poses' tangent size goes to Ceres as that many rows
    #: plus one, from its Gauss-Newton matrix and gradient (the same step to rounding, a
    #: fraction of Ceres' per-row work); False: one row per residual.
    compress_batches: bool = _default("compress_batches")
    linear_solver: LinearSolver = _default("linear_solver")
    #: Pose covariance (N, 6, 6) in the tangent space [dt, dtheta] via ceres::Covariance.
    compute_covariance: bool = _default("compute_covariance")
    verbose: bool = _default("verbose")
    #: Every term's options by key, in the registry's order: ``geometric``, ``depth``,
    #: ``floor``, ``ceiling``, ``wall``, ``column``, ``prior`` (pose prior, ROBUST only),
    #: ``odometry`` (ROBUST only).
    terms: dict[str, TermOptions] = field(default_factory=_default_terms)

    def __getattr__(self, name: str) -> TermOptions:
        # Called only for names that are not fields: the terms, by key.
        found = self.__dict__.get("terms", {}).get(name)
        if found is None:
            raise AttributeError(f"SolverOptions has no option or term {name!r}")
        return found  # type: ignore[no-any-return]

    def __setattr__(self, name: str, value: Any) -> None:
        # A misspelt or retired option (``prior_sigma_r_deg``) must not be set silently.
        if name not in _FIELD_NAMES:
            raise AttributeError(
                f"SolverOptions has no option {name!r} (a term's options: options.<key>.<name>, "
                "its own parameters: options.<key>.params[name])"
            )
        object.__setattr__(self, name, value)

    # ------------------------------------------------------------------ helpers
    @classmethod
    def preset(cls, name: Preset | str, **kwargs: Any) -> SolverOptions:
        """A named preset (:class:`Preset`) with some fields changed; an unknown name raises
        :class:`SolverInputError` naming ``preset``."""
        from bimcap.optimize.core import core

        try:
            flat = dict(core().preset_options(Preset(name).value))
        except ValueError:
            raise SolverInputError(
                f"unknown preset {name!r}; use {[p.value for p in Preset]}", field="preset"
            ) from None
        out = cls.from_flat(flat)
        for key, value in kwargs.items():
            setattr(out, key, value)
        return out

    @classmethod
    def paper(cls, **kwargs: Any) -> SolverOptions:
        """The peers' objective (:attr:`Preset.PAPER`): PAPER weighting, plain L2, λ = G 1,
        F/Ce 0.02, W/Co 0.0007, G as the point error."""
        return cls.preset(Preset.PAPER, **kwargs)

    def copy(self) -> SolverOptions:
        """A deep copy (the terms' options included)."""
        return replace(self, terms={k: replace(v, params=dict(v.params))
                                    for k, v in self.terms.items()})

    def with_terms(self, terms: str) -> SolverOptions:
        """A copy with exactly the listed paper terms on, e.g. ``"G+F+W"`` or ``"G,F,Ce,W,Co"``.

        ``depth`` follows G. Terms that are not the paper's (the pose prior, the odometry) keep
        their settings.
        """
        paper = [t for t in _registry() if t.paper_term]
        wanted = {t.strip() for t in terms.replace("+", ",").split(",") if t.strip()}
        unknown = wanted - {t.name for t in paper}
        if unknown:
            raise SolverInputError(
                f"unknown term(s) {sorted(unknown)}; use {sorted(t.name for t in paper)}",
                field="terms",
            )
        out = self.copy()
        for t in paper:
            on = t.name in wanted or (t.name == "depth" and "G" in wanted)
            out.terms[t.key].enabled = on
        return out

    def term(self, name: str) -> TermOptions:
        """A term's options by name (``"G"``, ``"F"``, ``"prior"`` ...) or key (``"floor"``)."""
        return self.terms[term_info(name).key]

    # --------------------------------------------------------------- validation
    def check(self) -> None:
        """Raise :class:`SolverInputError` naming the option if a value is out of range: the C++
        core's ``SolverOptions::Check``."""
        _core_check(self._flat())

    # ------------------------------------------------------------ serialisation
    def _flat(self) -> dict[str, str]:
        out = {f.name: _to_text(getattr(self, f.name)) for f in fields(self) if f.name != "terms"}
        for key, t in self.terms.items():
            for name in _TERM_TYPES:
                out[f"{key}.{name}"] = _to_text(getattr(t, name))
            out.update({f"{key}.{p}": _to_text(float(v)) for p, v in t.params.items()})
        return out

    def to_flat(self) -> dict[str, str]:
        """The flat ``key → str`` form the C++ core and problem files use (checked)."""
        return _core_check(self._flat())

    @classmethod
    def from_flat(cls, flat: dict[str, str]) -> SolverOptions:
        """Inverse of :meth:`to_flat`, through the C++ parser: unknown keys and bad values raise
        SolverInputError naming the key; keys renamed since a file was written are still read."""
        out = cls()
        for key, text in _core_check(dict(flat)).items():
            head, _, sub = key.partition(".")
            if not sub:
                setattr(out, key, _parse(text, _GLOBAL_TYPES[key]))
            elif sub in _TERM_TYPES:
                setattr(out.terms[head], sub, _parse(text, _TERM_TYPES[sub]))
            else:
                out.terms[head].params[sub] = float(text)
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready nested dict (enums as their names; each term under its key)."""
        out = {f.name: _plain(getattr(self, f.name)) for f in fields(self) if f.name != "terms"}
        for key, t in self.terms.items():
            out[key] = {tf.name: _plain(getattr(t, tf.name)) for tf in fields(t)}
        return out


_FIELD_NAMES = frozenset(f.name for f in fields(SolverOptions))


def _registry() -> tuple[TermInfo, ...]:
    return terms()


def _core_check(flat: dict[str, str]) -> dict[str, str]:
    """The C++ check and normalisation of flat options; an error names the key."""
    from bimcap.optimize.core import core

    _core = core()

    try:
        return dict(_core.check_options(flat))
    except ValueError as exc:
        key = getattr(exc, "field", "") or None
        message = str(exc)
        if key and message.startswith(f"{key}: "):
            message = message[len(key) + 2:]
        raise SolverInputError(message, field=key) from None


_GLOBAL_TYPES: dict[str, type] = {
    "geometric_mode": GeometricMode,
    "weighting": Weighting,
    "plane_mode": PlaneMode,
    "refine_mode": RefineMode,
    "pixel_sigma": float,
    "association_gate": float,
    "outer_iterations": int,
    "association_change_tolerance": float,
    "round_function_tolerance": float,
    "max_iterations": int,
    "function_tolerance": float,
    "gradient_tolerance": float,
    "parameter_tolerance": float,
    "max_time_s": float,
    "num_threads": int,
    "batch_size": int,
    "compress_batches": bool,
    "linear_solver": LinearSolver,
    "compute_covariance": bool,
    "verbose": bool,
}
_TERM_TYPES: dict[str, type] = {
    "enabled": bool,
    "paper_weight": float,
    "weight": float,
    "sigma": float,
    "loss": Loss,
    "loss_scale": float,
}


def _parse(text: str, kind: type) -> Any:
    """A value of the flat form as its Python type."""
    if kind is bool:
        return text in ("1", "true", "True")
    if kind is int:
        return int(text)
    if kind is float:
        return float(text)
    return kind(text)  # an Enum


def _plain(value: Any) -> Any:
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, dict):
        return dict(value)
    return value


def _to_text(value: Any) -> str:
    if isinstance(value, Enum):
        return str(value.value)
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return repr(value)
    return str(value)
