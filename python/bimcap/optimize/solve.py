"""``solve(problem, options)``: one call into the C++ Ceres core."""

from __future__ import annotations

import ctypes
import logging
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.optimize.core import core
from bimcap.optimize.errors import SolverError, SolverInputError
from bimcap.optimize.options import SolverOptions
from bimcap.optimize.problem import Problem
from bimcap.optimize.summary import SolveSummary

_log = logging.getLogger(__name__)


@dataclass
class SolveResult:
    """The refined state.

    Attributes
    ----------
    poses: (N, 7) refined world_from_cam, TUM order, unit quaternions.
    summary: what the solve did.
    planes: (Q, 4) the BIM planes as given; in FACaP plane mode (2, 4) the fitted floor and
        ceiling planes (a NaN row where a term had no points).
    track_points: (P, 3) refined landmarks (LANDMARK mode; else the input).
    segment_of: per segment term (its key: ``"wall"``, ``"column"``), each point's final
        segment, int32 (-1 = none); :attr:`wall_segment` and :attr:`column_segment` read it.
    covariance: (N, 6, 6) pose covariance in the tangent space [dt (m), dtheta (rad)], zero for
        fixed poses; None unless requested and computable.
    """

    poses: NDArray[np.float64]
    summary: SolveSummary
    planes: NDArray[np.float64]
    track_points: NDArray[np.float64]
    segment_of: dict[str, NDArray[np.int32]]
    covariance: NDArray[np.float64] | None = None

    @property
    def wall_segment(self) -> NDArray[np.int32]:
        """(W,) the wall points' final segments (-1 = none)."""
        return self.segment_of.get("wall", np.zeros(0, np.int32))

    @property
    def column_segment(self) -> NDArray[np.int32]:
        """(W',) the column points' final segments (-1 = none)."""
        return self.segment_of.get("column", np.zeros(0, np.int32))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the summary and the poses as lists."""
        return {"summary": self.summary.to_dict(), "poses": self.poses.tolist()}


def solve(problem: Problem, options: SolverOptions | None = None, *,
          check: bool = True) -> SolveResult:
    """Refine the poses of ``problem`` with Ceres.

    Parameters
    ----------
    problem: the arrays (validated on construction).
    options: how to solve; the defaults when None (ROBUST weighting, all terms on).
    check: raise :class:`SolverError` when the solve failed: Ceres reports an unusable solution,
        or the initial or final cost is not finite (termination ``NON_FINITE_COST``, the message
        names the term, the residual block and its frames); else only ``summary.success`` says so.

    With ``options.verbose`` Ceres writes its per-iteration progress and its full report; they go
    to stderr (the C++ side writes them to stdout, which this call points at stderr meanwhile),
    beside the log, so that stdout keeps a command's results. ``bimcap -v`` sets it.

    Raises
    ------
    SolverInputError: an array or option is malformed (names the field).
    SolverError: the solve failed and ``check`` is set.
    """
    opts = options if options is not None else SolverOptions()
    flat = opts.to_flat()
    _core = core()
    t0 = time.perf_counter()
    try:
        with _stdout_to_stderr(opts.verbose):
            out = _core.solve(problem.arrays(), flat)
    except _core.InputError as exc:
        field = getattr(exc, "field", "") or None
        message = str(exc)
        if field and message.startswith(f"{field}: "):
            message = message[len(field) + 2:]
        raise SolverInputError(message, field=field) from None
    summary = SolveSummary.from_dict(out["summary"])
    _log.debug(f"Ceres: {summary.termination}, {time.perf_counter() - t0:.2f} s")
    if check and not summary.success:
        raise SolverError(f"solve failed: {summary.termination}: {summary.message}")
    return SolveResult(
        poses=out["poses"],
        summary=summary,
        planes=out["planes"],
        track_points=out["track_points"],
        segment_of={k.removesuffix("_segment"): v.astype(np.int32)
                    for k, v in out.items() if k.endswith("_segment")},
        covariance=out["covariance"],
    )


@contextmanager
def _stdout_to_stderr(enabled: bool) -> Iterator[None]:
    """File descriptor 1 points at stderr while enabled (what C++ writes to ``std::cout``); the
    C and Python buffers are flushed on both sides so that nothing lands on the wrong one."""
    if not enabled:
        yield
        return
    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    sys.stderr.flush()
    libc.fflush(None)
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        libc.fflush(None)
        os.dup2(saved, 1)
        os.close(saved)
