"""The deviation outputs: ``deviations.json``, ``deviations.csv``, ``deviations.ply``, and the
one-call :func:`run_deviations` that writes them from a sequence, poses and an IFC.

``deviations.json`` is :meth:`DeviationReport.to_dict`: ``{"format": "bimcap-deviations",
"version": 1, "ifc", "options", "counts": {status: n}, "rays", "timings", "elements": [{"guid",
"ifc_class", "name", "storey", "status", "offset_m", "coverage", "n_points", "rays", "passes",
"offset_xy_m", "tilt_deg", "datum"}], "clusters": [{"n_points", "centroid", "min", "max",
"extent"}], "datum": {"mode": "none", "note"} | {"mode": "datum", "world_datum_from_world", ...}}``
(:mod:`bimcap.deviations.datum`: what the offsets are relative to).
The CSV has one row per element with the same fields (``offset_xy_m`` split into ``offset_x_m``
/ ``offset_y_m``). ``deviations.ply`` is the refined map coloured by the offset of the element each
point lies on (blue −2 × tolerance … white 0 … red +2 × tolerance; grey: no analysed element;
black: an element without an offset). ``deviations.png`` is the floor-plan picture
(:mod:`bimcap.deviations.plot`). ``deviations.ifc`` is the design IFC with a property set
:data:`PSET_NAME` on every analysed element (``Status``, ``Offset_m``, ``OffsetX_m`` /
``OffsetY_m`` for columns, ``Tilt_deg``, ``Coverage``, ``PointCount``, ``Tolerance_m``), written
with IfcOpenShell: any BIM viewer lists it in the element's properties and can filter or colour
by it. ``deviations.bcfzip`` is the BIM Collaboration Format 2.1 export: one topic per deviating or
missing element, its GUID selected in a viewpoint whose camera looks at it
(:mod:`bimcap.deviations.bcf`).
"""

from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.deviations.analysis import DeviationOptions, DeviationReport
from bimcap.io.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text

F64 = NDArray[np.float64]

#: The CSV's columns, in order.
CSV_FIELDS = ("guid", "ifc_class", "name", "storey", "status", "offset_m", "coverage", "n_points",
              "rays", "passes", "offset_x_m", "offset_y_m", "tilt_deg", "datum")
#: Files :func:`run_deviations` writes into its output directory.
DEVIATION_OUTPUTS = ("deviations.json", "deviations.csv", "deviations.ply", "deviations.png",
                     "deviations.ifc", "deviations.bcfzip")
#: The property set :func:`write_deviation_ifc` puts on every analysed element.
PSET_NAME = "BIMCaP_Deviation"


def write_deviations_json(path: str | PathLike[str], report: DeviationReport) -> None:
    """``deviations.json`` (atomically)."""
    atomic_write_json(path, report.to_dict())


def deviations_csv_text(report: DeviationReport) -> str:
    """The CSV text: a header of :data:`CSV_FIELDS`, one row per element (empty = none)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_FIELDS)
    for e in report.elements:
        d = e.to_dict()
        xy = d.pop("offset_xy_m") or [None, None]
        d["offset_x_m"], d["offset_y_m"] = xy
        writer.writerow(["" if d[k] is None else _fmt(d[k]) for k in CSV_FIELDS])
    return buf.getvalue()


def _fmt(value: Any) -> str:
    return f"{value:.5f}" if isinstance(value, float) else str(value)


def write_deviations_csv(path: str | PathLike[str], report: DeviationReport) -> None:
    """``deviations.csv`` (atomically)."""
    atomic_write_text(path, deviations_csv_text(report))


def offset_colors(report: DeviationReport, point_element: NDArray[np.integer]) -> NDArray[np.uint8]:
    """(P, 3) uint8 RGB of each point from its element's offset (see the module doc)."""
    scale = 2.0 * report.options.tolerance_m
    offsets = np.array([np.nan if e.offset_m is None else e.offset_m for e in report.elements]
                       + [np.nan])
    # columns: the sign of a length means nothing; shown as red by their size
    pe = np.asarray(point_element, dtype=np.int64)
    value = offsets[np.where(pe >= 0, pe, len(offsets) - 1)]
    s = np.clip(np.nan_to_num(value) / scale, -1.0, 1.0)
    rgb = np.empty((len(pe), 3))
    pos, neg = s >= 0, s < 0
    rgb[pos] = np.c_[np.ones(pos.sum()), 1 - s[pos], 1 - s[pos]]
    rgb[neg] = np.c_[1 + s[neg], 1 + s[neg], np.ones(neg.sum())]
    rgb[pe < 0] = 0.6
    rgb[(pe >= 0) & ~np.isfinite(value)] = 0.0
    out: NDArray[np.uint8] = np.round(255 * rgb).astype(np.uint8)
    return out


def write_deviation_ply(path: str | PathLike[str], points: F64, report: DeviationReport,
                        point_element: NDArray[np.integer]) -> None:
    """A binary PLY of (P, 3) ``points`` coloured by offset (``x y z`` float32, ``red green
    blue`` uchar, ``element`` int32: index into ``deviations.json``'s elements, -1 none)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    rgb = offset_colors(report, point_element)
    rec = np.empty(len(p), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"),
                                  ("green", "u1"), ("blue", "u1"), ("element", "<i4")])
    rec["x"], rec["y"], rec["z"] = p[:, 0], p[:, 1], p[:, 2]
    rec["red"], rec["green"], rec["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    rec["element"] = np.asarray(point_element, dtype=np.int32)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment bimcap deviations: colour = offset, blue -{2 * report.options.tolerance_m:g} m"
        f" .. red +{2 * report.options.tolerance_m:g} m; grey no element\n"
        f"element vertex {len(p)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty int element\n"
        "end_header\n"
    )
    atomic_write_bytes(path, header.encode("ascii") + rec.tobytes())


def write_deviation_ifc(design: str | PathLike[str], report: DeviationReport,
                        path: str | PathLike[str]) -> int:
    """Write ``design`` with the :data:`PSET_NAME` property set on each element of ``report``
    (atomically; lengths in metres whatever the file's unit, hence the ``_m`` names). Returns the
    number of elements annotated."""
    import ifcopenshell
    import ifcopenshell.api

    f = ifcopenshell.open(str(design))
    done = 0
    for e in report.elements:
        try:
            product = f.by_guid(e.guid)
        except RuntimeError:
            continue
        props: dict[str, Any] = {"Status": e.status.value, "Coverage": round(e.coverage, 4),
                                 "PointCount": int(e.n_points),
                                 "Tolerance_m": report.options.tolerance_m}
        if e.offset_m is not None:
            props["Offset_m"] = round(e.offset_m, 5)
        if e.offset_xy_m is not None:
            props["OffsetX_m"], props["OffsetY_m"] = (round(v, 5) for v in e.offset_xy_m)
        if e.tilt_deg is not None:
            props["Tilt_deg"] = round(e.tilt_deg, 3)
        pset = ifcopenshell.api.run("pset.add_pset", f, product=product, name=PSET_NAME)
        ifcopenshell.api.run("pset.edit_pset", f, pset=pset, properties=props)
        done += 1
    atomic_write_text(path, f.to_string())
    return done


@dataclass
class DeviationRun:
    """What :func:`run_deviations` did: the report and the files it wrote (name → path)."""

    report: DeviationReport
    files: dict[str, Path]
    seconds: float


def run_deviations(sequence: Any, world_from_cam: F64, ifc: str | PathLike[str], out_dir: Path,
                   options: DeviationOptions | None = None, storey: str | None = None,
                   voxel_m: float = 0.03, map_points: F64 | None = None, datum: Any = None,
                   model: Any = None) -> DeviationRun:
    """Analyse ``sequence`` under ``world_from_cam`` (N, 7) against ``ifc`` and write
    :data:`DEVIATION_OUTPUTS` into ``out_dir`` (which must exist).

    Parameters
    ----------
    sequence: a read :class:`bimcap.dataset.Sequence` (its scans and ``cam_from_lidar``).
    world_from_cam: the refined poses, one per frame.
    ifc: the design model.
    out_dir: where the files go (a run's staging directory, or any directory).
    options: the analysis settings.
    storey: keep only the elements and map points of this storey (by name).
    voxel_m: voxel of the map the clusters and the coloured PLY use (metres).
    map_points: (P, 3) the refined map, if already built (else built from the scans).
    datum: a :class:`bimcap.deviations.datum.DatumSpec`: offsets relative to it (the map, the
        PLY, the picture and the BCF viewpoints in its corrected world); None: relative to
        ``world_from_cam``.
    model: the design already loaded (:func:`~bimcap.deviations.analysis.load_design`).
    """
    from bimcap.deviations.analysis import analyse_deviations, load_design
    from bimcap.deviations.refined_map import load_scans, storey_z_range, voxel_downsample

    t0 = time.perf_counter()
    if model is None:
        model = load_design(ifc)
    scans = load_scans(sequence, world_from_cam)
    z_range = storey_z_range(model.storeys, storey) if storey is not None else None
    if map_points is None:
        map_points, _ = voxel_downsample(scans.p_in_world, voxel_m)
    if z_range is not None:
        keep = (map_points[:, 2] >= z_range[0]) & (map_points[:, 2] < z_range[1])
        map_points = map_points[keep]
    report = analyse_deviations(model, scans, options, ifc, map_points, storey=storey,
                                datum=datum)
    # the map and the walk in the datum's world (as analysed)
    assert report.map_points is not None and report.sensor_origins is not None
    assert report.point_element is not None
    map_points, viewers = report.map_points, report.sensor_origins
    if z_range is not None:  # a map rebuilt by the per-frame datum fit: cropped again
        keep = (map_points[:, 2] >= z_range[0]) & (map_points[:, 2] < z_range[1])
        map_points, report.point_element = map_points[keep], report.point_element[keep]
    out = Path(out_dir)
    write_deviations_json(out / "deviations.json", report)
    write_deviations_csv(out / "deviations.csv", report)
    write_deviation_ply(out / "deviations.ply", map_points, report, report.point_element)
    from bimcap.deviations.plot import plot_deviations_on_plan

    plot_deviations_on_plan(model, report, out / "deviations.png", storey,
                            walk_xy=viewers[:, :2])
    write_deviation_ifc(ifc, report, out / "deviations.ifc")
    from bimcap.deviations.bcf import write_deviation_bcf

    write_deviation_bcf(out / "deviations.bcfzip", report, model, viewers=viewers,
                        ifc_path=ifc)
    files = {name: out / name for name in DEVIATION_OUTPUTS}
    return DeviationRun(report, files, time.perf_counter() - t0)
