"""Write the seed corpus of the problem-file fuzzer (cpp/fuzz/corpus/): a few small, valid problem
files written by bimcap.optimize.write_problem. Run from the repository root after changing the
file format (the corpus is committed; scripts/fuzz.sh and tests/test_reliability_fuzz.py use it):

    PYTHONPATH=python python cpp/fuzz/make_corpus.py
"""

from __future__ import annotations

from pathlib import Path

from bimcap.optimize import Problem, SolverOptions, write_problem
from bimcap.optimize.options import GeometricMode
from bimcap.optimize.synthetic import make_synthetic_problem

CORPUS = Path(__file__).resolve().parent / "corpus"
SMALL = dict(num_frames=3, matches_per_pair=4, pair_offsets=(1,), landmarks_per_frame=3,
             floor_per_frame=4, ceiling_per_frame=3, wall_per_frame=6, column_per_frame=2, seed=7)


def main() -> None:
    CORPUS.mkdir(parents=True, exist_ok=True)
    problem = make_synthetic_problem(**SMALL).problem
    arrays = problem.arrays()
    write_problem(CORPUS / "all_terms_robust.bcp", problem, SolverOptions(max_iterations=5))
    write_problem(CORPUS / "all_terms_paper.bcp", problem, SolverOptions.paper(max_iterations=5))
    landmark = SolverOptions(max_iterations=5)
    landmark.geometric_mode = GeometricMode.LANDMARK
    write_problem(CORPUS / "landmarks.bcp", problem, landmark)
    required = {k: arrays[k] for k in ("poses", "timestamps", "pose_fixed", "cameras",
                                       "frame_camera")}
    write_problem(CORPUS / "required_only.bcp", Problem.from_arrays(required), SolverOptions())
    for p in sorted(CORPUS.glob("*.bcp")):
        print(f"{p}: {p.stat().st_size} bytes")


if __name__ == "__main__":
    main()
