"""Scan-vs-BIM deviations: per IFC element, what the refined scans say about where it really is.

Every LiDAR return of the sequence is a ray from its sensor centre (refined poses). Each ray is
cast into the design model (one Open3D ``RaycastingScene`` of every element; door leaves left out,
as doors stand open or move) and compared with the first face it meets there, at distance ``t``
with outward normal ``m`` turned towards the sensor. With ``r`` the measured range and
``c = |u·m|`` the cosine of the incidence angle, the return lies ``e = (t − r)·c`` metres in
front of that face along ``m`` (negative: behind it). A ray then

* **hits** its element when ``|e| <= pass_margin_m``: ``e`` is one observation of the element's
  displacement along ``m``;
* **passes through** it when ``e < −pass_margin_m``: free space seen where the element should be;
* is **occluded** (clutter in front) otherwise, and says nothing about the element.

Rays at grazing incidence (``c < cos max_incidence_deg``) are not used.

Per element (walls, columns, slabs, coverings), with ``a`` its offset axes, the observations
``e_i = δ · (A m_i)`` are solved for the displacement ``δ`` by least squares with a trimmed
residual (``trim_mad`` × 1.4826 MAD around the median, twice):

* wall: ``δ`` along the wall's normal, the local y axis of its IFC placement (the left normal of
  its axis, so that a positive offset is the IFC's positive side); its two side faces,
* column: ``(δx, δy)`` in the world; ``offset_m`` is its length, ``offset_xy_m`` both,
* slab / covering: ``δ`` along world z (floors seen from above, ceilings from below).

Status: ``missing`` when at least ``missing_fraction`` of the rays that reach the element pass
through it (and at least ``min_rays`` reach it); ``unobserved`` when fewer than ``min_rays``
reach it or fewer than ``min_points`` hit it; ``deviating`` when ``|offset_m| > tolerance_m``;
else ``ok``. ``coverage`` is the share of the surface samples (``sample_spacing_m``) of the
element's visible faces (wall and column sides, slab tops, covering undersides, where no other
element stands against them) that a hitting ray lands within ``sample_spacing_m`` of. A wall's
``tilt_deg`` is its lean, from the slope of ``e`` over height (when the hits span
``min_tilt_span_m``).

Returns of the refined map further than ``cluster_gate_m`` from every element are grouped into
clusters (voxels of ``cluster_voxel_m``, 26-connected); those of at least
``cluster_min_points`` map points come out with their extents: clutter, temporary works, or
building parts the model lacks.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.deviations.refined_map import ScanSet, voxel_downsample
from bimcap.errors import BimcapError, InputError
from bimcap.geometry.local_frame import local_origin
from bimcap.labels import Label

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
I64 = NDArray[np.int64]

#: At most this many hits per element are used to measure its coverage.
_COVERAGE_HITS = 50_000

#: The element classes analysed, by bimcap label.
ANALYSED_LABELS: tuple[Label, ...] = (Label.WALL, Label.COLUMN, Label.FLOOR, Label.CEILING)


class DeviationError(BimcapError):
    """A deviation analysis that cannot proceed."""


class DeviationInputError(InputError):
    """Bad input to the deviation analysis (options, a run directory, poses, a storey)."""


class ElementStatus(str, Enum):
    """What the scans say about one element."""

    OK = "ok"  #: seen where the model has it, within the tolerance
    DEVIATING = "deviating"  #: seen, but further than the tolerance from where the model has it
    MISSING = "missing"  #: expected in view, but free space seen through it
    UNOBSERVED = "unobserved"  #: not seen enough to say


@dataclass(frozen=True)
class DeviationOptions:
    """Settings of :func:`analyse_deviations` (lengths in metres, angles in degrees).

    Attributes
    ----------
    tolerance_m: an offset beyond this is ``deviating``.
    pass_margin_m: a return within this of the face its ray meets (along the normal) hits it;
        one further behind passes through it.
    missing_fraction: share of the rays reaching an element that must pass through it for
        ``missing``.
    min_rays, min_points: fewer rays reaching / returns hitting an element: ``unobserved``.
    max_incidence_deg: rays more oblique to the face are not used.
    trim_mad: residuals beyond this many (MAD-scaled) deviations are trimmed from the fit.
    sample_spacing_m: spacing of the surface samples that measure coverage.
    ray_step: every ``ray_step``-th return is cast (1: all).
    min_tilt_span_m: a wall's tilt needs hits spanning this much height.
    cluster_gate_m, cluster_voxel_m, cluster_min_points: map points further than the gate from
        every element, grouped by 26-connected voxels, clusters of at least this many points.
    ignore_doors: leave door leaves out of the model the rays are cast into.
    """

    tolerance_m: float = 0.02
    pass_margin_m: float = 0.15
    missing_fraction: float = 0.5
    min_rays: int = 30
    min_points: int = 30
    max_incidence_deg: float = 75.0
    trim_mad: float = 2.5
    sample_spacing_m: float = 0.1
    ray_step: int = 2
    min_tilt_span_m: float = 0.8
    cluster_gate_m: float = 0.2
    cluster_voxel_m: float = 0.1
    cluster_min_points: int = 30
    ignore_doors: bool = True

    def __post_init__(self) -> None:
        positive = ("tolerance_m", "pass_margin_m", "sample_spacing_m", "cluster_gate_m",
                    "cluster_voxel_m", "trim_mad")
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise DeviationInputError(f"must be a finite number > 0 (got {value})",
                                          field=name)
        if not 0 < self.missing_fraction <= 1:
            raise DeviationInputError(f"must be in (0, 1] (got {self.missing_fraction})",
                                      field="missing_fraction")
        if not 0 < self.max_incidence_deg < 90:
            raise DeviationInputError(f"must be in (0, 90) (got {self.max_incidence_deg})",
                                      field="max_incidence_deg")
        for name in ("min_rays", "min_points", "ray_step", "cluster_min_points"):
            if int(getattr(self, name)) < 1:
                raise DeviationInputError(f"must be >= 1 (got {getattr(self, name)})", field=name)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class ElementDeviation:
    """The verdict on one IFC element.

    Attributes
    ----------
    guid, ifc_class, name, storey: the element's IFC GlobalId, class, Name and storey.
    status: :class:`ElementStatus`.
    offset_m: displacement from the model (m): along the wall normal (the IFC placement's local
        y), along z for slabs and coverings, the horizontal length for columns; None when
        unobserved or missing.
    offset_xy_m: a column's ``(dx, dy)`` (m), else None.
    tilt_deg: a wall's lean (degrees, positive towards its normal at the top), None when its hits
        span too little height.
    coverage: share of its visible faces' samples seen (0..1).
    n_points: returns that hit it.
    rays: returns whose ray reaches it in the model (hits + passes).
    passes: returns that pass through it (free space where it should be).
    datum: declared as built right (:mod:`bimcap.deviations.datum`): the poses were corrected
        so that its offset is zero; its status says how well it then fits.
    """

    guid: str
    ifc_class: str
    name: str
    storey: str | None
    status: ElementStatus
    offset_m: float | None
    coverage: float
    n_points: int
    rays: int
    passes: int
    offset_xy_m: tuple[float, float] | None = None
    tilt_deg: float | None = None
    datum: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            "guid": self.guid, "ifc_class": self.ifc_class, "name": self.name,
            "storey": self.storey, "status": self.status.value, "offset_m": self.offset_m,
            "coverage": self.coverage, "n_points": self.n_points, "rays": self.rays,
            "passes": self.passes,
            "offset_xy_m": None if self.offset_xy_m is None else list(self.offset_xy_m),
            "tilt_deg": self.tilt_deg, "datum": self.datum,
        }


@dataclass(frozen=True)
class Cluster:
    """Map points that no element explains.

    Attributes
    ----------
    n_points: map points in it. centroid: (3,) metres. min, max: (3,) corners of its box.
    """

    n_points: int
    centroid: tuple[float, float, float]
    min: tuple[float, float, float]
    max: tuple[float, float, float]

    @property
    def extent(self) -> tuple[float, float, float]:
        lo, hi = np.asarray(self.min), np.asarray(self.max)
        e = hi - lo
        return (float(e[0]), float(e[1]), float(e[2]))

    def to_dict(self) -> dict[str, Any]:
        return {"n_points": self.n_points, "centroid": list(self.centroid),
                "min": list(self.min), "max": list(self.max), "extent": list(self.extent)}


@dataclass
class DeviationReport:
    """Everything :func:`analyse_deviations` found.

    Attributes
    ----------
    elements: one verdict per analysed element, in model order.
    clusters: unexplained clusters, largest first.
    options: the settings.
    ifc: the model file (or "").
    rays: returns cast.
    timings: seconds per step.
    point_element: (P,) int32 for the map points given (``map_points``): index into
        ``elements`` of the element each point lies on, -1 for none (for the coloured PLY).
    datum: what the offsets are relative to: ``{"mode": "none", "note"}`` (the refined poses)
        or :meth:`bimcap.deviations.datum.DatumFit.to_dict` (``"mode": "datum"``; with the
        per-frame fit, ``"frames"``: :meth:`~bimcap.deviations.datum.FrameCorrections.to_dict`).
    map_points: (P, 3) the map points ``point_element`` refers to, in the datum's world (not in
        the JSON).
    sensor_origins: (N, 3) the sensor centres the analysis used (the datum's world; not in the
        JSON).
    """

    elements: list[ElementDeviation]
    clusters: list[Cluster]
    options: DeviationOptions
    ifc: str = ""
    rays: int = 0
    timings: dict[str, float] = field(default_factory=dict)
    point_element: I32 | None = None
    datum: dict[str, Any] = field(default_factory=dict)
    map_points: F64 | None = None
    sensor_origins: F64 | None = None

    def counts(self) -> dict[str, int]:
        """Elements per status."""
        out = {s.value: 0 for s in ElementStatus}
        for e in self.elements:
            out[e.status.value] += 1
        return out

    def by_name(self, name: str) -> ElementDeviation:
        for e in self.elements:
            if e.name == name:
                return e
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": "bimcap-deviations", "version": 1, "ifc": self.ifc,
            "options": self.options.to_dict(), "counts": self.counts(), "rays": self.rays,
            "timings": dict(self.timings), "datum": self.datum,
            "elements": [e.to_dict() for e in self.elements],
            "clusters": [c.to_dict() for c in self.clusters],
        }


# ------------------------------------------------------------------------------ geometry
@dataclass
class _Element:
    """An analysed element: its mesh and offset axes."""

    index: int  # position in the model's element list
    source: Any  # bimcap.bim.ingest.BimElement
    axes: F64  # (k, 3) offset axes
    kind: str  # "wall" | "column" | "plate"


def _triangle_normals(vertices: F64, faces: NDArray[np.integer]) -> tuple[F64, F64]:
    """(F, 3) unit normals and (F,) areas (m²) of a mesh's triangles."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    norm = np.linalg.norm(cross, axis=1)
    return cross / np.maximum(norm, 1e-12)[:, None], 0.5 * norm


def wall_normal(vertices: F64, faces: NDArray[np.integer], placement_y: F64 | None) -> F64:
    """(3,) horizontal unit normal of a wall: the area-weighted dominant direction of its
    vertical triangles' normals, signed like the IFC placement's local y axis when known."""
    normals, areas = _triangle_normals(vertices, faces)
    vertical = np.abs(normals[:, 2]) < 0.3
    xy = normals[vertical, :2]
    w = areas[vertical]
    if len(xy) == 0:
        return np.array([1.0, 0.0, 0.0]) if placement_y is None else placement_y
    scatter = (xy * w[:, None]).T @ xy
    _, vecs = np.linalg.eigh(scatter)
    n = np.array([vecs[0, 1], vecs[1, 1], 0.0])
    if placement_y is not None and float(n @ placement_y) < 0:
        n = -n
    out: F64 = n / np.linalg.norm(n)
    return out


def placement_y_axes(ifc_path: str | PathLike[str], guids: list[str]) -> dict[str, F64]:
    """The local y axis (3,) of each element's IFC placement, in the world, by GUID."""
    import ifcopenshell
    import ifcopenshell.util.placement as up

    out: dict[str, F64] = {}
    ifc = ifcopenshell.open(str(ifc_path))
    for guid in guids:
        try:
            el = ifc.by_guid(guid)
        except RuntimeError:
            continue
        if getattr(el, "ObjectPlacement", None) is None:
            continue
        m = np.asarray(up.get_local_placement(el.ObjectPlacement), dtype=np.float64)
        y = m[:3, 1]
        if np.linalg.norm(y) > 0:
            out[guid] = y / np.linalg.norm(y)
    return out


def _analysed(model: Any, ifc_path: str | PathLike[str] | None, storey: str | None
              ) -> list[_Element]:
    wanted = [(i, e) for i, e in enumerate(model.elements) if e.label in ANALYSED_LABELS
              and (storey is None or e.storey == storey)]
    walls = [e.guid for _, e in wanted if e.label == Label.WALL]
    y_axes = placement_y_axes(ifc_path, walls) if ifc_path is not None and walls else {}
    out = []
    for i, e in wanted:
        if e.label == Label.WALL:
            n = wall_normal(e.vertices, e.faces, y_axes.get(e.guid))
            out.append(_Element(i, e, n[None, :], "wall"))
        elif e.label == Label.COLUMN:
            out.append(_Element(i, e, np.eye(3)[:2], "column"))
        else:
            out.append(_Element(i, e, np.eye(3)[2:], "plate"))
    return out


def _face_mask(el: _Element, normals: F64) -> NDArray[np.bool_]:
    """Triangles that carry the element's offset: wall sides, column sides, slab tops and
    covering undersides."""
    mask: NDArray[np.bool_]
    if el.kind == "wall":
        mask = np.abs(normals @ el.axes[0]) > 0.9
    elif el.kind == "column":
        mask = np.abs(normals[:, 2]) < 0.3
    elif el.source.label == Label.CEILING:
        mask = normals[:, 2] < -0.9
    else:
        mask = normals[:, 2] > 0.9
    return mask


def _surface_samples(el: _Element, spacing: float, rng: np.random.Generator) -> F64:
    """(S, 6) points on the element's visible faces, about one per ``spacing``² (m²), and their
    outward face normals."""
    v, f = el.source.vertices, el.source.faces
    normals, areas = _triangle_normals(v, f)
    keep = _face_mask(el, normals)
    tri, area = f[keep], areas[keep]
    if len(tri) == 0:
        return np.zeros((0, 3))
    counts = np.floor(area / spacing**2 + rng.uniform(size=len(area))).astype(np.int64)
    which = np.repeat(np.arange(len(tri)), counts)
    u, w = rng.uniform(size=(2, len(which)))
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    a, b, c = (v[tri[which, k]] for k in range(3))
    pts: F64 = a + u[:, None] * (b - a) + w[:, None] * (c - a)
    return np.concatenate([pts, normals[keep][which]], axis=1)


class LocalScene:
    """An Open3D raycasting scene that takes and returns world metres in float64.

    Open3D casts in float32, which steps by 0.5 m at a georeferenced model's northing: the
    triangles are held relative to ``origin``
    (:func:`~bimcap.geometry.local_frame.local_origin` of the model), which every query
    subtracts first and every returned point gets back.
    """

    def __init__(self, origin: F64) -> None:
        import open3d as o3d

        self.origin = np.asarray(origin, dtype=np.float64).reshape(3)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.INVALID_ID = int(self.scene.INVALID_ID)

    def add_triangles(self, vertices: F64, faces: NDArray[np.integer]) -> int:
        """Add a mesh, (V, 3) world metres and (F, 3) indices; its geometry id."""
        local = np.asarray(vertices, np.float64) - self.origin
        return int(self.scene.add_triangles(_tensor(local, np.float32),
                                            _tensor(faces, np.uint32)))

    def cast_rays(self, origins: F64, directions: F64) -> dict[str, NDArray[Any]]:
        """Rays from (M, 3) world ``origins`` along (M, 3) ``directions``: Open3D's answer
        (``t_hit``, ``geometry_ids``, ``primitive_normals``) as numpy arrays."""
        rays = np.concatenate([np.asarray(origins, np.float64) - self.origin, directions], axis=1)
        ans = self.scene.cast_rays(_tensor(rays, np.float32))
        return {k: ans[k].numpy() for k in ("t_hit", "geometry_ids", "primitive_normals")}

    def compute_occupancy(self, points: F64) -> NDArray[Any]:
        """(M,) occupancy of (M, 3) world points (1 inside a closed mesh)."""
        local = np.asarray(points, np.float64) - self.origin
        return self.scene.compute_occupancy(_tensor(local, np.float32)).numpy()

    def compute_closest_points(self, points: F64) -> dict[str, NDArray[Any]]:
        """For (M, 3) world ``points``: ``points`` (M, 3) float64 world metres of the closest
        surface point and its ``geometry_ids`` (M,)."""
        local = np.asarray(points, np.float64) - self.origin
        ans = self.scene.compute_closest_points(_tensor(local, np.float32))
        return {"points": ans["points"].numpy().astype(np.float64) + self.origin,
                "geometry_ids": ans["geometry_ids"].numpy()}


def _scene(model: Any, options: DeviationOptions) -> tuple[LocalScene, dict[int, int]]:
    """A raycasting scene of the model's elements; geometry id → element index."""
    meshes = [(i, e) for i, e in enumerate(model.elements)
              if len(e.faces) and not (options.ignore_doors and e.label == Label.DOOR)]
    verts = [e.vertices for _, e in meshes]
    scene = LocalScene(local_origin(np.concatenate(verts) if verts else np.zeros((0, 3))))
    ids: dict[int, int] = {}
    for i, e in meshes:
        ids[scene.add_triangles(e.vertices, e.faces)] = i
    return scene, ids


def _tensor(array: NDArray[Any], dtype: type) -> Any:
    """An Open3D tensor of ``array`` (C-contiguous, ``dtype``)."""
    import open3d as o3d

    return o3d.core.Tensor.from_numpy(np.ascontiguousarray(array, dtype=dtype))


def _robust_fit(b: F64, e: F64, trim_mad: float) -> tuple[F64, NDArray[np.bool_]]:
    """Least-squares ``δ`` of ``e ≈ b δ`` ((M, k), (M,)) with residuals trimmed at ``trim_mad``
    × 1.4826 MAD around their median (twice); returns ``δ`` (k,) and the rows kept."""
    keep = np.ones(len(e), dtype=bool)
    delta = np.zeros(b.shape[1])
    for _ in range(3):
        if keep.sum() < b.shape[1]:
            break
        delta = np.asarray(np.linalg.lstsq(b[keep], e[keep], rcond=None)[0], dtype=np.float64)
        r = e - b @ delta
        med = float(np.median(r[keep]))
        mad = 1.4826 * float(np.median(np.abs(r[keep] - med)))
        keep = np.abs(r - med) <= trim_mad * max(mad, 1e-3)
    return delta, keep


# ------------------------------------------------------------------------------ analysis
#: What the report says without a datum.
NO_DATUM_NOTE = ("no datum: offsets are relative to the refined poses, which the refinement fits "
                 "to the design (a common displacement of the building goes into the poses)")


def analyse_deviations(
    model: Any,
    scans: ScanSet,
    options: DeviationOptions | None = None,
    ifc_path: str | PathLike[str] | None = None,
    map_points: F64 | None = None,
    seed: int = 0,
    storey: str | None = None,
    datum: Any = None,
) -> DeviationReport:
    """Per-element deviations of the scanned building from ``model``.

    Parameters
    ----------
    model: the design (:class:`bimcap.bim.ingest.BimModel`, world metres).
    scans: the LiDAR returns through the refined poses (:func:`~bimcap.deviations.refined_map.
        load_scans`): (R, 3) points, their frame, (N, 3) sensor centres.
    options: the settings (default :class:`DeviationOptions`).
    ifc_path: the model's file, for the walls' placement axes (the sign of their offsets);
        None signs wall normals by geometry alone.
    map_points: (P, 3) the refined map's points (metres), for the unexplained clusters and the
        per-point element index (``DeviationReport.point_element``); None uses a voxel map of
        ``scans`` at ``cluster_voxel_m / 3``.
    seed: seed of the surface sampling (coverage).
    storey: analyse only the elements of this storey (by name); every element still occludes.
    datum: a :class:`bimcap.deviations.datum.DatumSpec`: the scans (and ``map_points``) are
        first moved by the rigid correction that puts the datum's returns on its design faces
        (:func:`~bimcap.deviations.datum.fit_datum`), and every offset is relative to the datum;
        None: relative to the given poses (``report.datum["mode"] == "none"``).
    """
    opts = options or DeviationOptions()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    elements = _analysed(model, ifc_path, storey)
    scene, gid_to_element = _scene(model, opts)
    element_of_model = {el.index: k for k, el in enumerate(elements)}
    timings["scene"] = time.perf_counter() - t0

    datum_info: dict[str, Any] = {"mode": "none", "note": NO_DATUM_NOTE}
    datum_indices: set[int] = set()
    if datum is not None:
        t0 = time.perf_counter()
        scans, map_points, datum_info, datum_indices = datum.apply(
            model, scans, map_points, opts, scene, gid_to_element, ifc_path)
        timings["datum"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    rays = scans.subsample(opts.ray_step)
    hits = _cast(scene, rays)
    timings["raycast"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    lookup = np.full(len(model.elements), -1, np.int64)
    for m_idx, k in element_of_model.items():
        lookup[m_idx] = k
    max_gid = max(gid_to_element, default=-1)
    gid_elem = np.full(max_gid + 2, -1, np.int64)
    for g, m_idx in gid_to_element.items():
        gid_elem[g] = lookup[m_idx]
    gid = hits["gid"]
    elem = np.where(gid >= 0, gid_elem[np.clip(gid, 0, max_gid + 1)], -1)
    cosine = hits["cos"]
    usable = (elem >= 0) & (cosine >= np.cos(np.radians(opts.max_incidence_deg)))
    # metres in front of the face along m (rays that hit nothing: never used)
    e_front = np.where(elem >= 0, np.where(np.isfinite(hits["t"]), hits["t"], 0.0) - hits["r"],
                       0.0) * cosine
    is_hit = usable & (np.abs(e_front) <= opts.pass_margin_m)
    is_pass = usable & (e_front < -opts.pass_margin_m)
    n_elem = len(elements)
    n_hit = np.bincount(elem[is_hit], minlength=n_elem)
    n_pass = np.bincount(elem[is_pass], minlength=n_elem)
    rng = np.random.default_rng(seed)
    results = []
    order = np.argsort(elem[is_hit], kind="stable")
    hit_rows = np.flatnonzero(is_hit)[order]
    bounds = np.searchsorted(elem[is_hit][order], np.arange(n_elem + 1))
    occupancy_probe = _Probe(scene)
    for k, el in enumerate(elements):
        rows = hit_rows[bounds[k]:bounds[k + 1]]
        results.append(_judge(el, rows, hits, e_front, int(n_hit[k]), int(n_pass[k]), opts,
                              rng, occupancy_probe))
        results[-1].datum = el.index in datum_indices
    timings["elements"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if map_points is None:
        map_points, _ = voxel_downsample(scans.p_in_world, opts.cluster_voxel_m / 3)
    clusters, point_element = _clusters(scene, gid_to_element, lookup, map_points, opts)
    timings["clusters"] = time.perf_counter() - t0
    return DeviationReport(results, clusters, opts, "" if ifc_path is None else str(ifc_path),
                           len(rays), timings, point_element, datum_info, map_points,
                           scans.origins)


def _cast(scene: LocalScene, scans: ScanSet) -> dict[str, Any]:
    """Cast every return's ray into ``scene``: first-hit distance ``t``, geometry id ``gid``
    (-1 none), measured range ``r``, incidence cosine ``cos``, face normal ``m`` towards the
    sensor, hit point ``h`` (design) and the return ``p``."""

    origins = scans.origins[scans.frame]
    d = scans.p_in_world - origins
    r = np.linalg.norm(d, axis=1)
    u = d / np.maximum(r, 1e-9)[:, None]
    ans = scene.cast_rays(origins, u)
    t = ans["t_hit"].astype(np.float64)
    gid = ans["geometry_ids"].astype(np.int64)
    gid[~np.isfinite(t)] = -1
    gid[gid == scene.INVALID_ID] = -1
    m = ans["primitive_normals"].astype(np.float64)
    m /= np.maximum(np.linalg.norm(m, axis=1), 1e-12)[:, None]
    um = np.sum(u * m, axis=1)
    m[um > 0] *= -1.0  # towards the sensor
    t = np.where(np.isfinite(t), t, np.inf)
    h = origins + u * np.where(np.isfinite(t), t, 0.0)[:, None]
    return {"t": t, "gid": gid, "r": r, "cos": np.abs(um), "m": m, "h": h,
            "p": scans.p_in_world}


class _Probe:
    """Whether points lie inside any element of a scene (the exposure test of samples)."""

    def __init__(self, scene: LocalScene) -> None:
        self.scene = scene

    def inside(self, points: F64) -> NDArray[np.bool_]:

        if len(points) == 0:
            return np.zeros(0, dtype=bool)
        occ = self.scene.compute_occupancy(points)
        return np.asarray(occ, dtype=np.float64) > 0.5


def _judge(el: _Element, rows: I64, hits: dict[str, Any], e_front: F64, n_hit: int, n_pass: int,
           opts: DeviationOptions, rng: np.random.Generator, probe: _Probe) -> ElementDeviation:
    """The verdict on one element from the rows of its hitting rays."""
    src = el.source
    m = hits["m"][rows]
    b = m @ el.axes.T  # (M, k)
    useful = np.abs(m[:, 2]) < 0.3 if el.kind == "column" else np.abs(b[:, 0]) > 0.9
    rows, b, e = rows[useful], b[useful], e_front[rows][useful]
    offset: float | None = None
    offset_xy: tuple[float, float] | None = None
    tilt: float | None = None
    kept = np.zeros(0, dtype=bool)
    if len(rows) >= max(opts.min_points, 1):
        delta, kept = _robust_fit(b, e, opts.trim_mad)
        if el.kind == "column":
            offset_xy = (float(delta[0]), float(delta[1]))
            offset = float(np.hypot(*delta))
        else:
            offset = float(delta[0])
            if el.kind == "wall":
                tilt = _tilt(hits["h"][rows][kept], (e / b[:, 0])[kept], opts.min_tilt_span_m)
    coverage = _coverage(el, hits["h"][rows], opts, rng, probe)
    rays = n_hit + n_pass
    if rays >= opts.min_rays and n_pass >= opts.missing_fraction * rays:
        status = ElementStatus.MISSING
        offset, offset_xy, tilt = None, None, None
    elif rays < opts.min_rays or offset is None:
        status = ElementStatus.UNOBSERVED
        offset, offset_xy, tilt = None, None, None
    elif abs(offset) > opts.tolerance_m:
        status = ElementStatus.DEVIATING
    else:
        status = ElementStatus.OK
    return ElementDeviation(src.guid, src.ifc_class, src.name, src.storey, status, offset,
                            coverage, len(rows), rays, n_pass, offset_xy, tilt)


def _tilt(points: F64, displacement: F64, min_span: float) -> float | None:
    """Lean (degrees) from the slope of the displacement over height, or None."""
    if len(points) < 10:
        return None
    z = points[:, 2]
    if float(np.percentile(z, 95) - np.percentile(z, 5)) < min_span:
        return None
    slope = np.polyfit(z - z.mean(), displacement, 1)[0]
    return float(np.degrees(np.arctan(slope)))


def _coverage(el: _Element, hit_points: F64, opts: DeviationOptions, rng: np.random.Generator,
              probe: _Probe) -> float:
    """Share of the element's exposed visible-face samples within a spacing of a hit."""
    samples = _surface_samples(el, opts.sample_spacing_m, rng)
    if len(samples) == 0:
        return 0.0
    pts, normals = samples[:, :3], samples[:, 3:]
    exposed = ~probe.inside(pts + 0.02 * normals)
    pts = pts[exposed]
    if len(pts) == 0 or len(hit_points) == 0:
        return 0.0
    from scipy.spatial import cKDTree

    if len(hit_points) > _COVERAGE_HITS:  # plenty to tell which samples were reached
        hit_points = hit_points[rng.choice(len(hit_points), _COVERAGE_HITS, replace=False)]
    dist, nearest = cKDTree(pts).query(hit_points, distance_upper_bound=opts.sample_spacing_m)
    seen = np.unique(nearest[np.isfinite(dist)])
    return len(seen) / len(pts)


def _clusters(scene: LocalScene, gid_to_element: dict[int, int], lookup: I64, points: F64,
              opts: DeviationOptions) -> tuple[list[Cluster], I32]:
    """Unexplained clusters among ``points`` and each point's analysed element (-1 none)."""

    point_element = np.full(len(points), -1, np.int32)
    if len(points) == 0:
        return [], point_element
    ans = scene.compute_closest_points(points)
    dist = np.linalg.norm(ans["points"] - points, axis=1)
    closest = ans["geometry_ids"].astype(np.int64)
    near = dist <= opts.pass_margin_m
    for g, m_idx in gid_to_element.items():
        sel = near & (closest == g)
        if sel.any():
            point_element[sel] = lookup[m_idx]
    far = np.flatnonzero(dist > opts.cluster_gate_m)
    return _connected_clusters(points[far], opts), point_element


def _connected_clusters(points: F64, opts: DeviationOptions) -> list[Cluster]:
    """26-connected voxel components of ``points`` with at least ``cluster_min_points``."""
    if len(points) < opts.cluster_min_points:
        return []
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    key = np.floor(points / opts.cluster_voxel_m).astype(np.int64)
    cells, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    base = cells.min(axis=0) - 1
    dims = cells.max(axis=0) - base + 2
    flat = ((cells[:, 0] - base[0]) * dims[1] + (cells[:, 1] - base[1])) * dims[2] + (
        cells[:, 2] - base[2])
    order = np.argsort(flat)
    sorted_flat = flat[order]
    src, dst = [], []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if (dx, dy, dz) <= (0, 0, 0):
                    continue
                nb = flat + (dx * dims[1] + dy) * dims[2] + dz
                pos = np.clip(np.searchsorted(sorted_flat, nb), 0, len(flat) - 1)
                ok = sorted_flat[pos] == nb
                src.append(np.flatnonzero(ok))
                dst.append(order[pos[ok]])
    s, d = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.ones(len(s)), (s, d)), shape=(len(cells), len(cells)))
    _, comp = connected_components(graph, directed=False)
    point_comp = comp[inverse]
    out = []
    for c in np.unique(point_comp):
        p = points[point_comp == c]
        if len(p) < opts.cluster_min_points:
            continue
        lo, hi, mid = p.min(axis=0), p.max(axis=0), p.mean(axis=0)
        out.append(Cluster(len(p), (float(mid[0]), float(mid[1]), float(mid[2])),
                           (float(lo[0]), float(lo[1]), float(lo[2])),
                           (float(hi[0]), float(hi[1]), float(hi[2]))))
    out.sort(key=lambda c: -c.n_points)
    return out


def load_design(ifc_path: str | PathLike[str]) -> Any:
    """The design model (:func:`bimcap.bim.ingest.load_model`) for the analysis, furniture
    included: it is not judged, but it explains the points on it (no cluster) and occludes."""
    from bimcap.bim.ingest import load_model

    return load_model(Path(ifc_path), include_furniture=True)
