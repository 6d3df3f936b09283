"""IFC ingest: open any IFC2X3 / IFC4 file and tessellate its elements in world metres.

Every element with a body becomes a :class:`BimElement` holding a triangle mesh in the IFC's own
frame (z up) converted to **metres**, whatever the file's length unit, plus its semantic
:class:`~bimcap.labels.Label` and the storey that contains it. IfcOpenShell's geometry iterator
returns metres by default (``convert-back-units`` is off); storey ``Elevation`` attributes are in
the file's unit and are scaled with :func:`ifcopenshell.util.unit.calculate_unit_scale`.

Classes (bimcap.labels):

=========================================  ================
IFC class                                   label
=========================================  ================
IfcWall, IfcWallStandardCase, IfcCurtainWall  WALL (curtain-wall parts too)
IfcColumn                                    COLUMN
IfcSlab FLOOR / BASESLAB / LANDING / unset   FLOOR
IfcCovering CEILING                          CEILING
IfcCovering FLOORING                         FLOOR
IfcDoor / IfcWindow                          DOOR / WINDOW
IfcBuildingElementProxy named as a wall      WALL (when its shape is a wall's, see below)
IfcBuildingElementProxy named as a column    COLUMN (when its shape is a column's)
anything else (stairs, beams, roofs, ...)    UNKNOWN ("other")
=========================================  ================

Some exports write every element as ``IfcBuildingElementProxy`` (SketchUp, Revit or ArchiCAD
with a generic mapping). Such a proxy is a wall when its ``Name``, ``ObjectType`` or type's name
says so (:data:`PROXY_WALL_WORDS`: "Basic Wall:…", "Wand-Ext-…", "mur", "muro" …; not a
"wall cabinet", :data:`PROXY_NOT_WALL_WORDS`) and its mesh is a wall's
(:func:`proxy_shape_agrees`: at least 0.2 m tall, at most 1 m thick, at least twice as long as
thick), likewise a column (:data:`PROXY_COLUMN_WORDS`; at least 1 m tall, at most 1.5 m
across). What was taken is a :class:`ProxyElementWarning` and a line of :attr:`BimModel.notes`.

Walls come tessellated with their openings already cut; doors and windows are their own elements.
Elements that fail to tessellate are listed in :attr:`BimModel.failed` by GUID and skipped.

Loading also checks that the model is usable (issue 12), and says what it did:

* **Damage.** The file's text is scanned for its entity instances (``#N=CLASS(...)``) and the
  instances they reference. Instances IfcOpenShell could not read (a malformed line, an unknown
  class), references to instances that are missing (a cut file with the trailer re-appended) and
  elements whose geometry failed are counted per element (:class:`ModelDamage`). More than
  ``max_lost_fraction`` of the building elements lost is a :class:`BimInputError` with the
  counts; any smaller loss a :class:`DamagedModelWarning` with the counts. A damaged file is
  tessellated in one thread, element by element where IfcOpenShell's iterator gives up.
* **Storey heights.** A storey's height is its ``Elevation`` when that agrees (within
  :data:`STOREY_TOLERANCE_M`) with the height its own walls (or slabs) stand at, else its
  placement's world z when that agrees, else the geometry's (a georeferenced model moved up,
  a wrong attribute); a model without ``IfcBuildingStorey`` gets levels from the heights of its
  wall bases. Each correction is a :class:`StoreyHeightWarning`.
* **Units.** A median wall height outside :data:`WALL_HEIGHT_RANGE_M` means the length unit is
  wrong (a prefix changed without rescaling the coordinates): a :class:`BimInputError` naming
  the unit.
"""

from __future__ import annotations

import multiprocessing
import os
import re
import warnings
from collections import Counter
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.bim.errors import (
    BimInputError,
    DamagedModelWarning,
    ProxyElementWarning,
    StoreyHeightWarning,
)
from bimcap.labels import Label

#: IFC classes never tessellated as elements (voids, and spaces which are read separately).
EXCLUDED_CLASSES: tuple[str, ...] = ("IfcOpeningElement", "IfcSpace", "IfcAnnotation", "IfcGrid")

#: A storey's Elevation (or placement z) further than this from the height its own walls stand
#: at is replaced by the geometry's height (metres).
STOREY_TOLERANCE_M = 1.0
#: Without IfcBuildingStorey, wall bases further apart than this start a new level (metres).
LEVEL_GAP_M = 1.5
#: Plausible median wall height in metres; outside it the file's length unit is wrong.
WALL_HEIGHT_RANGE_M = (0.3, 50.0)
#: Default largest share of the building elements a damaged file may lose (load_model).
DEFAULT_MAX_LOST_FRACTION = 0.02

_WALL_CLASSES = ("IfcWall", "IfcCurtainWall")  # IfcWall covers StandardCase/ElementedCase
_FLOOR_SLAB_TYPES = {"FLOOR", "BASESLAB", "LANDING", "NOTDEFINED", "USERDEFINED", None}
_PROXY_CLASS = "IfcBuildingElementProxy"
#: Words that name a wall in a proxy's Name / ObjectType / type name (English, German compounds
#: "Außenwand", French, Spanish, Italian, Dutch), case-insensitive.
PROXY_WALL_WORDS = re.compile(r"wall|wand\b|wand[-_ :]|mauer|\bmurs?\b|\bmuros?\b|\bparet[ei]\b"
                              r"|\bmuur\b", re.IGNORECASE)
#: Words that make a proxy named as a wall something else: a fixture or furniture on a wall.
PROXY_NOT_WALL_WORDS = re.compile(r"cabinet|cupboard|shelf|shelv|schrank|regal|lamp|light|"
                                  r"socket|outlet|switch|paper|tapete|bracket|clock|mount|"
                                  r"armoire|placard|sink|basin|heater|radiator", re.IGNORECASE)
#: Words that name a column (a pillar, a post) in a proxy's names, case-insensitive.
PROXY_COLUMN_WORDS = re.compile(r"column|st(ü|ue)tze|\bpillar|\bpilar|\bpilier|\bpoteau"
                                r"|\bcolonn[ae]|\bkolom", re.IGNORECASE)


@dataclass(frozen=True)
class Storey:
    """A building storey.

    Attributes
    ----------
    name: the storey's ``Name`` (or its GUID when unnamed); used as the storey key everywhere.
    elevation_m: ``Elevation`` in metres (the storey placement's z when the attribute is unset).
    guid: the storey's GlobalId.
    """

    name: str
    elevation_m: float
    guid: str

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "elevation_m": self.elevation_m, "guid": self.guid}


@dataclass
class ModelDamage:
    """What a damaged IFC file lost (counts; see :func:`load_model`).

    Attributes
    ----------
    instances: entity instances written in the file (``#N=...``).
    unread: instances IfcOpenShell could not read, per class name as written in the file.
    dangling: ids that instances reference but no instance defines (a cut file).
    parser_messages: errors and warnings IfcOpenShell logged while reading the file.
    elements_total: building elements (IfcElement except openings) read, plus those lost unread
        or missing.
    elements_unread: elements among the unread instances (by class, or listed in the spatial
        structure).
    elements_missing: elements the spatial structure (IfcRelContainedInSpatialStructure) lists
        but no instance defines.
    elements_failed: elements read whose tessellation produced no geometry.
    examples: a few of the lost instances, e.g. ``"#15042 IFCWALLXX (unread)"``.
    """

    instances: int
    unread: dict[str, int]
    dangling: int
    parser_messages: int
    elements_total: int
    elements_unread: int
    elements_missing: int
    elements_failed: int = 0
    examples: list[str] = field(default_factory=list)

    @property
    def elements_lost(self) -> int:
        return self.elements_unread + self.elements_missing + self.elements_failed

    @property
    def lost_fraction(self) -> float:
        """Share of the building elements lost."""
        return self.elements_lost / max(self.elements_total, 1)

    @property
    def any(self) -> bool:
        return bool(self.unread or self.dangling or self.elements_lost or self.parser_messages)

    def describe(self) -> str:
        """One line with every count."""
        unread = sum(self.unread.values())
        top = ", ".join(f"{k} {v}" for k, v in Counter(self.unread).most_common(4))
        parts = [
            f"lost {self.elements_lost} of {self.elements_total} building elements "
            f"({100 * self.lost_fraction:.1f} %: {self.elements_unread} unreadable, "
            f"{self.elements_missing} missing from the file, {self.elements_failed} without "
            "geometry)",
            f"{unread} of {self.instances} instances IfcOpenShell could not read"
            + (f" ({top})" if top else ""),
            f"{self.dangling} references to instances that are not in the file",
        ]
        if self.parser_messages:
            parts.append(f"{self.parser_messages} parser messages")
        if self.examples:
            parts.append("e.g. " + ", ".join(self.examples[:4]))
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        return {
            "instances": self.instances, "unread": dict(self.unread), "dangling": self.dangling,
            "parser_messages": self.parser_messages, "elements_total": self.elements_total,
            "elements_unread": self.elements_unread, "elements_missing": self.elements_missing,
            "elements_failed": self.elements_failed, "elements_lost": self.elements_lost,
            "lost_fraction": self.lost_fraction, "examples": list(self.examples),
        }


@dataclass
class BimElement:
    """One tessellated IFC element.

    Attributes
    ----------
    guid: IFC GlobalId.
    ifc_class: e.g. ``"IfcWallStandardCase"``.
    label: semantic class (:class:`~bimcap.labels.Label`; UNKNOWN = "other").
    storey: name of the containing storey, or None.
    vertices: (V, 3) float64, world coordinates in metres.
    faces: (F, 3) int32 vertex indices, outward-facing triangles as IfcOpenShell orders them.
    predefined_type: the IFC PredefinedType (e.g. ``"FLOOR"``, ``"CEILING"``) or None.
    name: the element's ``Name`` or "".
    """

    guid: str
    ifc_class: str
    label: Label
    storey: str | None
    vertices: NDArray[np.float64]
    faces: NDArray[np.int32]
    predefined_type: str | None = None
    name: str = ""

    @property
    def zmin(self) -> float:
        return float(self.vertices[:, 2].min())

    @property
    def zmax(self) -> float:
        return float(self.vertices[:, 2].max())


@dataclass
class BimModel:
    """A tessellated IFC model in metres.

    Attributes
    ----------
    path: the IFC file.
    schema: ``"IFC2X3"``, ``"IFC4"`` ...
    unit_scale: metres per file length unit (0.001 for millimetre files).
    elements: every tessellated element (spaces excluded).
    storeys: sorted by elevation.
    failed: ``(guid, reason)`` of elements that have a body but could not be tessellated.
    spaces: tessellated IfcSpace volumes (label UNKNOWN), read only when ``load_spaces`` is set.
    damage: what a damaged file lost (None for an intact file).
    notes: what loading corrected (storey heights from the geometry ...), one line each.
    """

    path: Path
    schema: str
    unit_scale: float
    elements: list[BimElement]
    storeys: list[Storey]
    failed: list[tuple[str, str]] = field(default_factory=list)
    spaces: list[BimElement] = field(default_factory=list)
    damage: ModelDamage | None = None
    notes: list[str] = field(default_factory=list)

    def by_label(self, *labels: Label) -> list[BimElement]:
        """The elements whose label is one of ``labels``."""
        wanted = set(labels)
        return [e for e in self.elements if e.label in wanted]

    def mesh(self, *labels: Label) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
        """All elements of ``labels`` (all elements when none given) as one mesh.

        Returns
        -------
        vertices: (V, 3) float64 metres; faces: (F, 3) int32.
        """
        elems = self.by_label(*labels) if labels else self.elements
        return concatenate_meshes(elems)

    def counts(self) -> dict[str, int]:
        """Number of elements per label name (``"other"`` for UNKNOWN)."""
        out: dict[str, int] = {}
        for e in self.elements:
            key = label_name(e.label)
            out[key] = out.get(key, 0) + 1
        return out

    def storey_index(self, name: str) -> int:
        for i, s in enumerate(self.storeys):
            if s.name == name:
                return i
        raise KeyError(name)


def label_name(label: Label) -> str:
    """Lower-case class name of a label, ``"other"`` for UNKNOWN."""
    return "other" if label == Label.UNKNOWN else label.name.lower()


def concatenate_meshes(
    elements: list[BimElement],
) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """Concatenate element meshes into one (V, 3) float64 / (F, 3) int32 mesh."""
    if not elements:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)
    offsets = np.cumsum([0] + [len(e.vertices) for e in elements[:-1]])
    verts = np.concatenate([e.vertices for e in elements])
    faces = np.concatenate(
        [e.faces + off for e, off in zip(elements, offsets, strict=True)]
    ).astype(np.int32)
    return verts, faces


def check_ifc_file(path: Path) -> None:
    """Raise :class:`BimInputError` unless ``path`` looks like a complete IFC STEP file.

    Checks the ``ISO-10303-21;`` header and the ``END-ISO-10303-21;`` trailer, so that a
    truncated download is caught before IfcOpenShell silently reads half a model.
    """
    if not path.exists():
        raise BimInputError("file not found", path)
    if not path.is_file():
        raise BimInputError("not a file", path)
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(64).lstrip(b"\xef\xbb\xbf \t\r\n")
        fh.seek(max(0, size - 4096))
        tail = fh.read()
    if not head.startswith(b"ISO-10303-21"):
        raise BimInputError(
            "not an IFC STEP file (IFC-SPF): the 'ISO-10303-21;' header is missing", path, "header"
        )
    if b"END-ISO-10303-21" not in tail:
        raise BimInputError(
            "truncated IFC file: the 'END-ISO-10303-21;' trailer is missing", path, "trailer"
        )


def classify(element: Any, parent: Any | None = None) -> Label:
    """The semantic label of an IFC entity (``parent``: the element it is a part of, if any)."""
    import ifcopenshell.util.element as ue

    if parent is not None and parent.is_a("IfcCurtainWall"):
        return Label.WALL
    if any(element.is_a(c) for c in _WALL_CLASSES):
        return Label.WALL
    if element.is_a("IfcColumn"):
        return Label.COLUMN
    if element.is_a("IfcDoor"):
        return Label.DOOR
    if element.is_a("IfcWindow"):
        return Label.WINDOW
    if element.is_a(_PROXY_CLASS):
        return _proxy_label(element)
    ptype = ue.get_predefined_type(element)
    if element.is_a("IfcSlab"):
        return Label.FLOOR if ptype in _FLOOR_SLAB_TYPES else Label.UNKNOWN
    if element.is_a("IfcCovering"):
        if ptype == "CEILING":
            return Label.CEILING
        if ptype == "FLOORING":
            return Label.FLOOR
    return Label.UNKNOWN


def _proxy_names(element: Any) -> str:
    """A proxy's Name, ObjectType and its type object's Name, joined (for the word lists)."""
    import ifcopenshell.util.element as ue

    names = [getattr(element, "Name", None), getattr(element, "ObjectType", None)]
    try:
        typ = ue.get_type(element)
    except Exception:  # a damaged type relation: the element's own names decide
        typ = None
    if typ is not None:
        names.append(getattr(typ, "Name", None))
    return " | ".join(str(n) for n in names if n)


def _proxy_label(element: Any) -> Label:
    """WALL / COLUMN for an IfcBuildingElementProxy its names call so, else UNKNOWN (the shape
    is checked after tessellation, :func:`proxy_shape_agrees`)."""
    names = _proxy_names(element)
    if PROXY_WALL_WORDS.search(names) and not PROXY_NOT_WALL_WORDS.search(names):
        return Label.WALL
    if PROXY_COLUMN_WORDS.search(names):
        return Label.COLUMN
    return Label.UNKNOWN


def proxy_shape_agrees(label: Label, vertices: NDArray[np.float64],
                       faces: NDArray[np.int32]) -> bool:
    """Whether a mesh has the shape of a ``label`` (WALL or COLUMN) element.

    The mesh is read as the box of the same volume and side area: with ``V`` its volume and
    ``S`` the area of its vertical faces, a wall ``L`` long, ``T`` thick and ``H`` tall has
    ``S = 2 (L + T) H`` and ``V = L T H``, so ``T`` and ``L`` follow from ``V / H`` and
    ``S / 2H`` (an L-shaped wall or one with openings reads as its unfolded length). A wall:
    ``H ≥ 0.2 m`` (parapets and knee walls are walls), ``T ≤ 1 m``, ``L ≥ 2 T``; a column:
    ``H ≥ 1 m``, ``L ≤ 1.5 m``.

    vertices: (V, 3) metres; faces: (F, 3) vertex indices.
    """
    if len(faces) == 0:
        return False
    height = float(np.ptp(vertices[:, 2]))
    if height < (1.0 if label == Label.COLUMN else 0.2):
        return False
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    vertical = np.abs(cross[:, 2]) < 0.1 * np.linalg.norm(cross, axis=1)
    side_area = float(area[vertical].sum())
    centred = tri - vertices.mean(axis=0)
    volume = abs(float(np.einsum("ij,ij->i", centred[:, 0],
                                 np.cross(centred[:, 1], centred[:, 2])).sum())) / 6.0
    half_perimeter = side_area / (2.0 * height)  # L + T
    footprint = volume / height  # L T
    disc = half_perimeter**2 - 4.0 * footprint
    if disc < 0.0:  # a square section (L = T): the roots meet
        disc = 0.0
    length = 0.5 * (half_perimeter + disc**0.5)
    thickness = 0.5 * (half_perimeter - disc**0.5)
    if label == Label.COLUMN:
        return length <= 1.5
    return thickness <= 1.0 and length >= 2.0 * thickness


def _storey_of(
    element: Any, cache: dict[int, str | None], storey_names: dict[int, str]
) -> str | None:
    """Name of the storey containing ``element`` (through spaces and aggregates), or None."""
    import ifcopenshell.util.element as ue

    key = element.id()
    if key in cache:
        return cache[key]
    result: str | None = None
    node = element
    for _ in range(16):
        container = ue.get_container(node)
        if container is None:
            container = ue.get_aggregate(node)
        if container is None:
            break
        if container.is_a("IfcBuildingStorey"):
            result = storey_names.get(container.id())
            break
        node = container
    cache[key] = result
    return result


@dataclass(frozen=True)
class _StoreyRecord:
    """A storey as the file states it: ``Elevation`` and placement z in metres (None if unset)."""

    name: str
    guid: str
    attribute_m: float | None
    placement_m: float | None

    @property
    def stated_m(self) -> float:
        """The height bimcap used before looking at the geometry: Elevation, else placement z."""
        if self.attribute_m is not None:
            return self.attribute_m
        return self.placement_m if self.placement_m is not None else 0.0


def _read_storey_records(ifc: Any, unit_scale: float) -> list[_StoreyRecord]:
    import ifcopenshell.util.placement as up

    records = []
    for st in ifc.by_type("IfcBuildingStorey"):
        attribute = float(st.Elevation) * unit_scale if st.Elevation is not None else None
        placement = None
        if st.ObjectPlacement is not None:
            try:
                placement = float(up.get_local_placement(st.ObjectPlacement)[2, 3]) * unit_scale
            except Exception:  # a damaged placement: the attribute is all there is
                placement = None
        records.append(_StoreyRecord(st.Name or st.GlobalId, st.GlobalId, attribute, placement))
    return records


def _unique_storeys(storeys: list[Storey]) -> list[Storey]:
    """Sorted by elevation; duplicate names made unique (storey names are keys)."""
    storeys = sorted(storeys, key=lambda s: s.elevation_m)
    seen: dict[str, int] = {}
    unique = []
    for s in storeys:
        n = seen.get(s.name, 0)
        seen[s.name] = n + 1
        unique.append(s if n == 0 else Storey(f"{s.name} ({n + 1})", s.elevation_m, s.guid))
    return unique


def _geometry_height(elements: list[BimElement]) -> tuple[float | None, str]:
    """The height a storey's own elements stand at: the median base of its walls and columns,
    else the median top of its floor slabs; None without either."""
    bases = [e.zmin for e in elements if e.label in (Label.WALL, Label.COLUMN) and len(e.vertices)]
    if bases:
        return float(np.median(bases)), f"its {len(bases)} walls/columns stand at"
    tops = [e.zmax for e in elements if e.label == Label.FLOOR and len(e.vertices)]
    if tops:
        return float(np.median(tops)), f"its {len(tops)} floor slabs' tops are at"
    return None, ""


def reconcile_storeys(
    records: list[_StoreyRecord], elements: list[BimElement], path: Path
) -> tuple[list[Storey], list[str]]:
    """Storey heights that agree with the geometry, and one note per correction.

    For each storey with walls, columns or floor slabs of its own: its ``Elevation`` when within
    :data:`STOREY_TOLERANCE_M` of the height they stand at, else its placement's world z when
    that is, else that height. A storey without such elements keeps its ``Elevation`` unless the
    others had to be corrected: then it takes its placement z when the others did, else its
    ``Elevation`` shifted by the others' median correction.
    """
    by_storey: dict[str, list[BimElement]] = {}
    for e in elements:
        if e.storey is not None:
            by_storey.setdefault(e.storey, []).append(e)
    chosen: dict[str, tuple[float, str]] = {}
    notes: list[str] = []
    for r in records:
        g, what = _geometry_height(by_storey.get(r.name, []))
        if g is None:
            continue
        if r.attribute_m is not None and abs(r.attribute_m - g) <= STOREY_TOLERANCE_M:
            chosen[r.name] = (r.attribute_m, "attribute")
            continue
        if r.placement_m is not None and abs(r.placement_m - g) <= STOREY_TOLERANCE_M:
            chosen[r.name] = (r.placement_m, "placement")
            how = f"its placement's height {r.placement_m:.3f} m"
        else:
            chosen[r.name] = (g, "geometry")
            how = f"the geometry's {g:.3f} m"
        stated = "no Elevation" if r.attribute_m is None else f"Elevation {r.attribute_m:.3f} m"
        notes.append(f"{path.name}: storey {r.name!r}: {stated}, but {what} {g:.3f} m; "
                     f"using {how}")
    corrected = [r for r in records if r.name in chosen and chosen[r.name][1] != "attribute"]
    offsets = [chosen[r.name][0] - r.attribute_m for r in corrected if r.attribute_m is not None]
    use_placement = bool(corrected) and all(chosen[r.name][1] == "placement" for r in corrected)
    storeys = []
    for r in records:
        if r.name in chosen:
            z = chosen[r.name][0]
        elif corrected and use_placement and r.placement_m is not None:
            z = r.placement_m
            notes.append(f"{path.name}: storey {r.name!r} (no walls or slabs of its own): using "
                         f"its placement's height {z:.3f} m like the other storeys")
        elif corrected and offsets and r.attribute_m is not None:
            z = r.attribute_m + float(np.median(offsets))
            notes.append(f"{path.name}: storey {r.name!r} (no walls or slabs of its own): "
                         f"Elevation shifted by the other storeys' correction to {z:.3f} m")
        else:
            z = r.stated_m
        storeys.append(Storey(r.name, z, r.guid))
    return _unique_storeys(storeys), notes


def levels_from_geometry(elements: list[BimElement], path: Path) -> tuple[list[Storey], list[str]]:
    """Storeys for a model without ``IfcBuildingStorey``: the bases of its walls and columns
    grouped into levels wherever consecutive bases are more than :data:`LEVEL_GAP_M` apart, each
    at its group's median base; every element without a storey goes to the highest level at or
    below its base (+0.5 m)."""
    bases = np.sort([e.zmin for e in elements if e.label in (Label.WALL, Label.COLUMN)])
    if len(bases) == 0:
        return [], []
    groups = np.split(bases, np.flatnonzero(np.diff(bases) > LEVEL_GAP_M) + 1)
    storeys = [Storey(f"Level {k + 1} (from geometry)", float(np.median(g)),
                      f"{GEOMETRY_LEVEL_PREFIX}{k + 1}")
               for k, g in enumerate(groups)]
    assign_by_height(elements, storeys)
    described = ", ".join(f"{st.name} at {st.elevation_m:.3f} m ({len(g)} walls/columns)"
                          for st, g in zip(storeys, groups, strict=True))
    note = (f"{path.name}: the model has no IfcBuildingStorey; {len(storeys)} level(s) from the "
            f"heights of its wall bases: {described}")
    return storeys, [note]


def assign_by_height(elements: list[BimElement], storeys: list[Storey]) -> None:
    """Give every element without a storey the highest of ``storeys`` (sorted by elevation) at
    or below its base + 0.5 m (the lowest when it is below them all)."""
    heights = np.array([st.elevation_m for st in storeys])
    for e in elements:
        if e.storey is None and len(e.vertices) and len(storeys):
            k = int(np.searchsorted(heights, e.zmin + 0.5, side="right")) - 1
            e.storey = storeys[max(k, 0)].name


GEOMETRY_LEVEL_PREFIX = "geometry-"


def check_units(elements: list[BimElement], ifc: Any, unit_scale: float, path: Path) -> None:
    """Raise :class:`BimInputError` when the walls' median height is implausible for the file's
    length unit (:data:`WALL_HEIGHT_RANGE_M`): a unit prefix changed without rescaling."""
    walls = [e for e in elements if e.label == Label.WALL and len(e.vertices)]
    if not walls:
        return
    heights = [e.zmax - e.zmin for e in walls]
    xy = np.concatenate([e.vertices[:, :2] for e in walls])
    span = float(np.linalg.norm(xy.max(axis=0) - xy.min(axis=0)))
    median = float(np.median(heights))
    lo, hi = WALL_HEIGHT_RANGE_M
    if lo <= median <= hi:
        return
    raise BimInputError(
        f"the walls are {median:.4g} m tall (median of {len(heights)}) and span {span:.4g} m with "
        f"the file's length unit {_length_unit_name(ifc)} ({unit_scale:g} m per unit): "
        f"implausible for a building (walls between {lo:g} and {hi:g} m). Was the unit changed "
        "without rescaling the coordinates?",
        path,
        "IfcUnitAssignment LENGTHUNIT",
    )


def _sample_walls(ifc: Any, walls: list[Any], count: int = 8) -> list[BimElement]:
    """A few walls tessellated one by one (for :func:`check_units` before the whole model)."""
    import ifcopenshell.geom

    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    out = []
    for wall in walls[:count]:
        try:
            shape = ifcopenshell.geom.create_shape(settings, wall)
        except Exception:  # the full pass reports it
            continue
        verts, faces = _shape_arrays(shape.geometry)
        if len(faces):
            out.append(BimElement(wall.GlobalId, wall.is_a(), Label.WALL, None, verts, faces))
    return out


def _length_unit_name(ifc: Any) -> str:
    try:
        import ifcopenshell.util.unit as uu

        unit = uu.get_project_unit(ifc, "LENGTHUNIT")
    except Exception:
        unit = None
    if unit is None:
        return "(none: metres assumed)"
    if unit.is_a("IfcSIUnit"):
        return f"{unit.Prefix or ''}{unit.Name}"
    return str(getattr(unit, "Name", unit.is_a()))


# ----------------------------------------------------------------------------- damage


_STEP_STRING = re.compile(rb"'(?:[^']|'')*'")
_STEP_DEFINITION = re.compile(rb"^[ \t]*#(\d+)[ \t]*=[ \t]*([A-Za-z0-9_]+)", re.M)
_STEP_REFERENCE = re.compile(rb"#(\d+)")
_STEP_CONTAINED = re.compile(rb"=[ \t]*IFCRELCONTAINEDINSPATIALSTRUCTURE[ \t]*\(([^;]*)",
                             re.I)


@dataclass
class _StepText:
    """What the file's text says, independent of IfcOpenShell."""

    classes: dict[int, str]  # instance id → class name as written
    dangling: set[int]  # referenced ids that no instance defines
    contained: set[int]  # ids listed by IfcRelContainedInSpatialStructure statements


def _scan_step_text(path: Path) -> _StepText:
    """The instances, dangling references and spatially contained ids of a STEP file's DATA
    section (string literals blanked first, so that ``'#12'`` in a name is no reference)."""
    data = path.read_bytes()
    start = data.find(b"DATA;")
    body = _STEP_STRING.sub(b"''", data[start if start >= 0 else 0:])
    classes = {int(m.group(1)): m.group(2).decode("ascii").upper()
               for m in _STEP_DEFINITION.finditer(body)}
    referenced = set(map(int, _STEP_REFERENCE.findall(body)))
    dangling = referenced - classes.keys()
    contained: set[int] = set()
    for m in _STEP_CONTAINED.finditer(body):
        contained.update(map(int, _STEP_REFERENCE.findall(m.group(1))))
    return _StepText(classes, dangling, contained)


def _is_element_class(schema: Any, name: str, cache: dict[str, bool | None]) -> bool | None:
    """Whether the class ``name`` is an IfcElement other than an opening; None if the schema
    does not know it."""
    if name not in cache:
        try:
            decl = schema.declaration_by_name(name)
        except RuntimeError:
            cache[name] = None
            return None
        chain = []
        while decl is not None:
            chain.append(decl.name())
            decl = decl.supertype()
        cache[name] = "IfcElement" in chain and "IfcFeatureElement" not in chain
    return cache[name]


def assess_damage(ifc: Any, text: _StepText, parser_messages: int) -> ModelDamage:
    """Compare what IfcOpenShell read with the file's text (:class:`ModelDamage`)."""
    import ifcopenshell.ifcopenshell_wrapper as wrapper

    read_ids = {e.id() for e in ifc}
    unread_ids = sorted(set(text.classes) - read_ids)
    unread = Counter(text.classes[i] for i in unread_ids)
    try:
        schema = wrapper.schema_by_name(str(ifc.schema))
    except Exception:
        schema = None
    cache: dict[str, bool | None] = {}
    elements_unread = []
    for i in unread_ids:
        is_element = None if schema is None else _is_element_class(schema, text.classes[i], cache)
        if is_element or i in text.contained:
            elements_unread.append(i)
    missing = sorted(text.dangling & text.contained)
    read_elements = [e for e in ifc.by_type("IfcElement") if not e.is_a("IfcFeatureElement")]
    examples = [f"#{i} {text.classes[i]} (unreadable)" for i in elements_unread[:3]]
    examples += [f"#{i} (listed in a storey, missing from the file)" for i in missing[:3]]
    return ModelDamage(
        instances=len(text.classes),
        unread=dict(unread),
        dangling=len(text.dangling),
        parser_messages=parser_messages,
        elements_total=len(read_elements) + len(elements_unread) + len(missing),
        elements_unread=len(elements_unread),
        elements_missing=len(missing),
        examples=examples,
    )


def check_damage(damage: ModelDamage, path: Path, max_lost_fraction: float) -> None:
    """Raise :class:`BimInputError` when the model lost more than ``max_lost_fraction`` of its
    building elements; warn (:class:`DamagedModelWarning`) with the counts for any smaller loss
    or any other damage."""
    if damage.lost_fraction > max_lost_fraction:
        raise BimInputError(
            f"damaged IFC file: {damage.describe()}; more than the allowed "
            f"{100 * max_lost_fraction:g} % (--max-lost-fraction). Re-export the model, or raise "
            "the limit to use what is left",
            path,
            "DATA",
        )
    if damage.any:
        warnings.warn(f"{path.name}: DAMAGED IFC FILE: {damage.describe()}", DamagedModelWarning,
                      stacklevel=3)


def _shape_arrays(geom: Any) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    verts = np.frombuffer(geom.verts_buffer, dtype=np.float64).reshape(-1, 3).copy()
    faces = np.frombuffer(geom.faces_buffer, dtype=np.int32).reshape(-1, 3).copy()
    return verts, faces


def _tessellate(
    ifc: Any, threads: int, include: list[Any] | None, exclude: list[str] | None
) -> list[tuple[int, NDArray[np.float64], NDArray[np.int32]]]:
    """(id, vertices, faces) of every product with geometry, in world metres, by id.

    IfcOpenShell's iterator stops at the first element it cannot process (a malformed
    attribute raises in ``next()``; with several threads it can wait forever, so damaged files
    come here with ``threads=1``): the products it did not reach are then tessellated one by
    one, and those that fail are left to :attr:`BimModel.failed`.
    """
    import ifcopenshell.geom

    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    if include is not None:
        if not include:
            return []
        it = ifcopenshell.geom.iterator(settings, ifc, threads, include=include)
    else:
        it = ifcopenshell.geom.iterator(settings, ifc, threads, exclude=exclude)
    out = []
    try:
        if not it.initialize():
            return out
        while True:
            shape = it.get()
            verts, faces = _shape_arrays(shape.geometry)
            if len(faces):
                out.append((int(shape.id), verts, faces))
            if not it.next():
                break
    except RuntimeError:
        done = {eid for eid, _, _ in out}
        if include is not None:
            rest = [e for e in include if e.id() not in done]
        else:
            skip = tuple(exclude or ())
            rest = [e for e in ifc.by_type("IfcProduct")
                    if e.id() not in done and getattr(e, "Representation", None) is not None
                    and not any(e.is_a(c) for c in skip)]
        for element in rest:
            try:
                shape = ifcopenshell.geom.create_shape(settings, element)
            except Exception:  # listed in BimModel.failed by the caller
                continue
            verts, faces = _shape_arrays(shape.geometry)
            if len(faces):
                out.append((int(element.id()), verts, faces))
    # With several threads the iterator yields elements in the order they finish: sort them, so
    # that the same file gives the same model (segments, planes, sampled cloud) on every run.
    out.sort(key=lambda shape: shape[0])
    return out


def _open_ifc(path: Path) -> tuple[Any, int]:
    """The opened IFC file and the number of errors and warnings IfcOpenShell logged."""
    import ifcopenshell

    ifcopenshell.get_log()  # reading the log empties it: start from a clean one
    try:
        ifc = ifcopenshell.open(str(path))
    except Exception as exc:  # IfcOpenShell raises several unrelated types on bad files
        raise BimInputError(f"IfcOpenShell cannot read the file: {exc}", path) from exc
    log = ifcopenshell.get_log()
    parser_messages = sum(1 for line in log.splitlines()
                          if line.startswith(("[error]", "[warning]")))
    return ifc, parser_messages


def _walls_and_damage(
    ifc: Any, path: Path, parser_messages: int, max_lost_fraction: float
) -> tuple[list[Any], ModelDamage]:
    """The model's walls and what the file lost; refuses a model without walls or one that
    lost too much, before the expensive tessellation."""
    try:
        walls = [*ifc.by_type("IfcWall"), *ifc.by_type("IfcCurtainWall")]
        walls += [e for e in ifc.by_type(_PROXY_CLASS) if _proxy_label(e) == Label.WALL]
    except RuntimeError as exc:
        raise BimInputError(f"unsupported IFC schema: {exc}", path, "FILE_SCHEMA") from exc
    # Damage, before the expensive tessellation: what the text has and IfcOpenShell did not read.
    damage = assess_damage(ifc, _scan_step_text(path), parser_messages)
    if not walls:
        if damage.any:
            raise BimInputError(f"the model has no walls left: damaged IFC file: "
                                f"{damage.describe()}", path, "IfcWall")
        raise BimInputError(
            "the model has no walls: a BIM reference needs IfcWall / IfcCurtainWall elements "
            "(or IfcBuildingElementProxy elements named as walls)",
            path,
            "IfcWall",
        )
    if damage.lost_fraction > max_lost_fraction:
        check_damage(damage, path, max_lost_fraction)  # refused before tessellating
    return walls, damage


def _stated_storeys(ifc: Any, unit_scale: float) -> tuple[list[_StoreyRecord], dict[int, str]]:
    """The storeys as the file states them (unique names, by height) and storey id → name."""
    raw = _read_storey_records(ifc, unit_scale)
    stated = _unique_storeys([Storey(r.name, r.stated_m, r.guid) for r in raw])
    by_guid = {r.guid: r for r in raw}
    records = [_StoreyRecord(s.name, s.guid, by_guid[s.guid].attribute_m,
                             by_guid[s.guid].placement_m) for s in stated]
    storey_names = {ifc.by_guid(s.guid).id(): s.name for s in stated}
    return records, storey_names


def _bim_elements(
    ifc: Any,
    shapes: list[tuple[int, NDArray[np.float64], NDArray[np.int32]]],
    storey_names: dict[int, str],
) -> list[BimElement]:
    """One :class:`BimElement` per tessellated ``(id, vertices (V, 3) m, faces (F, 3))``."""
    import ifcopenshell.util.element as ue

    cache: dict[int, str | None] = {}
    elements: list[BimElement] = []
    for eid, verts, faces in shapes:
        ent = ifc.by_id(eid)
        parent = ue.get_aggregate(ent)
        label = classify(ent, parent)
        if (label in (Label.WALL, Label.COLUMN) and ent.is_a(_PROXY_CLASS)
                and not proxy_shape_agrees(label, verts, faces)):
            label = Label.UNKNOWN
        elements.append(
            BimElement(
                guid=ent.GlobalId,
                ifc_class=ent.is_a(),
                label=label,
                storey=_storey_of(ent, cache, storey_names),
                vertices=verts,
                faces=faces,
                predefined_type=ue.get_predefined_type(ent),
                name=getattr(ent, "Name", None) or "",
            )
        )
    return elements


def _proxy_note(ifc: Any, elements: list[BimElement], path: Path) -> str:
    """The line saying which IfcBuildingElementProxy elements were taken as walls / columns
    ("" when none was named so); refuses a model whose only walls were proxies not shaped as
    walls."""
    named = {e.id(): _proxy_label(e) for e in ifc.by_type(_PROXY_CLASS)}
    named = {k: v for k, v in named.items() if v != Label.UNKNOWN}
    if not named:
        return ""
    proxies = [e for e in elements if e.ifc_class == _PROXY_CLASS]
    walls = sum(e.label == Label.WALL for e in proxies)
    columns = sum(e.label == Label.COLUMN for e in proxies)
    if not any(e.label == Label.WALL for e in elements):
        raise BimInputError(
            f"the model has no walls: its {len(named)} IfcBuildingElementProxy elements named "
            "as walls or columns are not shaped as walls (≥ 0.2 m tall, ≤ 1 m thick)", path,
            "IfcWall")
    left = len(named) - walls - columns
    return (f"{path.name}: {walls} IfcBuildingElementProxy elements taken as walls and "
            f"{columns} as columns by their names; {left} named so but not shaped so left as "
            "'other'")


def _failed_products(
    ifc: Any, done: set[int], excluded: tuple[str, ...]
) -> tuple[list[tuple[str, str]], int]:
    """``(guid, reason)`` of the products with a body that gave no geometry, and how many of
    them are building elements."""
    failed = []
    failed_elements = 0
    for prod in ifc.by_type("IfcProduct"):
        if prod.id() in done or any(prod.is_a(c) for c in excluded):
            continue
        rep = getattr(prod, "Representation", None)
        if rep is None:
            continue
        try:
            bodies = [r for r in rep.Representations
                      if (r.RepresentationIdentifier or "") == "Body"]
        except Exception:  # a damaged representation counts as failed
            bodies = [rep]
        if bodies and not prod.is_a("IfcSpatialStructureElement"):
            failed.append((prod.GlobalId, f"{prod.is_a()}: tessellation produced no geometry"))
            failed_elements += int(prod.is_a("IfcElement") and not prod.is_a("IfcFeatureElement"))
    return failed, failed_elements


def load_model(
    path: str | PathLike[str],
    *,
    threads: int | None = None,
    load_spaces: bool = False,
    include_furniture: bool = True,
    max_lost_fraction: float = DEFAULT_MAX_LOST_FRACTION,
) -> BimModel:
    """Open an IFC file and tessellate every element in world coordinates, in metres.

    Parameters
    ----------
    path: an IFC2X3 or IFC4 STEP file (``.ifc``).
    threads: geometry threads (default: ``multiprocessing.cpu_count()``; one for a damaged file).
    load_spaces: also tessellate IfcSpace volumes into :attr:`BimModel.spaces` (used to derive
        floor planes when a storey has no floor slab).
    include_furniture: tessellate IfcFurnishingElement (label "other") too. Furniture plays no
        part in planes, floor plan or cloud; leaving it out saves most of the time on furnished
        models (Duplex: 3.7 s → 1.2 s of tessellation).
    max_lost_fraction: the largest share of the building elements a damaged file may lose
        (unreadable, missing from the file, without geometry) before it is refused.

    Raises
    ------
    BimInputError: the file is missing, not IFC, truncated, unreadable, has no walls, lost more
        than ``max_lost_fraction`` of its elements, or its walls' size says that its length
        unit is wrong.

    Warns
    -----
    DamagedModelWarning: a damaged file that lost less (the counts). StoreyHeightWarning: storey
    heights taken from the geometry (they disagree with it, or the model has no storeys).
    """
    import ifcopenshell.util.unit

    p = Path(path)
    check_ifc_file(p)
    ifc, parser_messages = _open_ifc(p)
    walls, damage = _walls_and_damage(ifc, p, parser_messages, max_lost_fraction)
    unit_scale = float(ifcopenshell.util.unit.calculate_unit_scale(ifc))
    records, storey_names = _stated_storeys(ifc, unit_scale)
    # A wrong length unit shows on a few walls: refuse before tessellating the whole model.
    check_units(_sample_walls(ifc, walls), ifc, unit_scale, p)
    n_threads = 1 if damage.any else (threads or multiprocessing.cpu_count() or 1)

    excluded = EXCLUDED_CLASSES + (() if include_furniture else ("IfcFurnishingElement",))
    shapes = _tessellate(ifc, n_threads, None, list(excluded))
    elements = _bim_elements(ifc, shapes, storey_names)
    failed, damage.elements_failed = _failed_products(ifc, {eid for eid, _, _ in shapes},
                                                      excluded)
    if damage.elements_failed:
        damage.examples += [f"{g} {why}" for g, why in failed[:2]]
    check_damage(damage, p, max_lost_fraction)
    check_units(elements, ifc, unit_scale, p)
    proxy_note = _proxy_note(ifc, elements, p)

    if records:
        storeys, notes = reconcile_storeys(records, elements, p)
    else:
        storeys, notes = levels_from_geometry(elements, p)
    for note in notes:
        warnings.warn(note, StoreyHeightWarning, stacklevel=2)
    if proxy_note:
        warnings.warn(proxy_note, ProxyElementWarning, stacklevel=2)
        notes.append(proxy_note)

    spaces: list[BimElement] = []
    if load_spaces:
        spaces = load_spaces_of(ifc, None, storey_names, n_threads)
        if not records:
            assign_by_height(spaces, storeys)
    return BimModel(
        path=p,
        schema=str(ifc.schema),
        unit_scale=unit_scale,
        elements=elements,
        storeys=storeys,
        failed=failed,
        spaces=spaces,
        damage=damage if damage.any else None,
        notes=notes,
    )


def load_spaces_of(
    ifc: Any, storey: str | None, storey_names: dict[int, str], threads: int
) -> list[BimElement]:
    """Tessellate the IfcSpace volumes (of one storey, or all when ``storey`` is None)."""
    cache: dict[int, str | None] = {}
    wanted = [
        s
        for s in ifc.by_type("IfcSpace")
        if s.Representation is not None
        and (storey is None or _storey_of(s, cache, storey_names) == storey)
    ]
    out = []
    for eid, verts, faces in _tessellate(ifc, threads, wanted, None):
        ent = ifc.by_id(eid)
        out.append(
            BimElement(
                guid=ent.GlobalId,
                ifc_class=ent.is_a(),
                label=Label.UNKNOWN,
                storey=_storey_of(ent, cache, storey_names),
                vertices=verts,
                faces=faces,
                name=ent.Name or "",
            )
        )
    return out


def read_spaces(model: BimModel, threads: int | None = None) -> list[BimElement]:
    """Tessellate the model's IfcSpace volumes (cached in :attr:`BimModel.spaces`)."""
    if model.spaces:
        return model.spaces
    import ifcopenshell

    ifc = ifcopenshell.open(str(model.path))
    real = [s for s in model.storeys if not s.guid.startswith(GEOMETRY_LEVEL_PREFIX)]
    storey_names = {ifc.by_guid(s.guid).id(): s.name for s in real}
    threads = 1 if model.damage is not None else (threads or os.cpu_count() or 1)
    model.spaces = load_spaces_of(ifc, None, storey_names, threads)
    if len(real) < len(model.storeys):
        assign_by_height(model.spaces, model.storeys)
    return model.spaces
