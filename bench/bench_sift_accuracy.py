"""What a SIFT setting does to accuracy: BIMCaP on worlds of the generalization matrix with only
the ``[features]`` table (``bimcap.features.SiftOptions`` fields) changed.

Per world (built by ``bench_generalization.make_world`` into ``--work``, reused) and per run (the
fixed point from the ground truth, the paper's Exp. 1/2/3 drifts, seed = world seed + 1), the
default ``bimcap refine`` configuration with each variant's ``[features]`` table; prints
ATE_pos / ATE_rot and the front end's wall time. Compare with ``docs/generalization.csv`` (the
defaults of the day it was made).

    PYTHONPATH=python python bench/bench_sift_accuracy.py --work /tmp/gen \\
        --worlds gen-demo-s11,gen-small-s3 --variants octave-1,octave0
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_generalization import _row, world_runs

VARIANTS = {
    "default": {},
    "octave-1": {"first_octave": -1},
    "octave0": {"first_octave": 0},
    "opencv": {"backend": "opencv"},
    "opencv2k": {"backend": "opencv", "max_num_features": 2048},
}


def main() -> None:
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import prepare, solve_prepared

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/bimcap_generalization", help="worlds and caches")
    ap.add_argument("--worlds", default="gen-demo-s11,gen-small-s3", help="comma list")
    ap.add_argument("--variants", default="octave-1,octave0",
                    help=f"comma list of {', '.join(VARIANTS)}")
    ap.add_argument("--runs", default="fixed,exp1,exp2,exp3", help="comma list")
    ap.add_argument("--workers", type=int, default=None, help="front-end processes")
    args = ap.parse_args()
    work = Path(args.work)
    print("| world | variant | run | ATE_pos cm | ATE_rot ° | front end s |")
    print("|---|---|---|---|---|---|")
    for world in args.worlds.split(","):
        seq, reference, inits = world_runs(work, world)
        gt = inits["fixed"]
        for variant in args.variants.split(","):
            cfg = RefineConfig(workers=args.workers, features=VARIANTS[variant])
            for name in args.runs.split(","):
                t0 = time.perf_counter()
                prep = prepare(seq, reference, inits[name], cfg,
                               work / world / f"run_60_standard_sift_{variant}", quiet=True)
                t_fe = time.perf_counter() - t0
                out = solve_prepared(prep, cfg, quiet=True)
                row = _row(world, 60, "standard", name, "bimcap", inits[name], gt, out,
                           prep.frontend)
                print(f"| {world} | {variant} | {name} | {row['pos_m'] * 100:.2f} | "
                      f"{row['rot_deg']:.3f} | {t_fe:.1f} |", flush=True)


if __name__ == "__main__":
    main()
