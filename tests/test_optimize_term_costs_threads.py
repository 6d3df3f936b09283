"""The solve's per-term costs do not depend on its number of threads: each observation's squared
residual and loss are summed in one order whatever the split (``EvaluateTerms`` in
``cpp/bimcap/solver.cc``), so a summary written on a 2-core box reads the same on a 16-core one."""

from __future__ import annotations

from dataclasses import replace

from bimcap.optimize import SolverOptions, solve
from bimcap.optimize.synthetic import make_synthetic_problem


def test_term_costs_the_same_bits_with_any_number_of_threads() -> None:
    # More than 2 × 10,000 matches: EvaluateTerms splits a term only above 10,000 observations
    # a thread.
    s = make_synthetic_problem(num_frames=60, seed=3, matches_per_pair=400)
    base = SolverOptions(max_iterations=2)
    runs = [solve(s.problem, replace(base, num_threads=n), check=False) for n in (1, 2, 5)]
    g = next(t for t in runs[0].summary.terms if t.name == "G")
    assert g.num_residual_blocks > 20_000
    for r in runs[1:]:
        assert r.summary.initial_cost == runs[0].summary.initial_cost
        for a, b in zip(runs[0].summary.terms, r.summary.terms, strict=True):
            assert (a.name, a.initial_cost, a.initial_rms) == (b.name, b.initial_cost,
                                                                b.initial_rms)
