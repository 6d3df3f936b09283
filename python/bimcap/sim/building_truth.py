"""Ground truth of a generated building: the JSON sidecar written next to its IFC.

Everything here is in the IFC's frame (z up) and in metres. A wall is stored by its centre line
(``start`` → ``end``), its thickness and its z range; its two faces are the centre line offset by
``±thickness / 2`` along the wall's *left normal* ``n = (-dy, dx)`` of the unit direction
``(dx, dy)`` (``faces[0]`` is the ``+n`` face, ``faces[1]`` the ``-n`` face). Rooms, the corridor
and the passages (door holes, removed walls) are axis-aligned rectangles whose union is the
walkable free space of a storey; the walk graph's edges stay inside it and clear of columns.

Sidecar ``NAME.truth.json`` (read it with :func:`load_building_truth`)::

    {"format": "bimcap-building-truth", "version": 1, "units": "m", "schema": "IFC4",
     "variant": "design" | "as_built", "seed": int (design seed), "spec": {BuildingSpec fields},
     "counts": {"IfcBuildingStorey": n, "IfcWall": n, "IfcSlab": n, "IfcCovering": n,
                "IfcColumn": n, "IfcDoor": n, "IfcWindow": n, "IfcOpeningElement": n},
     "storeys": [{"index", "name" ("S0"...), "guid", "elevation", "floor_z", "ceiling_z",
                  "wall_top_z"}],
     "walls": [{"id" ("S0/wall/corr-north"), "guid", "storey", "kind": "exterior" | "corridor" |
                "partition", "start": [x, y], "end": [x, y], "thickness", "height", "z_min",
                "z_max", "normal": [nx, ny], "faces": [[x1, y1, x2, y2] (+normal side),
                                                     [x1, y1, x2, y2] (-normal side)]}],
     "columns": [{"id", "guid", "storey", "shape": "rectangular" | "round", "center": [x, y],
                  "size": [sx, sy] | null, "radius": r | null, "z_min", "z_max"}],
     "doors" / "windows": [{"id" ("S0/door/north-2"), "kind": "door" | "window", "storey",
                  "host_wall" (wall id), "opening_guid", "fill_guid" (null if the fill is
                  missing), "center": [x, y] (on the host centre line), "direction": [dx, dy]
                  (host direction), "width", "height", "z_min", "z_max"}],
     "slabs": [{"id", "guid", "storey", "ifc_class": "IfcSlab", "predefined_type": "BASESLAB" |
                "FLOOR" | "ROOF", "polygon": [[x, y], ...], "z_min", "z_max"}],
     "coverings": [same, "ifc_class": "IfcCovering", "predefined_type": "CEILING"; one per
                   room ("S0/ceiling/north-1") and corridor ("S0/ceiling/corridor"), z_min its
                   underside],
     "free_space": [{"storey", "floor_z",
                     "regions": [{"id", "kind": "room" | "corridor" | "door" | "removed_wall",
                                  "rect": [x_min, y_min, x_max, y_max], "polygon": 4 x [x, y]}],
                     "walk_graph": {"nodes": [[x, y], ...], "edges": [[i, j], ...]},
                     "tour": [node index, ...] (closed: first == last)}],
     "deviations": null | {"seed", "shift_sigma_m", "missing_fraction",
                           "wall_shifts": {wall id: metres along +normal},
                           "column_offsets": {column id: [dx, dy]},
                           "missing": [element ids absent from this IFC],
                           "datum": [element ids built exactly as designed, like surveyed
                                     control lines (absent in older files: none)]}}

Ids are the IFC ``Name`` of each element (openings are named ``<door/window id>/opening``);
GUIDs are the same in a design file and its as-built.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.labels import Label

TRUTH_FORMAT = "bimcap-building-truth"
TRUTH_VERSION = 1


class BuildingTruthError(InputError):
    """A ground-truth sidecar that cannot be read (wrong format, version or field)."""


class WallKind(str, Enum):
    """Role of a wall in the layout. Exterior walls form the shell that as-built never removes."""

    EXTERIOR = "exterior"
    CORRIDOR = "corridor"
    PARTITION = "partition"


class ColumnShape(str, Enum):
    """Cross-section of a column."""

    RECTANGULAR = "rectangular"
    ROUND = "round"


class Variant(str, Enum):
    """Which world a file describes: the design (BIM) or the as-built site."""

    DESIGN = "design"
    AS_BUILT = "as_built"


def _xy(p: Any) -> tuple[float, float]:
    return (float(p[0]), float(p[1]))


@dataclass(frozen=True)
class WallTruth:
    """One straight wall: centre line ``start`` → ``end`` (metres, world xy) and z range."""

    id: str
    guid: str
    storey: int
    kind: WallKind
    start: tuple[float, float]
    end: tuple[float, float]
    thickness: float
    z_min: float
    z_max: float

    @property
    def direction(self) -> NDArray[np.float64]:
        """(2,) unit vector from ``start`` to ``end``."""
        d = np.subtract(self.end, self.start)
        return d / np.linalg.norm(d)

    @property
    def normal(self) -> NDArray[np.float64]:
        """(2,) left unit normal ``(-dy, dx)``; ``faces[0]`` lies at ``+thickness/2`` along it."""
        d = self.direction
        return np.array([-d[1], d[0]])

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.subtract(self.end, self.start)))

    @property
    def faces(self) -> NDArray[np.float64]:
        """(2, 4) face lines ``[x1, y1, x2, y2]``: row 0 on the ``+normal`` side, row 1 on ``-``."""
        off = self.normal * (self.thickness / 2.0)
        s, e = np.asarray(self.start), np.asarray(self.end)
        return np.array([[*(s + off), *(e + off)], [*(s - off), *(e - off)]])

    def footprint(self) -> NDArray[np.float64]:
        """(4, 2) corners of the wall's xy rectangle, counter-clockwise."""
        f = self.faces
        return np.array([f[1, :2], f[1, 2:], f[0, 2:], f[0, :2]])

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "guid": self.guid,
            "storey": self.storey,
            "kind": self.kind.value,
            "start": list(self.start),
            "end": list(self.end),
            "thickness": self.thickness,
            "height": self.z_max - self.z_min,
            "z_min": self.z_min,
            "z_max": self.z_max,
            "normal": self.normal.tolist(),
            "faces": self.faces.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> WallTruth:
        return cls(
            d["id"], d["guid"], int(d["storey"]), WallKind(d["kind"]), _xy(d["start"]),
            _xy(d["end"]), float(d["thickness"]), float(d["z_min"]), float(d["z_max"]),
        )


@dataclass(frozen=True)
class ColumnTruth:
    """A vertical column: ``size`` (x, y) for rectangular ones, ``radius`` for round ones."""

    id: str
    guid: str
    storey: int
    shape: ColumnShape
    center: tuple[float, float]
    size: tuple[float, float] | None
    radius: float | None
    z_min: float
    z_max: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "guid": self.guid,
            "storey": self.storey,
            "shape": self.shape.value,
            "center": list(self.center),
            "size": None if self.size is None else list(self.size),
            "radius": self.radius,
            "z_min": self.z_min,
            "z_max": self.z_max,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ColumnTruth:
        return cls(
            d["id"], d["guid"], int(d["storey"]), ColumnShape(d["shape"]), _xy(d["center"]),
            None if d["size"] is None else _xy(d["size"]),
            None if d["radius"] is None else float(d["radius"]),
            float(d["z_min"]), float(d["z_max"]),
        )


@dataclass(frozen=True)
class OpeningTruth:
    """A door or window: the rectangular hole (IfcOpeningElement) in ``host_wall`` and its fill.

    ``center`` is the hole's centre on the host's centre line (xy); the hole spans
    ``width`` along the host's direction, the full host thickness, and z ``[z_min, z_max]``.
    ``fill_guid`` is None when the fill (IfcDoor / IfcWindow) is missing (as-built).
    """

    id: str
    kind: str  # "door" | "window"
    storey: int
    host_wall: str
    opening_guid: str
    fill_guid: str | None
    center: tuple[float, float]
    direction: tuple[float, float]
    width: float
    z_min: float
    z_max: float

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["center"] = list(self.center)
        d["direction"] = list(self.direction)
        d["height"] = self.z_max - self.z_min
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> OpeningTruth:
        return cls(
            d["id"], d["kind"], int(d["storey"]), d["host_wall"], d["opening_guid"],
            d["fill_guid"], _xy(d["center"]), _xy(d["direction"]), float(d["width"]),
            float(d["z_min"]), float(d["z_max"]),
        )


@dataclass(frozen=True)
class SlabTruth:
    """A horizontal plate: floor/base/roof slab (IfcSlab) or ceiling (IfcCovering CEILING)."""

    id: str
    guid: str
    storey: int
    ifc_class: str
    predefined_type: str
    polygon: tuple[tuple[float, float], ...]
    z_min: float
    z_max: float

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["polygon"] = [list(p) for p in self.polygon]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SlabTruth:
        return cls(
            d["id"], d["guid"], int(d["storey"]), d["ifc_class"], d["predefined_type"],
            tuple(_xy(p) for p in d["polygon"]), float(d["z_min"]), float(d["z_max"]),
        )


@dataclass(frozen=True)
class StoreyTruth:
    """One storey: ``floor_z`` is the top of its floor slab (= elevation), ``ceiling_z`` the
    underside of its rooms' ceiling coverings (the corridor's may be lower: each covering in
    ``BuildingTruth.coverings`` has its own ``z_min``), ``wall_top_z`` the underside of the
    slab above."""

    index: int
    name: str
    guid: str
    elevation: float
    floor_z: float
    ceiling_z: float
    wall_top_z: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StoreyTruth:
        return cls(
            int(d["index"]), d["name"], d["guid"], float(d["elevation"]), float(d["floor_z"]),
            float(d["ceiling_z"]), float(d["wall_top_z"]),
        )


@dataclass(frozen=True)
class Region:
    """An axis-aligned walkable rectangle ``[x_min, y_min, x_max, y_max]`` (metres)."""

    id: str
    kind: str  # "room" | "corridor" | "door" | "removed_wall"
    rect: tuple[float, float, float, float]

    def polygon(self) -> NDArray[np.float64]:
        """(4, 2) corners, counter-clockwise."""
        x0, y0, x1, y1 = self.rect
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])

    def contains(self, p_xy: NDArray[np.float64], margin: float = 0.0) -> NDArray[np.bool_]:
        """(M,) whether each (M, 2) point lies inside, at least ``margin`` metres from the edge."""
        p = np.atleast_2d(p_xy)
        x0, y0, x1, y1 = self.rect
        return (
            (p[:, 0] >= x0 + margin) & (p[:, 0] <= x1 - margin)
            & (p[:, 1] >= y0 + margin) & (p[:, 1] <= y1 - margin)
        )

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, "kind": self.kind, "rect": list(self.rect),
                "polygon": self.polygon().tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Region:
        r = d["rect"]
        return cls(d["id"], d["kind"], (float(r[0]), float(r[1]), float(r[2]), float(r[3])))


@dataclass(frozen=True)
class FreeSpace:
    """Walkable space of one storey and a graph to walk it.

    Attributes
    ----------
    regions: rooms, the corridor and passages; their union is the free floor (columns excepted).
    nodes: (K, 2) float64 walk-graph node positions, metres.
    edges: (E, 2) int32 node index pairs; every edge is a straight, collision-free segment.
    tour: (T,) int32 node indices of a closed walk that enters every room through its door.
    """

    storey: int
    floor_z: float
    regions: tuple[Region, ...]
    nodes: NDArray[np.float64]
    edges: NDArray[np.int32]
    tour: NDArray[np.int32]

    def tour_xy(self) -> NDArray[np.float64]:
        """(T, 2) the tour as a polyline in metres."""
        return self.nodes[self.tour]

    def to_dict(self) -> dict[str, Any]:
        return {
            "storey": self.storey,
            "floor_z": self.floor_z,
            "regions": [r.to_dict() for r in self.regions],
            "walk_graph": {"nodes": self.nodes.tolist(), "edges": self.edges.tolist()},
            "tour": self.tour.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FreeSpace:
        g = d["walk_graph"]
        return cls(
            int(d["storey"]), float(d["floor_z"]), tuple(Region.from_dict(r) for r in d["regions"]),
            np.asarray(g["nodes"], dtype=np.float64).reshape(-1, 2),
            np.asarray(g["edges"], dtype=np.int32).reshape(-1, 2),
            np.asarray(d["tour"], dtype=np.int32).reshape(-1),
        )


@dataclass(frozen=True)
class Deviations:
    """What the as-built differs by: per-wall normal shifts, column offsets, missing elements."""

    seed: int
    shift_sigma_m: float
    missing_fraction: float
    wall_shifts: dict[str, float] = field(default_factory=dict)  # id -> metres along +normal
    column_offsets: dict[str, tuple[float, float]] = field(default_factory=dict)  # id -> (dx, dy)
    missing: tuple[str, ...] = ()  # element ids absent from the as-built IFC
    datum: tuple[str, ...] = ()  # element ids built exactly as designed (control lines)

    def to_dict(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "shift_sigma_m": self.shift_sigma_m,
            "missing_fraction": self.missing_fraction,
            "wall_shifts": dict(self.wall_shifts),
            "column_offsets": {k: list(v) for k, v in self.column_offsets.items()},
            "missing": list(self.missing),
            "datum": list(self.datum),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Deviations:
        return cls(
            int(d["seed"]), float(d["shift_sigma_m"]), float(d["missing_fraction"]),
            {k: float(v) for k, v in d["wall_shifts"].items()},
            {k: _xy(v) for k, v in d["column_offsets"].items()},
            tuple(d["missing"]), tuple(d.get("datum", ())),
        )


@dataclass(frozen=True)
class BuildingTruth:
    """Everything known about a generated building, in metres in the IFC frame."""

    variant: Variant
    seed: int
    spec: dict[str, Any]
    storeys: tuple[StoreyTruth, ...]
    walls: tuple[WallTruth, ...]
    columns: tuple[ColumnTruth, ...]
    doors: tuple[OpeningTruth, ...]
    windows: tuple[OpeningTruth, ...]
    slabs: tuple[SlabTruth, ...]
    coverings: tuple[SlabTruth, ...]
    free_space: tuple[FreeSpace, ...]
    counts: dict[str, int]
    deviations: Deviations | None = None

    def plan_outline(self, storey: int, z: float, circle_sides: int = 32) -> PlanOutline:
        """See :func:`plan_outline`."""
        return plan_outline(self, storey, z, circle_sides)

    def wall(self, wall_id: str) -> WallTruth:
        for w in self.walls:
            if w.id == wall_id:
                return w
        raise KeyError(wall_id)

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": TRUTH_FORMAT,
            "version": TRUTH_VERSION,
            "units": "m",
            "schema": "IFC4",
            "variant": self.variant.value,
            "seed": self.seed,
            "spec": self.spec,
            "counts": dict(self.counts),
            "storeys": [s.to_dict() for s in self.storeys],
            "walls": [w.to_dict() for w in self.walls],
            "columns": [c.to_dict() for c in self.columns],
            "doors": [o.to_dict() for o in self.doors],
            "windows": [o.to_dict() for o in self.windows],
            "slabs": [s.to_dict() for s in self.slabs],
            "coverings": [s.to_dict() for s in self.coverings],
            "free_space": [f.to_dict() for f in self.free_space],
            "deviations": None if self.deviations is None else self.deviations.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], path: str | PathLike[str] | None = None) -> BuildingTruth:
        if d.get("format") != TRUTH_FORMAT:
            raise BuildingTruthError(f"not a {TRUTH_FORMAT} file", path, "format")
        if d.get("version") != TRUTH_VERSION:
            raise BuildingTruthError(
                f"unsupported version {d.get('version')!r} (expected {TRUTH_VERSION})", path,
                "version",
            )
        try:
            return cls(
                Variant(d["variant"]), int(d["seed"]), dict(d["spec"]),
                tuple(StoreyTruth.from_dict(s) for s in d["storeys"]),
                tuple(WallTruth.from_dict(w) for w in d["walls"]),
                tuple(ColumnTruth.from_dict(c) for c in d["columns"]),
                tuple(OpeningTruth.from_dict(o) for o in d["doors"]),
                tuple(OpeningTruth.from_dict(o) for o in d["windows"]),
                tuple(SlabTruth.from_dict(s) for s in d["slabs"]),
                tuple(SlabTruth.from_dict(s) for s in d["coverings"]),
                tuple(FreeSpace.from_dict(f) for f in d["free_space"]),
                {k: int(v) for k, v in d["counts"].items()},
                None if d.get("deviations") is None else Deviations.from_dict(d["deviations"]),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise BuildingTruthError(f"malformed ground truth: {exc!r}", path) from exc


@dataclass(frozen=True)
class PlanOutline:
    """The exact horizontal section of a storey's walls and columns at height ``z``.

    Attributes
    ----------
    storey: storey index.
    z: cut height, metres (world z).
    segments: (S, 4) float64 ``x1 y1 x2 y2`` in metres: the outline of the union of the wall
        solids at ``z`` (door and window holes cut), merged into maximal straight pieces, then
        the outline of every column (round ones as regular polygons).
    segment_class: (S,) uint8, ``Label.WALL`` or ``Label.COLUMN``.
    """

    storey: int
    z: float
    segments: NDArray[np.float64]
    segment_class: NDArray[np.uint8]

    def to_dict(self) -> dict[str, Any]:
        return {"storey": self.storey, "z": self.z, "segments": self.segments.tolist(),
                "segment_class": self.segment_class.tolist()}


def _union_outline(rects: list[tuple[float, float, float, float]]) -> NDArray[np.float64]:
    """(S, 4) boundary of a union of axis-aligned rectangles ``[x0, y0, x1, y1]``, exactly.

    Coordinates are snapped to 1e-7 m so that butt joints computed in different ways meet.
    """
    if not rects:
        return np.zeros((0, 4))
    r = np.round(np.asarray(rects, dtype=np.float64), 7)
    xs, ys = np.unique(r[:, [0, 2]]), np.unique(r[:, [1, 3]])
    cx, cy = (xs[:-1] + xs[1:]) / 2, (ys[:-1] + ys[1:]) / 2
    filled = np.zeros((cx.size, cy.size), dtype=bool)
    for x0, y0, x1, y1 in r:
        filled |= ((cx > x0) & (cx < x1))[:, None] & ((cy > y0) & (cy < y1))[None, :]
    pad = np.pad(filled, 1)
    out: list[list[float]] = []
    # Vertical edges at xs[i]: solid on one side only; merge runs with the same solid side.
    for i, x in enumerate(xs):
        side = pad[i + 1, 1:-1].astype(np.int8) - pad[i, 1:-1].astype(np.int8)
        j = 0
        while j < side.size:
            if side[j] == 0:
                j += 1
                continue
            k = j
            while k + 1 < side.size and side[k + 1] == side[j]:
                k += 1
            out.append([x, ys[j], x, ys[k + 1]])
            j = k + 1
    for j, y in enumerate(ys):
        side = pad[1:-1, j + 1].astype(np.int8) - pad[1:-1, j].astype(np.int8)
        i = 0
        while i < side.size:
            if side[i] == 0:
                i += 1
                continue
            k = i
            while k + 1 < side.size and side[k + 1] == side[i]:
                k += 1
            out.append([xs[i], y, xs[k + 1], y])
            i = k + 1
    return np.asarray(out, dtype=np.float64).reshape(-1, 4)


def plan_outline(truth: BuildingTruth, storey: int, z: float, circle_sides: int = 32
                 ) -> PlanOutline:
    """The exact floor-plan section of ``storey`` at world height ``z`` (the oracle a floor-plan
    vectorizer is scored against). Walls must be axis-aligned (the generator's are).

    Parameters
    ----------
    truth: the building.
    storey: storey index.
    z: cut height in metres (world z, e.g. ``floor_z + 1.0``).
    circle_sides: sides of the polygon that stands for a round column.
    """
    rects: list[tuple[float, float, float, float]] = []
    holes = [o for o in (*truth.doors, *truth.windows)
             if o.storey == storey and o.z_min < z < o.z_max]
    for w in truth.walls:
        if w.storey != storey or not w.z_min <= z <= w.z_max:
            continue
        d = w.direction
        if min(abs(d[0]), abs(d[1])) > 1e-9:
            raise ValueError(f"{w.id}: plan_outline needs axis-aligned walls")
        axis = 0 if abs(d[0]) > 0.5 else 1
        lo, hi = w.footprint().min(0), w.footprint().max(0)
        cuts = sorted((o.center[axis] - o.width / 2, o.center[axis] + o.width / 2)
                      for o in holes if o.host_wall == w.id)
        start = lo[axis]
        for a, b in [*cuts, (hi[axis], hi[axis])]:
            if a > start:
                piece_lo, piece_hi = lo.copy(), hi.copy()
                piece_lo[axis], piece_hi[axis] = start, min(a, hi[axis])
                rects.append((piece_lo[0], piece_lo[1], piece_hi[0], piece_hi[1]))
            start = max(start, b)
    segs = [_union_outline(rects)]
    classes = [np.full(len(segs[0]), Label.WALL, dtype=np.uint8)]
    for c in truth.columns:
        if c.storey != storey or not c.z_min <= z <= c.z_max:
            continue
        if c.shape is ColumnShape.ROUND:
            assert c.radius is not None
            t = np.linspace(0.0, 2 * np.pi, circle_sides + 1)
            p = np.asarray(c.center) + c.radius * np.c_[np.cos(t), np.sin(t)]
        else:
            assert c.size is not None
            hx, hy = c.size[0] / 2, c.size[1] / 2
            p = np.asarray(c.center) + np.array(
                [[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]])
        segs.append(np.c_[p[:-1], p[1:]])
        classes.append(np.full(len(p) - 1, Label.COLUMN, dtype=np.uint8))
    return PlanOutline(storey, float(z), np.concatenate(segs), np.concatenate(classes))


def load_building_truth(path: str | PathLike[str]) -> BuildingTruth:
    """Read a sidecar written by :func:`bimcap.sim.building.generate_building`."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise BuildingTruthError(f"cannot read: {exc.strerror}", p) from exc
    except json.JSONDecodeError as exc:
        raise BuildingTruthError(f"not JSON: {exc}", p) from exc
    if not isinstance(data, dict):
        raise BuildingTruthError("top level is not an object", p)
    return BuildingTruth.from_dict(data, p)
