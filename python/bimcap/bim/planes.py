"""Floor and ceiling reference planes per storey, each with its xy polygon.

Sign convention (the solver's F and Ce residuals rely on it): a plane is ``[nx, ny, nz, d]`` with
unit normal n and signed distance ``n·p + d``.

* **floor** planes have the normal **up** (0, 0, 1): d = −z_floor, points above the floor (inside
  the room) are positive;
* **ceiling** planes have the normal **down** (0, 0, −1), pointing into the room: d = +z_ceiling,
  points below the ceiling (inside the room) are positive.

Sources: only surfaces one can see become planes. Floors are the **top** faces of floor slabs
(IfcSlab FLOOR / BASESLAB / LANDING, IfcCovering FLOORING); ceilings are the **bottom** faces of
IfcCovering CEILING and, where no ceiling covering lies, the undersides of the slabs above. Top
and bottom are decided from each element's solid (a vertical ray's crossings of its own shell,
:func:`oriented_horizontal_faces`), not from the triangle winding, which exporters get wrong
(Revit's coverings in Duplex_A / Office_A come with their tops wound like undersides). A face
is hidden, and gives no plane, where another element rests on it or passes through it (a
finish floor on its structural slab, a wall or column on a slab, a slab over its covering,
within ``hide_gap_m``). The visible faces are cut in 1 mm height bins, grouped by height
(within ``height_tol_m``), merged in xy, and each connected piece becomes its own plane, so
split levels, sunken areas, landings, basements and several slabs per storey each get the plane
that is really there.

Ramps and pitched roofs (faces steeper than ``max_tilt_deg``, 1°) give **no** plane: the F and
Ce terms use horizontal planes only (the coarse registration levels on them), and a sample on a
ramp finds no plane over its xy and is dropped and counted
(:func:`bimcap.bim.plane_choice.choose_planes`), rather than pulled onto a horizontal plane it
is not on.

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
from bimcap.bim.ingest import BimElement, BimModel, Storey, read_spaces
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

        return shapely.Polygon(self.polygon, list(self.holes))

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
    max_tilt_deg: faces within this angle of horizontal count as floor / ceiling faces; steeper
        ones (ramps, pitched roofs) give no plane (module docstring).
    height_tol_m: visible faces whose heights differ by less than this share one plane (at the
        area-weighted mean of their heights). With 2 cm Duplex_A's floor finishes at 0, 13 and
        19 mm become one plane at 16.2 mm, 2.8 mm under the 19 mm floor the walk is on (its
        fixed point 0.43 cm; 0.41 cm with 2 mm). 2 mm is not the default: with it one global
        alignment of Duplex_A (bench_global seed 14) scored its 180-degree alias at 0.875 of
        the best, a silently wrong placement before the near-exact alias rule
        (docs/global_align.md, "Near-exact aliases"; flagged since), and the fixed point's
        gain is one world's 0.02 cm (docs/generalization.md, "What still pulled the fixed
        point").
    hide_gap_m: a top face is hidden where another element's bottom face lies within this above
        it (a finish floor on its structural slab, a raised floor, a wall), a bottom face where
        another element's top face lies within this below it (a slab over its ceiling covering).
    min_area_m2: smaller pieces are dropped.
    simplify_m: polygon simplification tolerance.
    """

    max_tilt_deg: float = 1.0
    height_tol_m: float = 0.02
    hide_gap_m: float = 0.25
    min_area_m2: float = 0.25
    simplify_m: float = 0.005


@dataclass
class _Faces:
    """Horizontal triangles of some elements with their true side: (T, 3, 3) xyz, (T,) centroid
    z, (T,) owner element index, (T,) True where the face is a top face (material below)."""

    tris: NDArray[np.float64]
    z: NDArray[np.float64]
    owner: NDArray[np.int64]
    top: NDArray[np.bool_]

    def select(self, mask: NDArray[np.bool_]) -> _Faces:
        return _Faces(self.tris[mask], self.z[mask], self.owner[mask], self.top[mask])


def _crossings_below(q: NDArray[np.float64], tris: NDArray[np.float64],
                     chunk: int = 256) -> NDArray[np.int64]:
    """(M,) number of distinct surfaces of ``tris`` (N, 3, 3) that the downward vertical ray
    from each point ``q`` (M, 3) crosses (distinct heights, so that a ray through an edge shared
    by two triangles of one face counts once)."""
    a, b, c = tris[:, 0, :2], tris[:, 1, :2], tris[:, 2, :2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-12  # vertical faces are never crossed by a vertical ray
    a, b, c, det, za = a[ok], b[ok], c[ok], det[ok], tris[ok][:, :, 2]
    out = np.zeros(len(q), np.int64)
    for s in range(0, len(q), chunk):
        p = q[s:s + chunk]
        px = p[:, None, 0] - a[None, :, 0]
        py = p[:, None, 1] - a[None, :, 1]
        u = (px * (c[None, :, 1] - a[None, :, 1]) - py * (c[None, :, 0] - a[None, :, 0])) / det
        v = (py * (b[None, :, 0] - a[None, :, 0]) - px * (b[None, :, 1] - a[None, :, 1])) / det
        inside = (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1.0 + 1e-9)
        z = (za[None, :, 0] + u * (za[None, :, 1] - za[None, :, 0])
             + v * (za[None, :, 2] - za[None, :, 0]))
        below = inside & (z < p[:, None, 2] - 1e-4)
        none = 1e18  # beyond any height in 0.1 mm units; not inf, whose differences are NaN
        zz = np.sort(np.where(below, np.round(z / 1e-4), none), axis=1)
        fin = zz < none
        distinct = fin[:, :1].sum(axis=1) + ((np.diff(zz, axis=1) != 0) & fin[:, 1:]).sum(axis=1)
        out[s:s + chunk] = distinct
    return out


def oriented_horizontal_faces(elements: list[BimElement], max_tilt_deg: float) -> _Faces:
    """The horizontal triangles of ``elements`` and whether each is a top or a bottom face.

    IFC tessellations do not orient their triangles consistently (a covering's underside may
    come with its normal up), so the side is decided from the solid itself: a vertical ray cast
    down from a point of the face crosses the element's other surfaces an odd number of times
    exactly when there is material right below it (a top face). An element whose shell is not
    closed falls back to its normals.
    """
    cos_tilt = float(np.cos(np.deg2rad(max_tilt_deg)))
    tris, zs, owners, tops = [], [], [], []
    w = np.array([0.31, 0.33, 0.36])  # a point inside the face, off its medians and edges
    for i, e in enumerate(elements):
        t = np.asarray(e.vertices, np.float64)[np.asarray(e.faces)]
        if len(t) == 0:
            continue
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        norm = np.linalg.norm(n, axis=1)
        nz = np.where(norm > 1e-12, n[:, 2] / np.maximum(norm, 1e-300), 0.0)
        hor = np.abs(nz) >= cos_tilt
        if not hor.any():
            continue
        th = t[hor]
        q = (w[None, :, None] * th).sum(axis=1)
        parity = _crossings_below(q, t) % 2 == 1
        # A closed shell has as many top as bottom faces' area over each xy; where the parity
        # says all faces are tops (or all bottoms) the shell is open: trust the normals then.
        area = 0.5 * norm[hor]
        up_area = area[parity].sum()
        if up_area < 1e-9 or up_area > area.sum() - 1e-9:
            parity = nz[hor] > 0
        tris.append(th)
        zs.append(th[:, :, 2].mean(axis=1))
        owners.append(np.full(len(th), i, np.int64))
        tops.append(parity)
    if not tris:
        return _Faces(np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, bool))
    return _Faces(np.concatenate(tris), np.concatenate(zs), np.concatenate(owners),
                  np.concatenate(tops))


def union_xy(tris: NDArray[np.float64]) -> Any:
    """The xy union of triangles (T, 3, 3) as one shapely geometry (empty when none)."""
    import shapely

    if len(tris) == 0:
        return shapely.Polygon()
    polys = shapely.polygons(tris[:, :, :2])
    polys = polys[shapely.area(polys) > 1e-10]
    if len(polys) == 0:
        return shapely.Polygon()
    # A tiny buffer welds triangles that share an edge only up to round-off.
    merged = shapely.union_all(shapely.buffer(polys, 1e-4, join_style="mitre"))
    return shapely.buffer(merged, -1e-4, join_style="mitre")


def _polygons(geom: Any, simplify: float) -> list[Any]:
    geom = geom.simplify(simplify) if not geom.is_empty else geom
    geoms = list(getattr(geom, "geoms", [geom]))
    return [g for g in geoms if g.geom_type == "Polygon" and not g.is_empty]


def _visible_planes(
    faces: _Faces, top: bool, hiders: _Faces, elements: list[BimElement], opts: PlaneOptions
) -> list[tuple[float, Any, list[str]]]:
    """(height, shapely polygon, guids) of every connected visible piece of the top faces
    (``top``) or bottom faces of ``faces``.

    A top face at height h is hidden where another element of ``hiders`` stands on it or passes
    through it: that element rises above h and has a bottom face at most ``hide_gap_m`` above h
    (a finish floor on its slab, a wall, a column; its bottom faces leave out the door openings
    cut to the floor). A bottom face is hidden likewise by another element that reaches below it
    with a top face at most ``hide_gap_m`` below it (a covering under a slab, a wall holding it).
    Faces are cut at 1 mm height bins before they are grouped by ``height_tol_m``.
    """
    sel = faces.select(faces.top if top else ~faces.top)
    cover = hiders.select(~hiders.top if top else hiders.top)
    # how far each hider reaches beyond its covering face: up (zmax) for floors, down for ceilings
    reach = np.array([e.zmax if top else -e.zmin for e in elements], np.float64)
    import shapely

    footprint: dict[int, Any] = {}  # per hiding element, the union of its covering faces

    def cover_of(owners: NDArray[np.int64]) -> Any:
        for o in owners:
            if o not in footprint:
                footprint[o] = union_xy(cover.tris[cover.owner == o])
        return shapely.union_all([footprint[o] for o in owners])

    bins = np.round(sel.z / 1e-3).astype(np.int64)
    pieces: list[tuple[float, Any, set[str]]] = []
    for b in np.unique(bins):
        z = float(b * 1e-3)
        if top:
            near = (cover.z <= z + opts.hide_gap_m) & (reach[cover.owner] > z + 0.01)
        else:
            near = (cover.z >= z - opts.hide_gap_m) & (reach[cover.owner] > -z + 0.01)
        near_owners = np.unique(cover.owner[near])
        common = cover_of(near_owners) if len(near_owners) else None
        in_bin = np.flatnonzero(bins == b)
        for owner in np.unique(sel.owner[in_bin]):
            idx = in_bin[sel.owner[in_bin] == owner]
            geom = union_xy(sel.tris[idx])
            if owner in near_owners:  # an element never hides itself (a stepped slab)
                others = near_owners[near_owners != owner]
                hide = cover_of(others) if len(others) else None
            else:
                hide = common
            if hide is not None and not hide.is_empty:
                geom = geom.difference(hide)
            if geom.area > 0.0:
                pieces.append((z, geom, {elements[owner].guid}))
    out = []
    zs = np.array([p[0] for p in pieces])
    for group in _height_groups(zs, opts.height_tol_m):
        areas = np.array([pieces[k][1].area for k in group])
        height = float((zs[group] * areas).sum() / max(areas.sum(), 1e-12))
        geom = shapely.union_all([pieces[k][1] for k in group])
        guids = sorted(set().union(*[pieces[k][2] for k in group]))
        for poly in _polygons(geom, opts.simplify_m):
            if poly.area >= opts.min_area_m2:
                out.append((height, poly, guids))
    return out


def _height_groups(z: NDArray[np.float64], tol: float) -> list[NDArray[np.int64]]:
    """Indices grouped so that sorted consecutive heights differ by less than ``tol``."""
    if len(z) == 0:
        return []
    order = np.argsort(z, kind="stable")
    cuts = np.nonzero(np.diff(z[order]) >= tol)[0] + 1
    return list(np.split(order, cuts))


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


def _is_slab(e: BimElement) -> bool:
    return e.ifc_class in ("IfcSlab", "IfcRoof") or (
        e.label == Label.FLOOR and e.ifc_class.startswith("IfcSlab"))


@dataclass
class _PlaneSources:
    """Every element that can carry or hide a floor or a ceiling surface, in the order floors,
    ceiling coverings, other slabs, walls and columns (``n_floor``, ``n_ceil``, ``n_slab``: the
    ends of the first three groups), and their oriented horizontal faces."""

    elements: list[BimElement]
    faces: _Faces
    n_floor: int
    n_ceil: int
    n_slab: int


def _plane_sources(model: BimModel, opts: PlaneOptions) -> _PlaneSources:
    """The elements of the model that carry or hide floors and ceilings, with their faces."""
    floors_src = model.by_label(Label.FLOOR)
    ceil_elems = model.by_label(Label.CEILING)
    slabs = [e for e in model.elements if _is_slab(e) and e.label != Label.FLOOR]
    # walls and columns only hide: the slab top under a wall, the underside a wall holds up
    solids = model.by_label(Label.WALL, Label.COLUMN)
    elements = floors_src + ceil_elems + slabs + solids
    n_floor, n_ceil = len(floors_src), len(floors_src) + len(ceil_elems)
    return _PlaneSources(elements=elements,
                         faces=oriented_horizontal_faces(elements, opts.max_tilt_deg),
                         n_floor=n_floor, n_ceil=n_ceil, n_slab=n_ceil + len(slabs))


def _floor_planes(src: _PlaneSources, model: BimModel, opts: PlaneOptions
                  ) -> list[ReferencePlane]:
    """Floors: the visible tops of slabs and floor coverings."""
    faces = src.faces
    of_floor = faces.select(faces.owner < src.n_floor)
    return [_make_plane(Label.FLOOR, h, poly, storey_for_height(model, h, -0.5), "slab", guids)
            for h, poly, guids in _visible_planes(of_floor, True, faces, src.elements, opts)]


def _storey_floor_substitute(model: BimModel, st: Storey, spaces: list[BimElement],
                             opts: PlaneOptions) -> tuple[list[ReferencePlane], str]:
    """Floor planes of a storey without a floor slab: its IfcSpace bottoms, else one plane at
    its elevation over its walls' convex hull; and how they were made."""
    import shapely

    mine = [sp for sp in spaces if sp.storey == st.name]
    sp_faces = oriented_horizontal_faces(mine, opts.max_tilt_deg)
    got = _visible_planes(sp_faces, False, _Faces(*(a[:0] for a in (
        sp_faces.tris, sp_faces.z, sp_faces.owner, sp_faces.top))), mine, opts)
    if got:
        planes = [_make_plane(Label.FLOOR, h, poly, st.name, "space", guids)
                  for h, poly, guids in got]
        return planes, f"{len(got)} floor plane(s) from its {len(mine)} IfcSpace bottoms"
    pts = np.concatenate(
        [e.vertices[:, :2] for e in model.by_label(Label.WALL) if e.storey == st.name]
    )
    hull = shapely.MultiPoint(pts).convex_hull
    planes = [_make_plane(Label.FLOOR, st.elevation_m, hull, st.name, "storey-elevation", [])]
    return planes, "one floor plane at the storey elevation over the walls' convex hull"


def _missing_floor_planes(model: BimModel, floors: list[ReferencePlane],
                          src: _PlaneSources, wall_storeys: set[str],
                          opts: PlaneOptions) -> list[ReferencePlane]:
    """Floors of the storeys with walls but no real floor slab, each with a
    :class:`MissingFloorWarning` (attributed to the caller of :func:`extract_planes`)."""
    # A storey has a real floor when a non-landing slab's top was assigned to it by height.
    nonlanding = {e.guid for e in src.elements[:src.n_floor]
                  if (e.predefined_type or "") != "LANDING"}
    real_floor = {p.storey for p in floors if set(p.guids) & nonlanding}
    missing = [s for s in model.storeys if s.name in wall_storeys and s.name not in real_floor]
    planes: list[ReferencePlane] = []
    if not missing:
        return planes
    spaces = read_spaces(model)
    for st in missing:
        got, how = _storey_floor_substitute(model, st, spaces, opts)
        planes += got
        warnings.warn(
            f"{model.path.name}: storey {st.name!r} (elevation {st.elevation_m:.3f} m) has "
            f"walls but no floor slab (IfcSlab FLOOR/BASESLAB); using {how}",
            MissingFloorWarning,
            stacklevel=3,
        )
    return planes


def _covering_ceilings(src: _PlaneSources, model: BimModel, opts: PlaneOptions
                       ) -> tuple[list[ReferencePlane], dict[str | None, Any]]:
    """Ceilings from coverings (their visible undersides), and per storey the xy area they
    cover (shapely)."""
    faces = src.faces
    of_ceil = faces.select((faces.owner >= src.n_floor) & (faces.owner < src.n_ceil))
    planes: list[ReferencePlane] = []
    covered: dict[str | None, Any] = {}
    for h, poly, guids in _visible_planes(of_ceil, False, faces, src.elements, opts):
        st = storey_for_height(model, h, 1.0)
        planes.append(_make_plane(Label.CEILING, h, poly, st, "covering", guids))
        covered[st] = poly if st not in covered else covered[st].union(poly)
    return planes, covered


def _slab_ceilings(src: _PlaneSources, model: BimModel, covered: dict[str | None, Any],
                   opts: PlaneOptions) -> list[ReferencePlane]:
    """Ceilings from the undersides of slabs, where no covering is."""
    faces, elements = src.faces, src.elements
    of_slab = faces.select((faces.owner < src.n_floor) | ((faces.owner >= src.n_ceil)
                                                          & (faces.owner < src.n_slab)))
    slab_owner = np.array([_is_slab(elements[k]) for k in range(len(elements))], bool)
    of_slab = of_slab.select(slab_owner[of_slab.owner]) if len(of_slab.owner) else of_slab
    planes: list[ReferencePlane] = []
    for h, poly, guids in _visible_planes(of_slab, False, faces, elements, opts):
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
    return planes


def _warn_missing_ceilings(model: BimModel, planes: list[ReferencePlane],
                           wall_storeys: set[str]) -> None:
    """A :class:`MissingCeilingWarning` (attributed to the caller of :func:`extract_planes`)
    for each storey with walls and no ceiling plane."""
    ceil_storeys = {p.storey for p in planes if p.kind == Label.CEILING}
    for st in model.storeys:
        if st.name in wall_storeys and st.name not in ceil_storeys:
            warnings.warn(
                f"{model.path.name}: storey {st.name!r} has walls but neither a ceiling covering "
                "nor a slab above it: no ceiling plane",
                MissingCeilingWarning,
                stacklevel=3,
            )


def extract_planes(model: BimModel, opts: PlaneOptions | None = None) -> list[ReferencePlane]:
    """Floor and ceiling planes of every storey (see the module docstring for the conventions).

    Only faces that can be seen become planes: the top faces of floor elements not covered by
    another element resting on them, the bottom faces of ceiling coverings, and the undersides
    of slabs where no covering hangs below them; top and bottom are decided from the solids
    (:func:`oriented_horizontal_faces`), not from the exporter's triangle winding.

    Warns :class:`MissingFloorWarning` for each storey with walls but no floor slab, and
    :class:`MissingCeilingWarning` for each storey with walls and no ceiling at all.
    """
    opts = opts or PlaneOptions()
    src = _plane_sources(model, opts)
    planes = _floor_planes(src, model, opts)
    wall_storeys = {e.storey for e in model.by_label(Label.WALL) if e.storey is not None}
    planes += _missing_floor_planes(model, planes, src, wall_storeys, opts)
    ceilings, covered = _covering_ceilings(src, model, opts)
    planes += ceilings
    planes += _slab_ceilings(src, model, covered, opts)
    _warn_missing_ceilings(model, planes, wall_storeys)
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
