"""Variants of a real IFC model the way other real-world exports differ from it (issue 11).

Each variant is the same building, written by IfcOpenShell into ``--out`` (the source is never
modified):

* ``georef``: the whole model moved far from the origin and turned, as a georeferenced export is:
  every root placement (``IfcLocalPlacement`` without ``PlacementRelTo``, i.e. the site's, and any
  other absolute one) composed with a yaw of :data:`GEOREF_YAW_DEG` about z and a shift of
  :data:`GEOREF_SHIFT_M` metres;
* ``shifted``, ``turned``: the georeferenced variant's shift alone and its yaw alone (about the
  origin), to tell float precision from a frame-dependent discretisation;
* ``m``, ``mm``, ``ft``: the length unit metres / millimetres / feet, every length in the file
  converted (:func:`ifcopenshell.util.unit.convert_file_length_units`);
* ``raised``: the building on a slope: root placements raised by :data:`RAISE_M` and every
  storey's ``Elevation`` with them;
* ``ifcwall``: ``IfcWallStandardCase`` written as plain ``IfcWall``;
* ``nocovering``: every ``IfcCovering`` removed;
* ``proxy``: every wall and column written as ``IfcBuildingElementProxy`` (as generic exports
  do), keeping its name, geometry and openings.

:func:`world_from_model` gives the rigid transform a variant applies to the original's world
coordinates (metres), so that a result in a variant's frame can be compared with the original.

Usage::

    PYTHONPATH=python python bench/ifc_variants.py ../shared/data/ifc/AC20-FZK-Haus.ifc \
        --out /tmp/ifcvar/variants --variants georef,mm,ft,raised
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: The georeferenced variant's shift (east, north, up) in metres and yaw about z in degrees.
GEOREF_SHIFT_M = (512_345.6, 5_401_234.5, 212.3)
GEOREF_YAW_DEG = 37.0
#: The raised variant's height in metres.
RAISE_M = 123.45

VARIANTS = ("georef", "shifted", "turned", "m", "mm", "ft", "raised", "ifcwall", "nocovering",
            "proxy")


def world_from_model(variant: str) -> NDArray[np.float64]:
    """(4, 4) rigid transform, metres: a point of the original model (its world frame) to the
    same point in ``variant``'s world frame (identity for the variants that move nothing)."""
    m = np.eye(4)
    if variant in ("georef", "turned"):
        c, s = math.cos(math.radians(GEOREF_YAW_DEG)), math.sin(math.radians(GEOREF_YAW_DEG))
        m[:2, :2] = [[c, -s], [s, c]]
    if variant in ("georef", "shifted"):
        m[:3, 3] = GEOREF_SHIFT_M
    elif variant == "raised":
        m[2, 3] = RAISE_M
    return m


def _move_roots(f: Any, world_from_model_m: NDArray[np.float64]) -> int:
    """Compose every root ``IfcLocalPlacement`` with ``world_from_model_m`` (metres); returns
    how many were moved."""
    import ifcopenshell.util.placement as up
    import ifcopenshell.util.unit as uu

    metres_per_unit = float(uu.calculate_unit_scale(f))
    move = world_from_model_m.copy()
    move[:3, 3] /= metres_per_unit
    n = 0
    for lp in f.by_type("IfcLocalPlacement"):
        if lp.PlacementRelTo is not None:
            continue
        new = move @ up.get_axis2placement(lp.RelativePlacement)
        lp.RelativePlacement = f.createIfcAxis2Placement3D(
            f.createIfcCartesianPoint([float(v) for v in new[:3, 3]]),
            f.createIfcDirection([float(v) for v in new[:3, 2]]),
            f.createIfcDirection([float(v) for v in new[:3, 0]]))
        n += 1
    return n


def make_variant(src: Path, variant: str, out: Path) -> Path:
    """Write ``variant`` of ``src`` to ``out/<stem>-<variant>.ifc`` (kept if there); its path."""
    import ifcopenshell
    import ifcopenshell.api
    import ifcopenshell.util.unit as uu

    dst = out / f"{src.stem}-{variant}.ifc"
    if dst.is_file():
        return dst
    f = ifcopenshell.open(str(src))
    if variant in ("georef", "shifted", "turned", "raised"):
        if _move_roots(f, world_from_model(variant)) == 0:
            raise SystemExit(f"{src}: no root IfcLocalPlacement to move")
        if variant == "raised":
            per_unit = RAISE_M / float(uu.calculate_unit_scale(f))
            for st in f.by_type("IfcBuildingStorey"):
                st.Elevation = float(st.Elevation or 0.0) + per_unit
    elif variant in ("m", "mm", "ft"):
        target = {"m": "METER", "mm": "MILLIMETER", "ft": "FOOT"}[variant]
        f = uu.convert_file_length_units(f, target)
    elif variant == "ifcwall":
        # IfcWallStandardCase adds no attribute to IfcWall (IFC2X3 and IFC4): rename the class
        text = src.read_text(encoding="utf-8", errors="surrogateescape")
        f = ifcopenshell.file.from_string(text.replace("IFCWALLSTANDARDCASE(", "IFCWALL("))
    elif variant == "proxy":
        # by GlobalId: a reassignment replaces the instance (and in IFC2X3 may replace others)
        for guid in [e.GlobalId for e in (*f.by_type("IfcWall"), *f.by_type("IfcColumn"))]:
            el = f.by_guid(guid)
            if not el.is_a("IfcBuildingElementProxy"):
                ifcopenshell.api.run("root.reassign_class", f, product=el,
                                     ifc_class="IfcBuildingElementProxy")
    elif variant == "nocovering":
        for c in list(f.by_type("IfcCovering")):
            ifcopenshell.api.run("root.remove_product", f, product=c)
    else:
        raise SystemExit(f"unknown variant {variant!r} (one of {', '.join(VARIANTS)})")
    out.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_suffix(".tmp.ifc")
    f.write(str(tmp))
    tmp.replace(dst)
    return dst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ifc", nargs="+", type=Path, help="source IFC files (read only)")
    ap.add_argument("--out", type=Path, required=True, help="directory for the variants")
    ap.add_argument("--variants", default=",".join(VARIANTS), help="comma list")
    args = ap.parse_args()
    for src in args.ifc:
        for v in args.variants.split(","):
            print(make_variant(src, v, args.out), flush=True)


if __name__ == "__main__":
    main()
