"""The shared BIM cache (``bimcap.io.cache``): the BIM reference step of ``bimcap refine`` on a new
output directory, the first time for an IFC and again once the shared cache holds it.

    PYTHONPATH=python python bench/bench_bim_cache.py [--models DIR]

Each run is a fresh process calling ``bimcap.bim.cache.reference_for`` with a new
``OUT/bim`` and one shared cache root; the figures are that call's wall and CPU seconds (the
process's imports, ~0.5 s, are not counted: every run pays them). Goal (issue "Fast enough for
real sequences"): the second run on the same IFC starts at once (< 1 s here); the ratio is
first / second.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/'s own helpers
from shared_paths import shared_ifc_dir

REPO = Path(__file__).resolve().parents[1]
SHARED = shared_ifc_dir()

_CHILD = """
import sys, time
from bimcap.bim.cache import reference_for
t, c = time.perf_counter(), time.process_time()
ref, _ = reference_for(sys.argv[1], sys.argv[2], shared_root=sys.argv[3])
print("BENCH", time.perf_counter() - t, time.process_time() - c, len(ref.segments))
"""


def _run(ifc: Path, out: Path, root: Path) -> tuple[float, float]:
    res = subprocess.run([sys.executable, "-c", _CHILD, str(ifc), str(out), str(root)],
                         capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(REPO / "python"), "PATH": "/usr/bin:/bin"})
    line = next(x for x in res.stdout.splitlines() if x.startswith("BENCH"))
    _, wall, cpu, _ = line.split()
    return float(wall), float(cpu)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", type=Path, default=SHARED)
    args = ap.parse_args()
    models = sorted(args.models.glob("*.ifc"))
    if not models:
        sys.exit(f"no IFC models in {args.models}")
    print(f"{'model':28} {'MB':>5} | {'first s':>8} {'cpu s':>7} | {'second s':>8} {'cpu s':>6} "
          f"| {'ratio':>6} | goal: second < 1 s")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "shared"
        for ifc in models:
            w1, c1 = _run(ifc, Path(tmp) / f"{ifc.stem}-a" / "bim", root)
            w2, c2 = _run(ifc, Path(tmp) / f"{ifc.stem}-b" / "bim", root)
            ok = "met" if w2 < 1.0 else "NOT met"
            print(f"{ifc.stem:28} {ifc.stat().st_size / 1e6:5.1f} | {w1:8.2f} {c1:7.2f} | "
                  f"{w2:8.2f} {c2:6.2f} | {w1 / w2:5.1f}x | {ok}")


if __name__ == "__main__":
    main()
