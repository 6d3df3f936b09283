"""A minimal two-storey IFC4 building with known geometry, written with ``ifcopenshell.api``.

Test support for ``tests/test_bim_*.py`` (not collected: the name does not start with ``test_``).
Every wall is a box in its own frame (x along the wall, y across its thickness, z up) placed by a
rotation about z; the whole site can be rotated by ``site_angle_deg`` so that no wall is
axis-aligned. The known wall faces at a cut height are returned in world metres, with door gaps.

Layout of each storey (before the site rotation), walls 0.2 m thick::

    y=6 +------------------------------+
        |            |                 |
        |  [] col    D  door     O col  |      [] 0.3 x 0.3 m column at (2, 3)
        |            |                 |      O  round column r = 0.15 m at (6, 3)
    y=0 +--------------WWW-------------+      WWW window in the south wall, x 5..6.5 m
        x=0         x=4               x=8

Storey k has elevation 3k m: floor slab top at 3k (0.2 m thick), walls from 3k to 3k + 2.8, the
next slab (or the roof slab) from 3k + 2.8 to 3k + 3.0. Storey 0 has a ceiling covering (underside
2.6 m) over the left room only; elsewhere the ceiling is the underside of the slab above.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

THICK = 0.2
STOREY_H = 3.0
WALL_H = 2.8
DOOR = (2.0, 2.9, 2.1)  # interior wall door: from, to (along the wall), height
WINDOW = (5.0, 6.5, 0.9, 2.1)  # south wall window: from, to, sill, head


@dataclass
class SimpleBuilding:
    """What the test knows about the building (world metres, after the site rotation).

    Attributes
    ----------
    path: the IFC file. site_from_local: (3, 3) homogeneous 2-D transform of the site.
    walls: per storey, list of (wall_from_local (3, 3), length, openings [(a, b, z0, z1)]).
    columns_rect / columns_round: centres (x, y) before the site rotation.
    floor_tops, ceiling_cover, slab_undersides: known heights.
    """

    path: Path
    site_from_local: NDArray[np.float64]
    walls: list[list[tuple[NDArray[np.float64], float, list[tuple[float, float, float, float]]]]]
    n_storeys: int
    columns_rect: list[tuple[float, float]] = field(default_factory=list)
    columns_round: list[tuple[float, float]] = field(default_factory=list)

    def wall_faces(self, storey: int, z_rel: float) -> NDArray[np.float64]:
        """(K, 4) known wall face segments ``x1 y1 x2 y2`` at height ``z_rel`` above the storey."""
        out = []
        for m, length, openings in self.walls[storey]:
            cuts = sorted((a, b) for a, b, z0, z1 in openings if z0 < z_rel < z1)
            pieces, start = [], 0.0
            for a, b in cuts:
                pieces.append((start, a))
                start = b
            pieces.append((start, length))
            local = []
            for a, b in pieces:
                local += [(a, 0, b, 0), (a, THICK, b, THICK), (a, 0, a, THICK), (b, 0, b, THICK)]
            for x1, y1, x2, y2 in local:
                p = self.site_from_local @ m @ np.array([[x1, x2], [y1, y2], [1.0, 1.0]])
                out.append([p[0, 0], p[1, 0], p[0, 1], p[1, 1]])
        return np.asarray(out)

    def column_faces(self) -> NDArray[np.float64]:
        """(4 * n, 4) faces of the rectangular columns (0.3 m squares)."""
        out = []
        for cx, cy in self.columns_rect:
            c = np.array([[cx - 0.15, cy - 0.15], [cx + 0.15, cy - 0.15],
                          [cx + 0.15, cy + 0.15], [cx - 0.15, cy + 0.15]])
            for i in range(4):
                a, b = c[i], c[(i + 1) % 4]
                pa = self.site_from_local @ np.array([a[0], a[1], 1.0])
                pb = self.site_from_local @ np.array([b[0], b[1], 1.0])
                out.append([pa[0], pa[1], pb[0], pb[1]])
        return np.asarray(out)


def _rot2(angle: float, tx: float = 0.0, ty: float = 0.0) -> NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, tx], [s, c, ty], [0.0, 0.0, 1.0]])


def build_simple_building(
    path: Path,
    *,
    site_angle_deg: float = 0.0,
    n_storeys: int = 2,
    with_slabs: bool = True,
    with_walls: bool = True,
) -> SimpleBuilding:
    """Write the building to ``path`` (IFC4, metres) and return what is known about it."""
    import ifcopenshell
    from ifcopenshell.api import aggregate, context, feature, geometry, root, spatial, unit

    f = ifcopenshell.file(schema="IFC4")
    project = root.create_entity(f, ifc_class="IfcProject", name="bimcap simple building")
    unit.assign_unit(f, units=[unit.add_si_unit(f, unit_type="LENGTHUNIT")])
    model = context.add_context(f, context_type="Model")
    body = context.add_context(f, context_type="Model", context_identifier="Body",
                               target_view="MODEL_VIEW", parent=model)
    site = root.create_entity(f, ifc_class="IfcSite", name="Site")
    angle = np.deg2rad(site_angle_deg)
    site_m = _rot2(angle, 10.0, -5.0)
    m4 = np.eye(4)
    m4[:2, :2] = site_m[:2, :2]
    m4[:2, 3] = site_m[:2, 2]
    geometry.edit_object_placement(f, product=site, matrix=m4, is_si=True)
    bld = root.create_entity(f, ifc_class="IfcBuilding", name="Building")
    aggregate.assign_object(f, relating_object=project, products=[site])
    aggregate.assign_object(f, relating_object=site, products=[bld])
    geometry.edit_object_placement(f, product=bld, matrix=m4, is_si=True)

    def place(product: object, m2: NDArray[np.float64], z: float, parent: object) -> None:
        m = np.eye(4)
        full = site_m @ m2
        m[:2, :2] = full[:2, :2]
        m[:2, 3] = full[:2, 2]
        m[2, 3] = z
        geometry.edit_object_placement(f, product=product, matrix=m, is_si=True)

    # Wall frames: (x0, y0, angle) of the local origin, length.
    wall_defs = [
        (_rot2(0.0, 0.0, 0.0), 8.0, "south"),
        (_rot2(0.0, 0.0, 6.0 - THICK), 8.0, "north"),
        (_rot2(np.pi / 2, THICK, THICK), 6.0 - 2 * THICK, "west"),
        (_rot2(np.pi / 2, 8.0, THICK), 6.0 - 2 * THICK, "east"),
        (_rot2(np.pi / 2, 4.0 + THICK / 2, THICK), 6.0 - 2 * THICK, "interior"),
    ]
    walls_known = []
    storeys = []
    for k in range(n_storeys):
        z0 = STOREY_H * k
        st = root.create_entity(f, ifc_class="IfcBuildingStorey", name=f"Storey {k}")
        st.Elevation = z0
        aggregate.assign_object(f, relating_object=bld, products=[st])
        place(st, np.eye(3), z0, bld)
        storeys.append(st)
        known = []
        if with_walls:
            for m2, length, name in wall_defs:
                w = root.create_entity(f, ifc_class="IfcWall", name=f"{name} {k}")
                place(w, m2, z0, st)
                rep = geometry.add_wall_representation(f, context=body, length=length,
                                                       height=WALL_H, thickness=THICK)
                geometry.assign_representation(f, product=w, representation=rep)
                spatial.assign_container(f, relating_structure=st, products=[w])
                openings = []
                if name == "interior":
                    openings.append((DOOR[0], DOOR[1], 0.0, DOOR[2]))
                if name == "south":
                    openings.append((WINDOW[0], WINDOW[1], WINDOW[2], WINDOW[3]))
                for a, b, oz0, oz1 in openings:
                    op = root.create_entity(f, ifc_class="IfcOpeningElement")
                    place(op, m2 @ _rot2(0.0, a, -0.1), z0 + oz0, w)
                    rep = geometry.add_wall_representation(f, context=body, length=b - a,
                                                           height=oz1 - oz0, thickness=THICK + 0.2)
                    geometry.assign_representation(f, product=op, representation=rep)
                    feature.add_feature(f, feature=op, element=w)
                    cls = "IfcDoor" if oz0 == 0.0 else "IfcWindow"
                    el = root.create_entity(f, ifc_class=cls)
                    place(el, m2 @ _rot2(0.0, a, THICK / 2 - 0.025), z0 + oz0, st)
                    rep = geometry.add_wall_representation(f, context=body, length=b - a,
                                                           height=oz1 - oz0, thickness=0.05)
                    geometry.assign_representation(f, product=el, representation=rep)
                    spatial.assign_container(f, relating_structure=st, products=[el])
                known.append((m2, length, openings))
            for cx, cy, prof in [
                (2.0, 3.0, f.create_entity("IfcRectangleProfileDef", ProfileType="AREA",
                                           XDim=0.3, YDim=0.3)),
                (6.0, 3.0, f.create_entity("IfcCircleProfileDef", ProfileType="AREA",
                                           Radius=0.15)),
            ]:
                col = root.create_entity(f, ifc_class="IfcColumn", name=f"column {k}")
                place(col, _rot2(0.0, cx, cy), z0, st)
                rep = geometry.add_profile_representation(f, context=body, profile=prof,
                                                          depth=WALL_H)
                geometry.assign_representation(f, product=col, representation=rep)
                spatial.assign_container(f, relating_structure=st, products=[col])
        walls_known.append(known)

    outline = [(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)]
    if with_slabs:
        for k in range(n_storeys + 1):
            top = STOREY_H * k
            ptype = "BASESLAB" if k == 0 else ("ROOF" if k == n_storeys else "FLOOR")
            sl = root.create_entity(f, ifc_class="IfcSlab", name=f"slab {k}",
                                    predefined_type=ptype)
            st = storeys[min(k, n_storeys - 1)]
            place(sl, np.eye(3), top - 0.2, st)
            rep = geometry.add_slab_representation(f, context=body, depth=0.2, polyline=outline)
            geometry.assign_representation(f, product=sl, representation=rep)
            spatial.assign_container(f, relating_structure=st, products=[sl])
        cov = root.create_entity(f, ifc_class="IfcCovering", name="ceiling",
                                 predefined_type="CEILING")
        place(cov, np.eye(3), 2.6, storeys[0])
        rep = geometry.add_slab_representation(
            f, context=body, depth=0.02,
            polyline=[(THICK, THICK), (4.0, THICK), (4.0, 6.0 - THICK), (THICK, 6.0 - THICK)],
        )
        geometry.assign_representation(f, product=cov, representation=rep)
        spatial.assign_container(f, relating_structure=storeys[0], products=[cov])
    f.write(str(path))
    return SimpleBuilding(
        path=path,
        site_from_local=site_m,
        walls=walls_known,
        n_storeys=n_storeys,
        columns_rect=[(2.0, 3.0)] if with_walls else [],
        columns_round=[(6.0, 3.0)] if with_walls else [],
    )


def dist_to_segments(p: np.ndarray, segs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of points (P, 2) to segments (S, 4) and the index of the nearest one (brute
    force: the tests' own oracle)."""
    a, b = segs[:, :2], segs[:, 2:]
    ab = b - a
    t = np.clip(((p[:, None] - a[None]) * ab[None]).sum(-1) / (ab * ab).sum(-1)[None], 0, 1)
    d = np.linalg.norm(p[:, None] - (a[None] + t[..., None] * ab[None]), axis=-1)
    return d.min(axis=1), d.argmin(axis=1)
