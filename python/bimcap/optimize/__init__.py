"""Bundle adjustment against the BIM: problem arrays, options, problem files, the Ceres solve.

Typical use::

    from bimcap.optimize import Problem, SolverOptions, solve
    result = solve(Problem(poses=..., cameras=..., floor_frame=..., ...), SolverOptions.paper())
    result.poses, result.summary.to_json()

The compiled core (``bimcap._core``) is imported only when :func:`solve` runs.
"""

from __future__ import annotations

from bimcap.optimize.errors import SolverError, SolverInputError, SolverUnavailableError
from bimcap.optimize.options import (
    GeometricMode,
    LinearSolver,
    Loss,
    PlaneMode,
    Preset,
    RefineMode,
    SolverOptions,
    TermOptions,
    Weighting,
)
from bimcap.optimize.problem import Problem
from bimcap.optimize.problem_file import ProblemFileError, read_problem, write_problem
from bimcap.optimize.solve import SolveResult, solve
from bimcap.optimize.summary import SolveSummary, TermSummary

__all__ = [
    "GeometricMode",
    "LinearSolver",
    "Loss",
    "PlaneMode",
    "Preset",
    "Problem",
    "ProblemFileError",
    "RefineMode",
    "SolveResult",
    "SolveSummary",
    "SolverError",
    "SolverInputError",
    "SolverOptions",
    "SolverUnavailableError",
    "TermOptions",
    "TermSummary",
    "Weighting",
    "read_problem",
    "solve",
    "write_problem",
]
