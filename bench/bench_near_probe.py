"""The coarse stage's near probe: does it hand back only what the full pass hands back, and how
fast is a hand-back?

Per world of ``bench_generalization.py`` (built there, reused here) and per run (the fixed point
from the ground truth, the paper's Exp. 1/2/3 drifts), on the front end of the default ``bimcap
refine``:

* stage 0's tracked drift over every frame (the full pass) and over ``near_probe_frames`` evenly
  spaced frames (the probe), with the CPU seconds of each;
* the decision: the probe hands back when it reads less than ``near_probe_m``; a hand-back is
  *wrong* if the full pass reads ``frame_gate_m`` or more (it would have moved the poses);
* for the runs handed back, the whole ``coarse_register`` call with the probe off and on.

Goals (issue "Fast enough for real sequences"): a hand-back under 1 s; wrong hand-backs: 0.

    PYTHONPATH=python python bench/bench_near_probe.py --work /tmp/gen \\
        --worlds gen-demo-s0,gen-demo-s11,ifc-SampleHouse4
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_generalization import DEFAULT_WORLDS, world_runs


def _cpu(fn, *args, **kwargs):
    t = time.process_time()
    out = fn(*args, **kwargs)
    return out, time.process_time() - t


def main() -> None:
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import prepare
    from bimcap.registration import CoarseOptions, FloorPlan, SemanticSamples, coarse_register
    from bimcap.registration import coarse as stages

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/bimcap_generalization", help="worlds and caches")
    ap.add_argument("--worlds", default="gen-demo-s0," + DEFAULT_WORLDS, help="comma list")
    args = ap.parse_args()
    work = Path(args.work)
    opt = CoarseOptions()
    wrong = handed = total = 0
    t_full: list[float] = []
    t_probe: list[float] = []
    print("| world | run | full pass: drift / CPU s | probe: drift / CPU s | decision |")
    print("|---|---|---|---|---|")
    for world in args.worlds.split(","):
        seq, reference, runs = world_runs(work, world)
        for name, init in runs.items():
            prep = prepare(seq, reference, init, RefineConfig(workers=1),
                           work / world / "run_60_standard_ref", quiet=True)
            arrays = prep.frontend.to_problem_arrays()
            samples = SemanticSamples.from_arrays(**{
                f"{c}_{s}": arrays.get(f"{c}_{s}")
                for c in ("wall", "column", "floor", "ceiling") for s in ("frame", "p_in_cam")})
            ref = prep.reference
            plan = FloorPlan.from_planes(ref.segments, ref.segment_class, ref.segment_z,
                                         ref.planes, ref.plane_kind)
            poses = prep.init.poses.copy()
            maps_for = stages._storey_maps(plan, opt, {})
            full, tf = _cpu(stages._level_frames, poses, samples, plan, maps_for, opt,
                            np.random.default_rng(opt.seed))
            probe, tp = _cpu(stages._near_probe, poses, samples, plan, maps_for, opt)
            exits = probe is not None and probe < opt.near_probe_m
            bad = exits and full.drift_m >= opt.frame_gate_m
            total += 1
            handed += exits
            wrong += bad
            decision = ("WRONG hand-back" if bad else "hand back" if exits else "full pass")
            if exits:
                cache: dict = {}
                coarse_register(poses, samples, plan, opt, cache)  # build the maps once
                off, t0 = _cpu(coarse_register, poses, samples, plan,
                               replace(opt, near_probe_frames=0), cache)
                on, t1 = _cpu(coarse_register, poses, samples, plan, opt, cache)
                assert np.array_equal(off.poses, on.poses)
                t_full.append(t0)
                t_probe.append(t1)
                decision += f" (coarse stage {t0:.2f} → {t1:.2f} CPU s)"
            shown = "–" if probe is None else f"{probe:.3f} m"
            print(f"| {world} | {name} | {full.drift_m:.3f} m / {tf:.1f} | {shown} / {tp:.1f} | "
                  f"{decision} |", flush=True)
    print()
    print(f"runs: {total}; handed back: {handed}; wrong hand-backs: {wrong} (goal 0)")
    if t_full:
        print(f"hand-back, coarse stage CPU s: mean {np.mean(t_full):.2f} → {np.mean(t_probe):.2f}"
              f", worst {max(t_full):.2f} → {max(t_probe):.2f} (goal < 1 s; ratio "
              f"{np.mean(t_full) / np.mean(t_probe):.1f}×)")


if __name__ == "__main__":
    main()
