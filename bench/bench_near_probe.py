"""The coarse stage's near probe: does it hand back only what the full pass hands back, and how
fast is a hand-back?

Per world of ``bench_generalization.py`` (built there, reused here) and per run (the fixed point
from the ground truth, the paper's Exp. 1/2/3 drifts), on the front end of the default ``bimcap
refine``:

* stage 0's tracked drift over every frame (the full pass) and over ``near_probe_frames`` evenly
  spaced frames (the probe), with the CPU seconds of each;
* the decision: the probe hands back when it reads less than ``near_probe_m``; a hand-back is
  *wrong* if the full pass reads ``frame_gate_m`` or more (it would have moved the poses);
* for the runs handed back, the whole ``coarse_register`` call: with the probe off (the full
  pass), with the code of 4206b3e (``tests/_coarse_reference.py``: its correlative search, stage
  0's ICPs one at a time, the probe's yaw step of 1°) and with the code now, the two alternating
  in this process (``--repeats`` times each, the least CPU time kept); every hand-back's poses
  and fit are checked to be the full pass's, bit for bit.

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
    ap.add_argument("--repeats", type=int, default=2,
                    help="timings of each hand-back per code version (alternating; the least)")
    args = ap.parse_args()
    work = Path(args.work)
    opt = CoarseOptions()
    # The code of 4206b3e: its probe's yaw step, its correlative search and stage 0's ICPs.
    old_opt = replace(opt, near_probe_yaw_step_deg=opt.yaw_step_deg)
    old_code = _old_code()
    wrong = handed = total = 0
    wrong_old = handed_old = 0
    t_full: list[float] = []
    t_old: list[float] = []
    t_new: list[float] = []
    print("| world | run | full pass: drift / CPU s | probe 4206b3e: drift / CPU s | "
          "probe now: drift / CPU s | decision |")
    print("|---|---|---|---|---|---|")
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
            cache: dict = {}
            maps_for = stages._storey_maps(plan, opt, cache)
            full, tf = _cpu(stages._level_frames, poses, samples, plan, maps_for, opt,
                            np.random.default_rng(opt.seed))
            with old_code():
                probe_old, tpo = _cpu(stages._near_probe, poses, samples, plan, maps_for,
                                      old_opt)
            probe, tp = _cpu(stages._near_probe, poses, samples, plan, maps_for, opt)
            exits = probe is not None and probe < opt.near_probe_m
            exits_old = probe_old is not None and probe_old < opt.near_probe_m
            far = full.drift_m >= opt.frame_gate_m
            bad = exits and far
            total += 1
            handed += exits
            wrong += bad
            handed_old += exits_old
            wrong_old += exits_old and far
            decision = ("WRONG hand-back" if bad else "hand back" if exits else "full pass")
            if exits:
                off, t0 = _cpu(coarse_register, poses, samples, plan,
                               replace(opt, near_probe_frames=0), cache)
                before, after = [], []
                for _ in range(max(args.repeats, 1)):
                    with old_code():
                        was, t1 = _cpu(coarse_register, poses, samples, plan, old_opt, cache)
                    on, t2 = _cpu(coarse_register, poses, samples, plan, opt, cache)
                    before.append(t1)
                    after.append(t2)
                    # A hand-back gives the full pass's poses and fit, bit for bit.
                    for res in (was, on):
                        assert np.array_equal(off.poses, res.poses)
                        assert np.array_equal(off.frame_score, res.frame_score)
                t_full.append(t0)
                t_old.append(min(before))
                t_new.append(min(after))
                decision += (f" (coarse stage: full pass {t0:.2f}, 4206b3e {min(before):.2f}"
                             f" → now {min(after):.2f} CPU s, goal < 1 s)")
            print(f"| {world} | {name} | {full.drift_m:.3f} m / {tf:.1f} | {_m(probe_old)} / "
                  f"{tpo:.2f} | {_m(probe)} / {tp:.2f} | {decision} |", flush=True)
    print()
    print(f"runs: {total}; handed back: {handed} (4206b3e: {handed_old}); wrong hand-backs: "
          f"{wrong} (4206b3e: {wrong_old}; goal 0)")
    if t_new:
        print(f"hand-back, coarse stage CPU s: full pass mean {np.mean(t_full):.2f} / worst "
              f"{max(t_full):.2f}; 4206b3e mean {np.mean(t_old):.2f} / worst {max(t_old):.2f}; "
              f"now mean {np.mean(t_new):.2f} / worst {max(t_new):.2f} (goal < 1 s, worst); "
              f"now vs 4206b3e {np.mean(t_old) / np.mean(t_new):.2f}× (mean of the ratios "
              f"{np.mean(np.array(t_old) / np.array(t_new)):.2f}×)")


def _m(drift: float | None) -> str:
    return "–" if drift is None else f"{drift:.3f} m"


def _old_code():
    """A context in which the coarse stage runs the code of 4206b3e
    (``tests/_coarse_reference.py``)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from _coarse_reference import old_coarse

    return old_coarse


if __name__ == "__main__":
    main()
