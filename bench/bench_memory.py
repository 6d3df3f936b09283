"""Peak memory of a whole ``bimcap refine`` (goal of issue 14: under 2 GiB at 1000 frames), and
of the refined map written streamed vs merged from every return, in the same process.

The refine runs in this process (``bimcap.cli.main``) while a thread samples the RSS every
0.2 s; each rise of 100 MB is printed beside the run's own log lines, so the stage that holds
the peak can be read off. ``--map-only`` skips the refine and compares the refined map's two
builds on an existing run's ``refined.tum``.

Usage (the 1000-frame world of ``docs/generalization.md``)::

    PYTHONPATH=python python bench/bench_memory.py -- refine SEQ --ifc MODEL.ifc \
        --init exp2.tum --gt SEQ/poses/gt.tum --workers 1 -o OUT
    PYTHONPATH=python python bench/bench_memory.py --map-only SEQ OUT/refined.tum
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import psutil

GOAL_GIB = 2.0


class RssSampler:
    """Peak RSS of this process, sampled every ``period_s`` seconds from a daemon thread."""

    def __init__(self, period_s: float = 0.2, report_step_mb: float = 100.0) -> None:
        self._proc = psutil.Process()
        self.peak = self._proc.memory_info().rss
        self._period = period_s
        self._step = report_step_mb * 2**20
        self._t0 = time.perf_counter()
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last = 0
        while not self._stop:
            rss = self._proc.memory_info().rss
            self.peak = max(self.peak, rss)
            if abs(rss - last) > self._step:
                print(f"[rss {time.perf_counter() - self._t0:7.1f} s] {rss / 2**30:.2f} GiB "
                      f"(peak {self.peak / 2**30:.2f})", file=sys.stderr, flush=True)
                last = rss
            time.sleep(self._period)

    def stop(self) -> float:
        """Stop sampling; the peak in GiB."""
        self._stop = True
        self._thread.join()
        return self.peak / 2**30


def map_only(seq_dir: str, tum: str) -> None:
    from bimcap.dataset import read_sequence
    from bimcap.deviations.refined_map import build_refined_map, load_scans, stream_refined_map
    from bimcap.geometry.trajectory import read_tum

    seq = read_sequence(seq_dir)
    poses = read_tum(tum).poses
    rows = []
    for name in ("streamed (what refine writes)", "every return merged at once"):
        sampler = RssSampler()
        base = sampler.peak
        t = time.perf_counter()
        if name.startswith("streamed"):
            m = stream_refined_map(seq, poses)
        else:
            m = build_refined_map(load_scans(seq, poses))
        seconds = time.perf_counter() - t
        peak = sampler.stop() - base / 2**30
        rows.append((name, peak, seconds, len(m.points), m.returns))
        del m
    print("| refined map | extra peak GiB | s | voxels | returns |\n|---|---|---|---|---|")
    for name, peak, seconds, voxels, returns in rows:
        print(f"| {name} | {peak:.2f} | {seconds:.1f} | {voxels} | {returns} |")
    print(f"ratio (merged / streamed): memory {rows[1][1] / max(rows[0][1], 1e-9):.1f}x, "
          f"time {rows[1][2] / rows[0][2]:.1f}x")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map-only", nargs=2, metavar=("SEQ", "REFINED_TUM"))
    ap.add_argument("cli", nargs=argparse.REMAINDER, help="-- then bimcap's arguments")
    args = ap.parse_args()
    if args.map_only:
        map_only(*args.map_only)
        return 0
    argv = args.cli[1:] if args.cli[:1] == ["--"] else args.cli
    if not argv:
        ap.error("give bimcap's arguments after --, or --map-only SEQ REFINED_TUM")
    from bimcap.cli import main as bimcap_main

    sampler = RssSampler()
    t0 = time.perf_counter()
    rc = bimcap_main(argv)
    peak = sampler.stop()
    verdict = "met" if peak < GOAL_GIB else "NOT met"
    print(f"bimcap {argv[0]}: exit {rc}, {time.perf_counter() - t0:.0f} s wall, peak RSS "
          f"{peak:.2f} GiB (goal < {GOAL_GIB:g} GiB at 1000 frames: {verdict})")
    return rc


if __name__ == "__main__":
    sys.exit(main())
