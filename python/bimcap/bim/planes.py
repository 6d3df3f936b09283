"""Floor and ceiling reference planes per storey, each with its xy polygon.

Sign convention (the solver's F and Ce residuals rely on it): a plane is ``[nx, ny, nz, d]`` with
unit normal n and signed distance ``n·p + d``.

* **floor** planes have the normal **up** (0, 0, 1): d = −z_floor, points above the floor (inside
  the room) are positive;
* **ceiling** planes have the normal **down** (0, 0, −1), pointing into the room: d = +z_ceiling,
  points below the ceiling (inside the room) are positive.

Sources: floors are the up-facing faces of floor slabs (IfcSlab FLOOR / BASESLAB / LANDING,
IfcCovering FLOORING); ceilings are the down-facing faces of IfcCovering CEILING and, where no
ceiling covering lies, the undersides of the slabs above. Faces of all elements of one kind are
grouped by height (within ``height_tol``), merged in xy, and each connected piece becomes its own
plane, so split levels, landings and several slabs per storey each get the plane under them.
A storey that has walls but no floor slab gets floors from its IfcSpace bottoms (or, without
spaces, a plane at the storey elevation over the walls' convex hull) and a
:class:`~bimcap.bim.errors.MissingFloorWarning`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.bim.errors import MissingCeilingWarning, MissingFloorWarning
from bimcap.bim.ingest import BimElement, BimModel, read_spaces
from bimcap.labels import Label


@dataclass
class ReferencePlane:
    """One floor or ceiling plane.

    Attributes
    ----------
    kind: Label.FLOOR or Label.CEILING.
    storey: name of the storey it belongs to (by height), or None.
    plane: (4,) float64 ``[nx, ny, nz, d]``, unit n, signed distance ``n·p + d`` (see module doc).
    polygon: (K, 2) float64 exterior ring in xy metres (not closed: last != first).
    holes: list of (K_i, 2) interior rings.
    source: how it was derived: ``"slab"``, ``"covering"``, ``"slab-above"``, ``"space"``,
        ``"storey-elevation"``.
    guids: GlobalIds of the elements it came from.
    """

    kind: Label
    storey: str | None
    plane: NDArray[np.float64]
    polygon: NDArray[np.float64]
    holes: list[NDArray[np.float64]] = field(default_factory=list)
    source: str = "slab"
    guids: list[str] = field(default_factory=list)

    @property
    def height(self) -> float:
        """z of the (horizontal) plane in metres."""
        return float(-self.plane[3] / self.plane[2])

    @property
    def area_m2(self) -> float:
        return float(self.shape().area)

    def shape(self) -> Any:
        """The polygon as a :class:`shapely.Polygon`."""
        import shapely

        return shapely.Polygon(self.polygon, [h for h in self.holes])

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind.name.lower(),
            "storey": self.storey,
            "plane": [float(v) for v in self.plane],
            "height_m": self.height,
            "polygon": self.polygon.tolist(),
            "holes": [h.tolist() for h in self.holes],
            "source": self.source,
            "guids": list(self.guids),
        }

    @staticmethod
    def from_dict(d: dict[str, Any]) -> ReferencePlane:
        return ReferencePlane(
            kind=Label[str(d["kind"]).upper()],
            storey=d.get("storey"),
            plane=np.asarray(d["plane"], dtype=np.float64),
            polygon=np.asarray(d["polygon"], dtype=np.float64).reshape(-1, 2),
            holes=[np.asarray(h, dtype=np.float64).reshape(-1, 2) for h in d.get("holes", [])],
            source=str(d.get("source", "slab")),
            guids=list(d.get("guids", [])),
        )


@dataclass(frozen=True)
class PlaneOptions:
    """How planes are extracted.

    Attributes
    ----------
    max_tilt_deg: faces within this angle of horizontal count as floor / ceiling faces.
    height_tol_m: faces whose heights differ by less than this share one plane.
    min_area_m2: smaller pieces are dropped.
    simplify_m: polygon simplification tolerance.
    """

    max_tilt_deg: float = 5.0
    height_tol_m: float = 0.02
    min_area_m2: float = 0.25
    simplify_m: float = 0.005


def _horizontal_faces(
    elements: list[BimElement], up: bool, cos_tilt: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], list[int]]:
    """Triangles facing up (or down) of ``elements``: (T, 3, 3) xyz, (T,) z, owner index list."""
    tris, owners = [], []
    for i, e in enumerate(elements):
        t = e.vertices[e.faces]
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        norm = np.linalg.norm(n, axis=1)
        ok = norm > 1e-12
        nz = np.zeros(len(t))
        nz[ok] = n[ok, 2] / norm[ok]
        sel = nz > cos_tilt if up else nz < -cos_tilt
        if sel.any():
            tris.append(t[sel])
            owners.extend([i] * int(sel.sum()))
    if not tris:
        return np.zeros((0, 3, 3)), np.zeros(0), []
    allt = np.concatenate(tris)
    return allt, allt[:, :, 2].mean(axis=1), owners


def _height_groups(z: NDArray[np.float64], tol: float) -> list[NDArray[np.int64]]:
    """Indices grouped so that sorted consecutive heights differ by less than ``tol``."""
    if len(z) == 0:
        return []
    order = np.argsort(z, kind="stable")
    cuts = np.nonzero(np.diff(z[order]) >= tol)[0] + 1
    return list(np.split(order, cuts))


def _pieces(tris: NDArray[np.float64], simplify: float) -> list[Any]:
    """Connected xy polygons covered by triangles (T, 3, 3)."""
    import shapely

    polys = shapely.polygons(tris[:, :, :2])
    polys = polys[shapely.area(polys) > 1e-10]
    if len(polys) == 0:
        return []
    # A tiny buffer welds triangles that share an edge only up to round-off.
    merged = shapely.union_all(shapely.buffer(polys, 1e-4, join_style="mitre"))
    merged = shapely.buffer(merged, -1e-4, join_style="mitre").simplify(simplify)
    geoms = list(getattr(merged, "geoms", [merged]))
    return [g for g in geoms if g.geom_type == "Polygon" and not g.is_empty]


def _planes_from_faces(
    elements: list[BimElement], up: bool, opts: PlaneOptions
) -> list[tuple[float, Any, list[str]]]:
    """(height, shapely polygon, guids) of every connected horizontal piece of the up-facing
    (``up``) or down-facing faces of ``elements``."""
    cos_tilt = float(np.cos(np.deg2rad(opts.max_tilt_deg)))
    tris, z, owners = _horizontal_faces(elements, up, cos_tilt)
    out = []
    own = np.asarray(owners, dtype=np.int64)
    for idx in _height_groups(z, opts.height_tol_m):
        t = tris[idx]
        e1 = t[:, 1, :2] - t[:, 0, :2]
        e2 = t[:, 2, :2] - t[:, 0, :2]
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        if area.sum() < opts.min_area_m2:
            continue
        height = float((z[idx] * area).sum() / max(area.sum(), 1e-12))
        guids = sorted({elements[k].guid for k in own[idx]})
        for poly in _pieces(t, opts.simplify_m):
            if poly.area >= opts.min_area_m2:
                out.append((height, poly, guids))
    return out


def _make_plane(
    kind: Label, height: float, poly: Any, storey: str | None, source: str, guids: list[str]
) -> ReferencePlane:
    if kind == Label.FLOOR:
        plane = np.array([0.0, 0.0, 1.0, -height])
    else:
        plane = np.array([0.0, 0.0, -1.0, height])
    ext = np.asarray(poly.exterior.coords, dtype=np.float64)[:-1]
    holes = [np.asarray(r.coords, dtype=np.float64)[:-1] for r in poly.interiors]
    return ReferencePlane(kind, storey, plane, ext, holes, source, guids)


def storey_for_height(model: BimModel, z: float, below_by: float) -> str | None:
    """The highest storey whose elevation is at most ``z - below_by`` (None if below all)."""
    name = None
    for s in model.storeys:
        if s.elevation_m <= z - below_by + 1e-9:
            name = s.name
    if name is None and model.storeys:
        name = model.storeys[0].name
    return name


def extract_planes(model: BimModel, opts: PlaneOptions | None = None) -> list[ReferencePlane]:
    """Floor and ceiling planes of every storey (see the module docstring for the conventions).

    Warns :class:`MissingFloorWarning` for each storey with walls but no floor slab, and
    :class:`MissingCeilingWarning` for each storey with walls and no ceiling at all.
    """
    import shapely

    opts = opts or PlaneOptions()
    planes: list[ReferencePlane] = []

    # ---- floors from slabs / floor coverings
    floors_src = model.by_label(Label.FLOOR)
    for h, poly, guids in _planes_from_faces(floors_src, True, opts):
        planes.append(
            _make_plane(Label.FLOOR, h, poly, storey_for_height(model, h, -0.5), "slab", guids)
        )

    # ---- storeys with walls but no real floor slab
    wall_storeys = {e.storey for e in model.by_label(Label.WALL) if e.storey is not None}
    # A storey has a real floor when a non-landing slab's top was assigned to it by height.
    nonlanding = {e.guid for e in floors_src if (e.predefined_type or "") != "LANDING"}
    real_floor = {p.storey for p in planes if set(p.guids) & nonlanding}
    missing = [s for s in model.storeys if s.name in wall_storeys and s.name not in real_floor]
    if missing:
        spaces = read_spaces(model)
        for st in missing:
            mine = [sp for sp in spaces if sp.storey == st.name]
            got = _planes_from_faces(mine, False, opts)
            if got:
                for h, poly, guids in got:
                    planes.append(_make_plane(Label.FLOOR, h, poly, st.name, "space", guids))
                how = f"{len(got)} floor plane(s) from its {len(mine)} IfcSpace bottoms"
            else:
                pts = np.concatenate(
                    [e.vertices[:, :2] for e in model.by_label(Label.WALL) if e.storey == st.name]
                )
                hull = shapely.MultiPoint(pts).convex_hull
                planes.append(
                    _make_plane(Label.FLOOR, st.elevation_m, hull, st.name, "storey-elevation", [])
                )
                how = "one floor plane at the storey elevation over the walls' convex hull"
            warnings.warn(
                f"{model.path.name}: storey {st.name!r} (elevation {st.elevation_m:.3f} m) has "
                f"walls but no floor slab (IfcSlab FLOOR/BASESLAB); using {how}",
                MissingFloorWarning,
                stacklevel=2,
            )

    # ---- ceilings from coverings
    ceil_elems = model.by_label(Label.CEILING)
    cover = _planes_from_faces(ceil_elems, False, opts)
    covered: dict[str | None, Any] = {}
    for h, poly, guids in cover:
        st = storey_for_height(model, h, 1.0)
        planes.append(_make_plane(Label.CEILING, h, poly, st, "covering", guids))
        covered[st] = poly if st not in covered else covered[st].union(poly)

    # ---- ceilings from the undersides of slabs, where no covering is
    slabs = [e for e in model.elements if e.ifc_class in ("IfcSlab", "IfcRoof")
             or (e.label == Label.FLOOR and e.ifc_class.startswith("IfcSlab"))]
    for h, poly, guids in _planes_from_faces(slabs, False, opts):
        st = storey_for_height(model, h, 1.0)
        if st is None:
            continue
        elev = model.storeys[model.storey_index(st)].elevation_m
        if h - elev < 1.0:
            continue
        rest = poly.difference(covered[st]) if st in covered else poly
        for piece in getattr(rest, "geoms", [rest]):
            # Slivers over walls (narrower than 0.4 m) are not ceilings anyone sees.
            if (piece.geom_type == "Polygon" and piece.area >= opts.min_area_m2
                    and not piece.buffer(-0.2).is_empty):
                planes.append(
                    _make_plane(Label.CEILING, h, piece.simplify(opts.simplify_m), st,
                                "slab-above", guids)
                )
    ceil_storeys = {p.storey for p in planes if p.kind == Label.CEILING}
    for st in model.storeys:
        if st.name in wall_storeys and st.name not in ceil_storeys:
            warnings.warn(
                f"{model.path.name}: storey {st.name!r} has walls but neither a ceiling covering "
                "nor a slab above it: no ceiling plane",
                MissingCeilingWarning,
                stacklevel=2,
            )
    return planes


def plane_under(
    planes: list[ReferencePlane],
    plane_array: NDArray[np.float64],
    p_in_world: NDArray[np.float64],
    kind: Label,
    side_tol_m: float = 0.5,
) -> NDArray[np.int32]:
    """For each point, the index of the plane of ``kind`` under (floor) or over (ceiling) it.

    A plane qualifies when its xy polygon contains the point and the point is on the plane's
    room side: signed distance ``n·p + d ≥ −side_tol_m`` (floor normals point up, ceiling normals
    down, so a point in the room is positive for both; the tolerance absorbs noise and drift).
    Among the qualifying planes the one nearest in ``|n·p + d|`` wins, so the floor of the storey
    a point is in is chosen, not the ceiling of the storey below that may be nearer.

    Parameters
    ----------
    planes: the planes (polygons). plane_array: (Q, 4) their ``[nx, ny, nz, d]``.
    p_in_world: (M, 3) float64 metres.
    kind: Label.FLOOR or Label.CEILING. side_tol_m: metres.

    Returns
    -------
    (M,) int32 plane indices into ``planes``, −1 where no plane qualifies.
    """
    import shapely

    p = np.asarray(p_in_world, dtype=np.float64).reshape(-1, 3)
    best = np.full(len(p), -1, dtype=np.int32)
    best_d = np.full(len(p), np.inf)
    for q, pl in enumerate(planes):
        if pl.kind != kind:
            continue
        shp = pl.shape()
        xmin, ymin, xmax, ymax = shp.bounds
        cand = np.nonzero(
            (p[:, 0] >= xmin) & (p[:, 0] <= xmax) & (p[:, 1] >= ymin) & (p[:, 1] <= ymax)
        )[0]
        if len(cand) == 0:
            continue
        signed = p[cand] @ plane_array[q, :3] + plane_array[q, 3]
        ok = signed >= -side_tol_m
        cand, signed = cand[ok], signed[ok]
        if len(cand) == 0:
            continue
        inside = shapely.contains_xy(shp, p[cand, 0], p[cand, 1])
        cand, dist = cand[inside], np.abs(signed[inside])
        better = dist < best_d[cand]
        best[cand[better]] = q
        best_d[cand[better]] = dist[better]
    return best
