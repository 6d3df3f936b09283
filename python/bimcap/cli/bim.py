"""``bimcap bim MODEL.ifc -o OUT/``: the BIM reference of an IFC model, with a short summary."""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path
from typing import Any

NAME = "bim"
HELP = "IFC → semantic cloud, floor/ceiling planes, vectorized floor plan (metres)"
EXAMPLES = ("bimcap bim house.ifc -o bim/",
            "bimcap bim Duplex_A.ifc -o duplex_bim/ --meshes --vectorizer lsd")


def register(sub: Any) -> None:
    from bimcap.cli import add_out_argument

    p = sub.add_parser(
        NAME,
        help=HELP,
        description="Ingest an IFC model and write its BIM reference: semantic point cloud (PLY), "
        "floor/ceiling planes (JSON), vectorized floor plan (JSON, SVG, PNG) and arrays (NPZ).",
    )
    p.add_argument("model", type=Path, metavar="MODEL.ifc", help="IFC2X3 / IFC4 file")
    add_out_argument(p, "output directory", required=True, type=Path, metavar="DIR")
    p.add_argument("--density", type=float, default=100.0, help="cloud points per m² (100)")
    p.add_argument("--seed", type=int, default=0, help="cloud sampling seed (0)")
    p.add_argument("--cut-height", type=float, default=1.2,
                   help="floor-plan cut height above each storey elevation, m (1.2)")
    p.add_argument("--half-band", type=float, default=0.2, help="half height of the cut band, m")
    p.add_argument("--resolution", type=float, default=0.05, help="raster cell size, m (0.05)")
    p.add_argument("--vectorizer", choices=["hough", "lsd", "contour"], default="hough",
                   help="rough line detector (hough)")
    p.add_argument("--meshes", action="store_true",
                   help="also write one OBJ mesh per class (furniture included in 'other')")
    p.add_argument("--max-lost-fraction", type=float, default=0.02, metavar="F",
                   help="refuse a damaged IFC that lost more than this share of its building "
                        "elements (default 0.02); a smaller loss is a warning with the counts")
    p.set_defaults(func=run, output_dirs=["out"], input_paths=["model"])


def run(args: argparse.Namespace) -> int:
    import sys

    from bimcap.bim.errors import BimOptionsError, BimWarning, DamagedModelWarning
    from bimcap.bim.floorplan import FloorPlanOptions, Vectorizer
    from bimcap.bim.ingest import load_model
    from bimcap.bim.reference import ReferenceOptions, build_reference
    from bimcap.bim.semantic_cloud import write_class_meshes
    from bimcap.io.atomic import check_not_input

    out: Path = args.out
    check_not_input(out, [args.model])
    if not 0.0 <= args.max_lost_fraction <= 1.0:
        raise BimOptionsError(
            f"--max-lost-fraction must be in [0, 1], got {args.max_lost_fraction}")
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BimWarning)
        model = load_model(args.model, include_furniture=args.meshes,
                           max_lost_fraction=args.max_lost_fraction)
        for w in caught:
            if issubclass(w.category, DamagedModelWarning):  # loudly, before anything else
                print(f"bimcap bim: WARNING: {w.message}", file=sys.stderr)
        t1 = time.perf_counter()
        opts = ReferenceOptions(
            density_per_m2=args.density,
            seed=args.seed,
            floorplan=FloorPlanOptions(
                cut_height_m=args.cut_height,
                half_band_m=args.half_band,
                resolution_m=args.resolution,
                vectorizer=Vectorizer(args.vectorizer),
            ),
        )
        ref = build_reference(model, opts)
    t2 = time.perf_counter()
    ref.save(out)
    if args.meshes:
        write_class_meshes(model, out)
    t3 = time.perf_counter()

    s = ref.summary()
    print(f"{args.model.name}: {model.schema}, unit scale {model.unit_scale:g} m/unit")
    print("elements: " + ", ".join(f"{k} {v}" for k, v in sorted(s["elements"].items())))
    if model.failed:
        print(f"failed to tessellate ({len(model.failed)}): "
              + ", ".join(g for g, _ in model.failed[:10]))
    print("storeys: " + ", ".join(f"{st['name']} {st['elevation_m']:.3f} m" for st in s["storeys"]))
    print(f"planes: {s['planes']['floor']} floor, {s['planes']['ceiling']} ceiling")
    for name, v in s["segments"].items():
        print(f"segments {name}: {v['count']}, {v['length_m']:.1f} m")
    for st in s["floorplan_storeys"]:
        a = st["agreement"]["all"]
        print(f"  {st['storey']}: band {st['band'][0]:.2f}..{st['band'][1]:.2f} m, "
              f"{st['segment_count']} segments, coverage {a['coverage']:.3f}, "
              f"precision {a['precision']:.3f} (tol {a['tol_m']:.2f} m)")
    print(f"cloud: {s['points']} points")
    for w in caught:
        if not issubclass(w.category, DamagedModelWarning):
            print(f"warning: {w.message}")
    print(f"time: load {t1 - t0:.1f} s, reference {t2 - t1:.1f} s, write {t3 - t2:.1f} s; "
          f"written to {out}")
    return 0
