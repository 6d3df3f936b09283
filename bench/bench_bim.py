"""Benchmark of ``bimcap bim`` and of the floor-plan vectorizers (not a test; run by hand).

    PYTHONPATH=python python bench/bench_bim.py [--models DIR] [--skip-vectorizers]

Part 1 runs ``bimcap bim MODEL -o TMP`` on each shared model and on a generated 3-storey building,
each in a fresh process (imports included), and prints wall time, CPU time (user + system, all
threads) and peak memory (target: Duplex < 15 s on the project's 2-core machine; the machine is
shared, so compare CPU time when the wall time looks off). Part 2 compares the rough detectors
(Hough / LSD / contour, each followed by the same refinement and merging) by coverage / precision
against the exact slice
and by time: the numbers behind the default (``Vectorizer.HOUGH``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench/'s own helpers
from shared_paths import shared_ifc_dir

REPO = Path(__file__).resolve().parents[1]
SHARED = shared_ifc_dir()
MODELS = ["AC20-FZK-Haus.ifc", "SampleHouse4.ifc", "Duplex_A_20110907.ifc",
          "Office_A_20110811.ifc"]

_CHILD = """
import resource, sys, time
t = time.perf_counter()
from bimcap.cli import main
rc = main(["bim", sys.argv[1], "-o", sys.argv[2]])
dt = time.perf_counter() - t
ru = resource.getrusage(resource.RUSAGE_SELF)
print("BENCH", rc, dt, ru.ru_maxrss / 1024.0, ru.ru_utime + ru.ru_stime)
"""


def generated_building(directory: Path) -> Path:
    """A generated 3-storey building: bimcap.sim.building when present, else the test building."""
    path = directory / "generated_3storey.ifc"
    try:
        from bimcap.sim.building import BuildingSpec, generate_building

        generate_building(BuildingSpec(storeys=3), seed=0, ifc_path=path)
        return path
    except Exception:  # the generator branch may not have landed
        sys.path.insert(0, str(REPO / "tests"))
        from _bim_building import build_simple_building

        build_simple_building(path, n_storeys=3)
        return path


def run_cli(model: Path) -> tuple[int, float, float, float, str]:
    with tempfile.TemporaryDirectory() as out:
        env_path = str(REPO / "python")
        proc = subprocess.run(
            [sys.executable, "-c", _CHILD, str(model), out],
            capture_output=True, text=True, env={"PYTHONPATH": env_path, "PATH": "/usr/bin:/bin"},
        )
        line = [x for x in proc.stdout.splitlines() if x.startswith("BENCH")]
        if not line:
            return -1, float("nan"), float("nan"), float("nan"), proc.stderr[-500:]
        _, rc, dt, mem, cpu = line[0].split()
        cov = [x.strip() for x in proc.stdout.splitlines() if "coverage" in x]
        return int(rc), float(dt), float(mem), float(cpu), "; ".join(cov)


def compare_vectorizers(model_path: Path) -> list[tuple[str, str, float, float, float, int]]:
    from bimcap.bim.floorplan import FloorPlanOptions, Vectorizer, build_floor_plan
    from bimcap.bim.ingest import load_model

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = load_model(model_path)
    rows = []
    for method in Vectorizer:
        t = time.perf_counter()
        fp = build_floor_plan(model, FloorPlanOptions(vectorizer=method))
        dt = time.perf_counter() - t
        exact = sum(sp.agreement["all"].exact_length_m for sp in fp.storeys)
        det = sum(sp.agreement["all"].detected_length_m for sp in fp.storeys)
        cov = sum(sp.agreement["all"].coverage * sp.agreement["all"].exact_length_m
                  for sp in fp.storeys) / max(exact, 1e-9)
        prec = sum(sp.agreement["all"].precision * sp.agreement["all"].detected_length_m
                   for sp in fp.storeys) / max(det, 1e-9)
        nseg = sum(len(sp.segments) for sp in fp.storeys)
        rows.append((model_path.name, method.value, cov, prec, dt, nseg))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", type=Path, default=SHARED)
    ap.add_argument("--skip-vectorizers", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        paths = [args.models / m for m in MODELS if (args.models / m).is_file()]
        paths.append(generated_building(Path(tmp)))
        print("## bimcap bim, one fresh process per model")
        print(f"{'model':<28} {'rc':>3} {'wall s':>7} {'cpu s':>6} {'peak MiB':>9}  floor plan")
        for p in paths:
            rc, dt, mem, cpu, cov = run_cli(p)
            print(f"{p.name:<28} {rc:>3} {dt:>7.2f} {cpu:>6.2f} {mem:>9.0f}  {cov}")
        if not args.skip_vectorizers:
            print("\n## rough detector comparison (same refinement), length-weighted over storeys")
            print(f"{'model':<28} {'detector':<8} {'coverage':>9} {'precision':>9} "
                  f"{'time s':>7} {'segments':>8}")
            for p in paths:
                for row in compare_vectorizers(p):
                    print(f"{row[0]:<28} {row[1]:<8} {row[2]:>9.4f} {row[3]:>9.4f} "
                          f"{row[4]:>7.2f} {row[5]:>8d}")
    print(json.dumps({"python": sys.version.split()[0]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
