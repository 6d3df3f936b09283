"""A split-level IFC4 house over a basement, with known visible floor and ceiling heights.

Test support (not collected). Plan 8 m x 6 m, walls 0.2 m thick, one interior wall at
x = 4.0..4.2 with a 0.76 m door (x is along the long side)::

    storey "Ground" (elevation 0):
      left room  x 0.2..4.0: structural slab top 0.00 (0.25 thick) under a 0.02 m finish floor
                             (IfcCovering FLOORING, top 0.02); ceiling covering, underside 2.60
      right room x 4.2..7.8: sunken slab top -0.15 (0.25 thick); ceiling = roof slab underside 2.80
      the door sill steps 0.17 m from the finish down to the sunken floor
    storey "Basement" (elevation -3): slab top -3.00; its ceiling is the undersides of the ground
      slabs, -0.25 (left) and -0.40 (right)

Exporters orient the triangles of thin elements inconsistently; this file is written by
IfcOpenShell and is consistent, which is fine: the test of the planes is the hidden surfaces
(the structural slab top 0.00 under the finish, the covering's top 2.62) that must not become
planes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: visible planes: (kind, storey, height)
FLOORS = {("Ground", 0.02), ("Ground", -0.15), ("Basement", -3.0)}
CEILINGS = {("Ground", 2.6), ("Ground", 2.8), ("Basement", -0.25), ("Basement", -0.40)}
LEFT_ROOM = (0.2, 4.0, 0.2, 5.8)  # x0, x1, y0, y1 clear
RIGHT_ROOM = (4.2, 7.8, 0.2, 5.8)
DOOR_X = (4.0, 4.2)
DOOR_Y = (2.5, 3.26)  # a 0.76 m door: its middle is 0.38 m from the jambs


def build_split_level(path: Path) -> Path:
    """Write the house (IFC4, metres) to ``path`` and return it."""
    import ifcopenshell
    from ifcopenshell.api import aggregate, context, feature, geometry, root, spatial, unit

    f = ifcopenshell.file(schema="IFC4")
    project = root.create_entity(f, ifc_class="IfcProject", name="split level")
    unit.assign_unit(f, units=[unit.add_si_unit(f, unit_type="LENGTHUNIT")])
    model = context.add_context(f, context_type="Model")
    body = context.add_context(f, context_type="Model", context_identifier="Body",
                               target_view="MODEL_VIEW", parent=model)
    site = root.create_entity(f, ifc_class="IfcSite", name="Site")
    bld = root.create_entity(f, ifc_class="IfcBuilding", name="Building")
    aggregate.assign_object(f, relating_object=project, products=[site])
    aggregate.assign_object(f, relating_object=site, products=[bld])

    def place(product: object, x: float, y: float, z: float, angle: float = 0.0) -> None:
        m = np.eye(4)
        c, s = np.cos(angle), np.sin(angle)
        m[:2, :2] = [[c, -s], [s, c]]
        m[:3, 3] = (x, y, z)
        geometry.edit_object_placement(f, product=product, matrix=m, is_si=True)

    storeys = {}
    for name, elev in (("Basement", -3.0), ("Ground", 0.0)):
        st = root.create_entity(f, ifc_class="IfcBuildingStorey", name=name)
        st.Elevation = elev
        aggregate.assign_object(f, relating_object=bld, products=[st])
        place(st, 0.0, 0.0, elev)
        storeys[name] = st

    def slab(cls: str, ptype: str, name: str, storey: str, top: float, depth: float,
             outline: list[tuple[float, float]]) -> None:
        el = root.create_entity(f, ifc_class=cls, name=name, predefined_type=ptype)
        place(el, 0.0, 0.0, top - depth)
        rep = geometry.add_slab_representation(f, context=body, depth=depth, polyline=outline)
        geometry.assign_representation(f, product=el, representation=rep)
        spatial.assign_container(f, relating_structure=storeys[storey], products=[el])

    def rect(x0: float, x1: float, y0: float, y1: float) -> list[tuple[float, float]]:
        return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]

    def wall(storey: str, name: str, x: float, y: float, angle: float, length: float, z0: float,
             height: float, door: tuple[float, float, float] | None = None) -> None:
        w = root.create_entity(f, ifc_class="IfcWall", name=name)
        place(w, x, y, z0, angle)
        rep = geometry.add_wall_representation(f, context=body, length=length, height=height,
                                               thickness=0.2)
        geometry.assign_representation(f, product=w, representation=rep)
        spatial.assign_container(f, relating_structure=storeys[storey], products=[w])
        if door is not None:
            a, b, h = door
            c, s = np.cos(angle), np.sin(angle)
            op = root.create_entity(f, ifc_class="IfcOpeningElement")
            place(op, x + c * a + s * 0.1, y + s * a - c * 0.1, z0, angle)
            rep = geometry.add_wall_representation(f, context=body, length=b - a, height=h,
                                                   thickness=0.4)
            geometry.assign_representation(f, product=op, representation=rep)
            feature.add_feature(f, feature=op, element=w)
            d = root.create_entity(f, ifc_class="IfcDoor", name=f"{name} door")
            place(d, x + c * a - s * 0.075, y + s * a + c * 0.075, z0, angle)
            rep = geometry.add_wall_representation(f, context=body, length=b - a, height=h,
                                                   thickness=0.05)
            geometry.assign_representation(f, product=d, representation=rep)
            spatial.assign_container(f, relating_structure=storeys[storey], products=[d])

    # basement
    slab("IfcSlab", "BASESLAB", "basement slab", "Basement", -3.0, 0.2, rect(0, 8, 0, 6))
    for name, z0, h in (("Basement", -3.0, 2.75), ("Ground", -0.15, 2.95)):
        wall(name, "south", 0.0, 0.0, 0.0, 8.0, z0, h)
        wall(name, "north", 0.0, 5.8, 0.0, 8.0, z0, h)
        wall(name, "west", 0.2, 0.2, np.pi / 2, 5.6, z0, h)
        wall(name, "east", 8.0, 0.2, np.pi / 2, 5.6, z0, h)
    # ground: split-level slabs, a finish floor, the interior wall with its door, ceilings
    slab("IfcSlab", "FLOOR", "left slab", "Ground", 0.0, 0.25, rect(0, 4.1, 0, 6))
    slab("IfcSlab", "FLOOR", "sunken slab", "Ground", -0.15, 0.25, rect(4.1, 8, 0, 6))
    slab("IfcCovering", "FLOORING", "finish", "Ground", 0.02, 0.02, rect(*LEFT_ROOM))
    wall("Ground", "interior", 4.2, 0.2, np.pi / 2, 5.6, -0.15, 2.95,
         door=(DOOR_Y[0] - 0.2, DOOR_Y[1] - 0.2, 2.25))
    slab("IfcCovering", "CEILING", "ceiling", "Ground", 2.62, 0.02, rect(*LEFT_ROOM))
    slab("IfcSlab", "ROOF", "roof", "Ground", 3.0, 0.2, rect(0, 8, 0, 6))
    f.write(str(path))
    return path
