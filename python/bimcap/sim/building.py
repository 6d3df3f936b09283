"""Parametric IFC4 building generator: a corridor with rooms on both sides, the demo world.

Layout (one storey, seen from above; x along the corridor, y across it, z up, metres)::

      y ^   ext-north (exterior, te)
        |  +------+--------+---------+
        |  |north-1| north-2| north-3 |       rooms: clear depth ``room_depth_north_m``
        |  +--D---+---D----+----D----+       corr-north (interior, ti), doors D
      0 +  | E          corridor       W|     clear width ``corridor_width_m``; entrance E
        |  +---D--+--D--+--D---+--D--+       corr-south
        |  |south-1|s-2 |south-3|s-4 |
        |  +------+-----+-------+----+       ext-south
        +--|------------------------|--> x
           0                        corridor_length_m

The corridor's clear space is ``x in [0, corridor_length_m]``, ``y in [-w/2, w/2]``. Exterior
north/south walls run the full length (they hold the corners); west/east walls, the corridor walls
and the partitions butt against the faces of the walls they meet, so no two wall solids overlap
and the union of their footprints is exactly the plan. Rectangular columns stand in the corridor
(near its north wall, at the north partitions' x), a round one in the widest south room (the
"hall"). Every room has a door to the corridor (IfcOpeningElement + IfcDoor) and a window in its
exterior wall (IfcOpeningElement + IfcWindow); the corridor has an entrance door in the west wall
(ground floor) and a window in the east wall. Each storey has a floor slab (BASESLAB on the
ground floor, FLOOR above) whose top is the storey elevation; every room and the corridor has its
own suspended ceiling (IfcCovering CEILING, a thin plate whose underside is
``ceiling_height_m`` above the floor in the rooms and ``corridor_ceiling_height_m`` in the
corridor, below the structural slab as in real models), filling the room's clear rectangle from
wall face to wall face; a ROOF slab closes the top storey.

:func:`generate_building` writes the design IFC and its ground truth
(:class:`~bimcap.sim.building_truth.BuildingTruth`, a JSON sidecar ``NAME.truth.json``);
:func:`as_built` writes the same building as it was built: every wall shifted along its normal by
a few centimetres, columns offset, and some interior elements (partitions, columns, door and
window fills; never the shell, the corridor walls or the slabs) missing. Same seed → identical
IFC bytes: GUIDs are hashed from the seed and the element's id, the header time stamp is fixed.
"""

from __future__ import annotations

import hashlib
import logging
import math
import uuid
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.io.atomic import atomic_write_json, atomic_write_text
from bimcap.sim.building_truth import (
    BuildingTruth,
    ColumnShape,
    ColumnTruth,
    Deviations,
    FreeSpace,
    OpeningTruth,
    Region,
    SlabTruth,
    StoreyTruth,
    Variant,
    WallKind,
    WallTruth,
)

if TYPE_CHECKING:
    import ifcopenshell

__all__ = [
    "PRESETS",
    "BuildingSpec",
    "BuildingSpecError",
    "GeneratedBuilding",
    "as_built",
    "expected_counts",
    "generate_building",
    "truth_path_for",
]

_log = logging.getLogger(__name__)

#: Fixed FILE_NAME time stamp, so that the same seed gives the same bytes.
HEADER_TIME_STAMP = "2000-01-01T00:00:00"
#: Clearance (m) the walk graph keeps from walls and columns.
WALK_CLEARANCE_M = 0.45
#: Distance (m) of room walking loops from the room's walls.
ROOM_LOOP_MARGIN_M = 0.7


class BuildingSpecError(InputError):
    """A building specification that cannot be built (names the offending field)."""


@dataclass(frozen=True)
class BuildingSpec:
    """Parameters of a generated building. All lengths in metres.

    The default is the demo world: one storey, a 15 m x 2.4 m corridor, 3 rooms north (4.0 m
    deep) and 4 south (4.4 m deep) with seeded unequal widths, 2 rectangular corridor columns and
    a round one in the widest south room, suspended ceilings at 2.7 m in the rooms and 2.5 m in
    the corridor (the storey is 3.1 m, the slab 0.2 m: the walls go up to the slab at 2.9 m).

    ``ceiling_height_m`` / ``corridor_ceiling_height_m`` are the heights of the ceilings'
    undersides above the storey floor; ``ceiling_thickness_m`` the plates' thickness.
    """

    storeys: int = 1
    storey_height_m: float = 3.1
    slab_thickness_m: float = 0.2
    ceiling_height_m: float = 2.7
    corridor_ceiling_height_m: float = 2.5
    ceiling_thickness_m: float = 0.03
    corridor_length_m: float = 15.0
    corridor_width_m: float = 2.4
    rooms_north: int = 3
    rooms_south: int = 4
    room_depth_north_m: float = 4.0
    room_depth_south_m: float = 4.4
    room_width_jitter: float = 0.12
    room_widths_north_m: tuple[float, ...] | None = None
    room_widths_south_m: tuple[float, ...] | None = None
    exterior_wall_thickness_m: float = 0.2
    interior_wall_thickness_m: float = 0.12
    corridor_columns: int = 2
    column_size_m: float = 0.3
    hall_round_column: bool = True
    round_column_radius_m: float = 0.2
    door_width_m: float = 0.9
    door_height_m: float = 2.1
    entrance_door_width_m: float = 1.0
    window_width_m: float = 1.2
    window_height_m: float = 1.3
    window_sill_m: float = 0.9
    corridor_end_window: bool = True

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise :class:`BuildingSpecError` naming the field if the building cannot be built.

        ``room_widths_north_m`` / ``room_widths_south_m``, when given, are the rooms' clear
        widths from west to east; they replace the seeded widths, must number ``rooms_north`` /
        ``rooms_south`` and, with the partitions between them, fill the corridor length.
        """

        def bad(name: str, why: str) -> BuildingSpecError:
            return BuildingSpecError(f"{why} (got {getattr(self, name)!r})", None, name)

        for name, value in asdict(self).items():
            if isinstance(value, float) and not math.isfinite(value):
                raise bad(name, "must be finite")
        if self.storeys < 1:
            raise bad("storeys", "need at least one storey")
        if self.rooms_north < 1 or self.rooms_south < 1:
            raise bad("rooms_north" if self.rooms_north < 1 else "rooms_south",
                      "need at least one room per side")
        for name in ("storey_height_m", "slab_thickness_m", "ceiling_thickness_m",
                     "corridor_length_m", "corridor_width_m", "room_depth_north_m",
                     "room_depth_south_m", "exterior_wall_thickness_m",
                     "interior_wall_thickness_m", "column_size_m", "round_column_radius_m",
                     "door_width_m", "door_height_m", "entrance_door_width_m", "window_width_m",
                     "window_height_m", "window_sill_m"):
            if getattr(self, name) <= 0:
                raise bad(name, "must be positive")
        if not 0 <= self.room_width_jitter < 0.5:
            raise bad("room_width_jitter", "must be in [0, 0.5)")
        if self.corridor_columns < 0:
            raise bad("corridor_columns", "must be >= 0")
        wall_top = self.storey_height_m - self.slab_thickness_m
        for name in ("ceiling_height_m", "corridor_ceiling_height_m"):
            if not self.door_height_m < getattr(self, name) < wall_top - self.ceiling_thickness_m:
                raise bad(name, "must lie between the door height and "
                                f"{wall_top - self.ceiling_thickness_m:g} (the slab above minus "
                                "the ceiling thickness)")
        if self.window_sill_m + self.window_height_m >= min(self.ceiling_height_m,
                                                            self.corridor_ceiling_height_m):
            raise bad("window_height_m", "window top must stay below the ceilings")
        min_room = self.door_width_m + 2 * ROOM_LOOP_MARGIN_M + 0.2
        for side, n in (("north", self.rooms_north), ("south", self.rooms_south)):
            clear = self.corridor_length_m - (n - 1) * self.interior_wall_thickness_m
            widths = getattr(self, f"room_widths_{side}_m")
            if widths is not None:
                name = f"room_widths_{side}_m"
                if len(widths) != n:
                    raise bad(name, f"need rooms_{side} = {n} widths")
                if abs(sum(widths) - clear) > 1e-6:
                    raise bad(name, f"widths must sum to {clear:.6f} m (corridor length minus "
                                    "the partitions)")
                if min(widths) < min_room:
                    raise bad(name, f"each room needs at least {min_room} m")
            elif clear / n * (1 - self.room_width_jitter) < min_room:
                raise bad("corridor_length_m",
                          f"too short for {n} rooms on the {side} side (each needs {min_room} m)")
        for name in ("room_depth_north_m", "room_depth_south_m"):
            if getattr(self, name) < 2 * ROOM_LOOP_MARGIN_M + 2 * self.round_column_radius_m + 0.5:
                raise bad(name, "room too shallow to walk around")
        if self.corridor_columns and self.corridor_width_m < self.column_size_m + 1.6:
            raise bad("corridor_width_m", "too narrow for columns and a walking lane")
        if self.corridor_end_window and self.window_width_m > self.corridor_width_m - 0.2:
            raise bad("window_width_m", "the corridor end window is wider than the corridor")
        if self.entrance_door_width_m > self.corridor_width_m - 0.2:
            raise bad("entrance_door_width_m", "the entrance is wider than the corridor")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> BuildingSpec:
        """Inverse of :meth:`to_dict` (the sidecar's ``spec``)."""
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(d) - known)
        if unknown:
            raise BuildingSpecError(f"unknown field(s) {unknown}", None, unknown[0])
        d = dict(d)
        for name in ("room_widths_north_m", "room_widths_south_m"):
            if d.get(name) is not None:
                d[name] = tuple(float(x) for x in d[name])
        return cls(**d)

    @classmethod
    def demo(cls) -> BuildingSpec:
        """The demo world (= ``BuildingSpec()``)."""
        return cls()

    @classmethod
    def tiny(cls) -> BuildingSpec:
        """A corridor and two rooms (one each side), one column of each kind; fast to ray-cast."""
        return cls(corridor_length_m=5.0, rooms_north=1, rooms_south=1, room_depth_north_m=3.6,
                   room_depth_south_m=4.0, corridor_columns=1)

    @classmethod
    def tower(cls) -> BuildingSpec:
        """The demo floor plan on three storeys."""
        return cls(storeys=3)


#: Named presets for the CLI.
PRESETS: dict[str, BuildingSpec] = {
    "demo": BuildingSpec.demo(),
    "tiny": BuildingSpec.tiny(),
    "tower": BuildingSpec.tower(),
}


def expected_counts(spec: BuildingSpec) -> dict[str, int]:
    """IFC element counts of the *design* building of ``spec`` (independent of the seed)."""
    n_rooms = spec.rooms_north + spec.rooms_south
    walls = 6 + (spec.rooms_north - 1) + (spec.rooms_south - 1)
    doors = spec.storeys * n_rooms + 1
    windows = spec.storeys * (n_rooms + int(spec.corridor_end_window))
    columns = spec.storeys * (spec.corridor_columns + int(spec.hall_round_column))
    return {
        "IfcBuildingStorey": spec.storeys,
        "IfcWall": spec.storeys * walls,
        "IfcSlab": spec.storeys + 1,
        "IfcCovering": spec.storeys * (n_rooms + 1),  # a ceiling per room and the corridor
        "IfcColumn": columns,
        "IfcDoor": doors,
        "IfcWindow": windows,
        "IfcOpeningElement": doors + windows,
    }


# --------------------------------------------------------------------------------------------
# The plan: storey-independent positions of every wall line, opening and column.


@dataclass(frozen=True)
class _OpeningPlan:
    key: str  # e.g. "door/north-2"
    kind: str  # "door" | "window"
    host: str  # wall key
    axis_pos: float  # centre coordinate along the host's axis (x for x-walls, y for y-walls)
    width: float
    sill: float
    height: float
    ground_floor_only: bool = False


@dataclass(frozen=True)
class _ColumnPlan:
    key: str
    shape: ColumnShape
    center: tuple[float, float]
    size: float  # side (rectangular) or radius (round)


@dataclass(frozen=True)
class _Plan:
    positions: dict[str, float]  # wall key -> centre-line coordinate (y for x-walls, x for y-walls)
    wall_kinds: dict[str, WallKind]
    openings: tuple[_OpeningPlan, ...]
    columns: tuple[_ColumnPlan, ...]
    corridor_path_y: float


def _is_x_wall(key: str) -> bool:
    """Walls running along x (direction +x); the others run along y (direction +y)."""
    return key in ("ext-south", "ext-north", "corr-south", "corr-north")


def _room_widths(total: float, n: int, thickness: float, jitter: float,
                 rng: np.random.Generator) -> NDArray[np.float64]:
    clear = total - (n - 1) * thickness
    w = 1.0 + jitter * rng.uniform(-1.0, 1.0, size=n)
    return clear * w / w.sum()


def _make_plan(spec: BuildingSpec, rng: np.random.Generator) -> _Plan:
    te, ti = spec.exterior_wall_thickness_m, spec.interior_wall_thickness_m
    half_w, length = spec.corridor_width_m / 2, spec.corridor_length_m
    pos: dict[str, float] = {
        "ext-south": -(half_w + ti + spec.room_depth_south_m + te / 2),
        "ext-north": half_w + ti + spec.room_depth_north_m + te / 2,
        "ext-west": -te / 2,
        "ext-east": length + te / 2,
        "corr-south": -(half_w + ti / 2),
        "corr-north": half_w + ti / 2,
    }
    kinds = {k: WallKind.EXTERIOR if k.startswith("ext") else WallKind.CORRIDOR for k in pos}
    room_spans: dict[str, list[tuple[float, float]]] = {}
    for side, n in (("north", spec.rooms_north), ("south", spec.rooms_south)):
        given = getattr(spec, f"room_widths_{side}_m")
        widths = _room_widths(length, n, ti, spec.room_width_jitter, rng) if given is None \
            else np.asarray(given, dtype=np.float64)
        x0, spans = 0.0, []
        for i, w in enumerate(widths):
            spans.append((x0, x0 + w))
            if i < n - 1:
                pos[f"part-{side}-{i + 1}"] = x0 + w + ti / 2
                kinds[f"part-{side}-{i + 1}"] = WallKind.PARTITION
            x0 += w + ti
        room_spans[side] = spans

    columns: list[_ColumnPlan] = []
    col_y = half_w - 0.45 - spec.column_size_m / 2
    if spec.corridor_columns:
        parts = [pos[f"part-north-{i}"] for i in range(1, spec.rooms_north)]
        if len(parts) >= spec.corridor_columns:
            idx = np.linspace(0, len(parts) - 1, spec.corridor_columns).round().astype(int)
            xs = [parts[i] for i in idx]
        else:
            xs = [length * (k + 1) / (spec.corridor_columns + 1)
                  for k in range(spec.corridor_columns)]
        columns += [_ColumnPlan(f"column/corridor-{k + 1}", ColumnShape.RECTANGULAR,
                                (float(x), col_y), spec.column_size_m) for k, x in enumerate(xs)]
    if spec.hall_round_column:
        spans = room_spans["south"]
        i = int(np.argmax([b - a for a, b in spans]))
        cy = -(half_w + ti + spec.room_depth_south_m / 2)
        columns.append(_ColumnPlan("column/hall", ColumnShape.ROUND,
                                   ((spans[i][0] + spans[i][1]) / 2, cy),
                                   spec.round_column_radius_m))
    # The corridor walking lane: midway between the columns' south faces and the south wall.
    path_y = (-half_w + col_y - spec.column_size_m / 2) / 2 if spec.corridor_columns else 0.0

    openings: list[_OpeningPlan] = []
    hw = spec.door_width_m / 2
    keep_out = [c.center[0] for c in columns if c.key.startswith("column/corridor")]
    for side in ("north", "south"):
        for i, (a, b) in enumerate(room_spans[side]):
            lo, hi = a + hw + 0.3, b - hw - 0.3
            lo, hi = max(lo, a + ROOM_LOOP_MARGIN_M + 0.05), min(hi, b - ROOM_LOOP_MARGIN_M - 0.05)
            grid = np.linspace(lo, hi, 64) if lo <= hi else np.zeros(0)
            if side == "north":
                for cx in keep_out:
                    grid = grid[np.abs(grid - cx) >= spec.column_size_m / 2 + WALK_CLEARANCE_M]
            if grid.size == 0:
                raise BuildingSpecError(f"no room for the door of {side}-{i + 1}", None,
                                        "corridor_length_m")
            x = float(grid[rng.integers(grid.size)])
            openings.append(_OpeningPlan(f"door/{side}-{i + 1}", "door", f"corr-{side}", x,
                                         spec.door_width_m, 0.0, spec.door_height_m))
    openings.append(_OpeningPlan("door/entrance", "door", "ext-west", 0.0,
                                 spec.entrance_door_width_m, 0.0, spec.door_height_m,
                                 ground_floor_only=True))
    for side in ("north", "south"):
        for i, (a, b) in enumerate(room_spans[side]):
            slack = max(0.0, (b - a - spec.window_width_m) / 2 - 0.3)
            x = float((a + b) / 2 + rng.uniform(-0.5, 0.5) * slack)
            openings.append(_OpeningPlan(f"window/{side}-{i + 1}", "window", f"ext-{side}", x,
                                         spec.window_width_m, spec.window_sill_m,
                                         spec.window_height_m))
    if spec.corridor_end_window:
        openings.append(_OpeningPlan("window/corridor-east", "window", "ext-east", 0.0,
                                     spec.window_width_m, spec.window_sill_m,
                                     spec.window_height_m))
    return _Plan(pos, kinds, tuple(openings), tuple(columns), path_y)


def _wall_lines(spec: BuildingSpec, pos: dict[str, float]
                ) -> dict[str, tuple[tuple[float, float], tuple[float, float], float]]:
    """Centre lines ``key -> (start, end, thickness)`` from the wall positions (butt joints)."""
    te, ti = spec.exterior_wall_thickness_m, spec.interior_wall_thickness_m
    out: dict[str, tuple[tuple[float, float], tuple[float, float], float]] = {}
    xw, xe = pos["ext-west"], pos["ext-east"]
    ys, yn = pos["ext-south"], pos["ext-north"]
    for key in ("ext-south", "ext-north"):
        out[key] = ((xw - te / 2, pos[key]), (xe + te / 2, pos[key]), te)
    for key in ("ext-west", "ext-east"):
        out[key] = ((pos[key], ys + te / 2), (pos[key], yn - te / 2), te)
    for key in ("corr-south", "corr-north"):
        out[key] = ((xw + te / 2, pos[key]), (xe - te / 2, pos[key]), ti)
    for key, x in pos.items():
        if key.startswith("part-north"):
            out[key] = ((x, pos["corr-north"] + ti / 2), (x, yn - te / 2), ti)
        elif key.startswith("part-south"):
            out[key] = ((x, ys + te / 2), (x, pos["corr-south"] - ti / 2), ti)
    return out


# --------------------------------------------------------------------------------------------
# Storey contents: the plan turned into walls, openings, columns, slabs and free space.


@dataclass
class _StoreyContent:
    truth: StoreyTruth
    walls: list[WallTruth] = field(default_factory=list)
    columns: list[ColumnTruth] = field(default_factory=list)
    doors: list[OpeningTruth] = field(default_factory=list)
    windows: list[OpeningTruth] = field(default_factory=list)
    slabs: list[SlabTruth] = field(default_factory=list)
    coverings: list[SlabTruth] = field(default_factory=list)
    free_space: FreeSpace | None = None


def _guid(seed: int, key: str) -> str:
    """A 22-character IFC GUID hashed from the design seed and an element id."""
    digest = hashlib.sha256(f"bimcap-building:{seed}:{key}".encode()).digest()[:16]
    import ifcopenshell.guid

    return ifcopenshell.guid.compress(uuid.UUID(bytes=digest, version=4).hex)


def _storey_content(spec: BuildingSpec, plan: _Plan, k: int, pos: dict[str, float],
                    column_offsets: dict[str, tuple[float, float]], missing: set[str],
                    design_seed: int) -> _StoreyContent:
    """Everything on storey ``k`` with the wall positions ``pos`` (design or as-built)."""
    elev = k * spec.storey_height_m
    wall_top = elev + spec.storey_height_m - spec.slab_thickness_m
    name = f"S{k}"
    st = _StoreyContent(StoreyTruth(k, name, _guid(design_seed, name), elev, elev,
                                    elev + spec.ceiling_height_m, wall_top))
    lines = _wall_lines(spec, pos)
    for key, (s, e, t) in lines.items():
        wid = f"{name}/wall/{key}"
        if wid in missing:
            continue
        st.walls.append(WallTruth(wid, _guid(design_seed, wid), k, plan.wall_kinds[key], s, e, t,
                                  elev, wall_top))
    for c in plan.columns:
        cid = f"{name}/{c.key}"
        if cid in missing:
            continue
        dx, dy = column_offsets.get(cid, (0.0, 0.0))
        center = (c.center[0] + dx, c.center[1] + dy)
        if c.shape is ColumnShape.ROUND:
            st.columns.append(ColumnTruth(cid, _guid(design_seed, cid), k, c.shape, center, None,
                                          c.size, elev, wall_top))
        else:
            st.columns.append(ColumnTruth(cid, _guid(design_seed, cid), k, c.shape, center,
                                          (c.size, c.size), None, elev, wall_top))
    for o in plan.openings:
        if o.ground_floor_only and k != 0:
            continue
        oid = f"{name}/{o.key}"
        host_s, _, _ = lines[o.host]
        if _is_x_wall(o.host):
            center = (o.axis_pos, host_s[1])
            direction = (1.0, 0.0)
        else:
            center = (host_s[0], o.axis_pos)
            direction = (0.0, 1.0)
        fill = None if oid in missing else _guid(design_seed, oid)
        ot = OpeningTruth(oid, o.kind, k, f"{name}/wall/{o.host}",
                          _guid(design_seed, oid + "/opening"), fill, center, direction, o.width,
                          elev + o.sill, elev + o.sill + o.height)
        (st.doors if o.kind == "door" else st.windows).append(ot)
    te = spec.exterior_wall_thickness_m
    # Slabs follow the design shell (they are not shifted in the as-built); the ceilings are
    # fitted between the walls as built (see _ceilings).
    xw, xe = plan.positions["ext-west"], plan.positions["ext-east"]
    ys, yn = plan.positions["ext-south"], plan.positions["ext-north"]
    outer = ((xw - te / 2, ys - te / 2), (xe + te / 2, ys - te / 2), (xe + te / 2, yn + te / 2),
             (xw - te / 2, yn + te / 2))
    sid = f"{name}/slab/floor"
    st.slabs.append(SlabTruth(sid, _guid(design_seed, sid), k, "IfcSlab",
                              "BASESLAB" if k == 0 else "FLOOR", outer,
                              elev - spec.slab_thickness_m, elev))
    if k == spec.storeys - 1:
        rid = f"{name}/slab/roof"
        top = elev + spec.storey_height_m
        st.slabs.append(SlabTruth(rid, _guid(design_seed, rid), k, "IfcSlab", "ROOF", outer,
                                  top - spec.slab_thickness_m, top))
    st.free_space = _free_space(spec, plan, k, pos, lines, st, missing)
    st.coverings += _ceilings(spec, k, st.free_space, design_seed)
    return st


def _ceilings(spec: BuildingSpec, k: int, free: FreeSpace, design_seed: int) -> list[SlabTruth]:
    """One suspended ceiling (IfcCovering CEILING) per room and one for the corridor.

    Each fills its room's clear rectangle (wall face to wall face, as the walls stand in this
    variant: a ceiling is fitted after the walls are built); where an as-built partition is
    missing, the room west (south) of it takes the strip the wall would have stood on, so the
    ceiling stays closed. Ids ``S{k}/ceiling/corridor``, ``S{k}/ceiling/north-1`` ...
    """
    name = f"S{k}"
    rects = {r.id.split("/")[-1]: r.rect for r in free.regions if r.kind in ("room", "corridor")}
    for r in free.regions:
        if r.kind != "removed_wall":
            continue
        side, i = r.id.split("/")[-1].split("-")[1:]  # "part-north-2" -> north, 2
        x0, y0, _, y1 = rects[f"{side}-{i}"]
        rects[f"{side}-{i}"] = (x0, y0, r.rect[2], y1)
    out = []
    for key in sorted(rects, key=lambda q: (q != "corridor", q)):
        x0, y0, x1, y1 = (float(v) for v in rects[key])
        z = k * spec.storey_height_m + (spec.corridor_ceiling_height_m if key == "corridor"
                                        else spec.ceiling_height_m)
        cid = f"{name}/ceiling/{key}"
        out.append(SlabTruth(cid, _guid(design_seed, cid), k, "IfcCovering", "CEILING",
                             ((x0, y0), (x1, y0), (x1, y1), (x0, y1)), z,
                             z + spec.ceiling_thickness_m))
    return out


def _free_space(spec: BuildingSpec, plan: _Plan, k: int, pos: dict[str, float],
                lines: dict[str, tuple[tuple[float, float], tuple[float, float], float]],
                st: _StoreyContent, missing: set[str]) -> FreeSpace:
    te, ti = spec.exterior_wall_thickness_m, spec.interior_wall_thickness_m
    name = f"S{k}"
    x_lo, x_hi = pos["ext-west"] + te / 2, pos["ext-east"] - te / 2
    cy0, cy1 = pos["corr-south"] + ti / 2, pos["corr-north"] - ti / 2
    regions = [Region(f"{name}/corridor", "corridor", (x_lo, cy0, x_hi, cy1))]
    rooms: dict[str, tuple[float, float, float, float]] = {}
    for side, n in (("north", spec.rooms_north), ("south", spec.rooms_south)):
        if side == "north":
            y0, y1 = cy1 + ti, pos["ext-north"] - te / 2
        else:
            y0, y1 = pos["ext-south"] + te / 2, cy0 - ti
        for i in range(1, n + 1):
            a = x_lo if i == 1 else pos[f"part-{side}-{i - 1}"] + ti / 2
            b = x_hi if i == n else pos[f"part-{side}-{i}"] - ti / 2
            rooms[f"{side}-{i}"] = (a, y0, b, y1)
            regions.append(Region(f"{name}/room/{side}-{i}", "room", (a, y0, b, y1)))
            part = f"{name}/wall/part-{side}-{i}"
            if i < n and part in missing:
                x = pos[f"part-{side}-{i}"]
                regions.append(Region(part, "removed_wall", (x - ti / 2, y0, x + ti / 2, y1)))
    for d in st.doors:
        hw = d.width / 2
        if d.direction[0] != 0.0:  # in an x-wall
            t = lines[d.host_wall.split("/")[-1]][2]
            rect = (d.center[0] - hw, d.center[1] - t / 2, d.center[0] + hw, d.center[1] + t / 2)
        else:
            t = lines[d.host_wall.split("/")[-1]][2]
            rect = (d.center[0] - t / 2, d.center[1] - hw, d.center[0] + t / 2, d.center[1] + hw)
        regions.append(Region(d.id, "door", rect))

    # Walk graph: a lane along the corridor, a branch through every room door, a loop per room.
    nodes: list[tuple[float, float]] = []
    edges: list[tuple[int, int]] = []

    def node(p: tuple[float, float]) -> int:
        nodes.append((float(p[0]), float(p[1])))
        return len(nodes) - 1

    lane_y = plan.corridor_path_y
    west = node((x_lo + WALK_CLEARANCE_M + 0.3, lane_y))
    east_x = x_hi - WALK_CLEARANCE_M - 0.3
    room_doors = sorted((d for d in st.doors if "/door/entrance" not in d.id),
                        key=lambda d: d.center[0])
    tour = [west]
    lane = [west]
    prev = west
    m = ROOM_LOOP_MARGIN_M
    for d in room_doors:
        side, room = ("north" if d.center[1] > 0 else "south"), d.id.split("/")[-1]
        a, y0, b, y1 = rooms[room]
        out = node((d.center[0], lane_y))
        edges.append((prev, out))
        door = node(d.center)
        edges.append((out, door))
        yin = y0 + m if side == "north" else y1 - m
        yfar = y1 - m if side == "north" else y0 + m
        inside = node((d.center[0], yin))
        edges.append((door, inside))
        c = [node((a + m, yin)), node((a + m, yfar)), node((b - m, yfar)), node((b - m, yin))]
        edges += [(inside, c[0]), (c[0], c[1]), (c[1], c[2]), (c[2], c[3]), (c[3], inside)]
        tour += [out, door, inside, c[0], c[1], c[2], c[3], inside, door, out]
        lane.append(out)
        prev = out
    east = node((east_x, lane_y))
    edges.append((prev, east))
    # Out to the east end of the lane, then back along it to the start: a closed walk.
    tour += [east, *reversed(lane)]
    return FreeSpace(k, st.truth.floor_z, tuple(regions), np.asarray(nodes, dtype=np.float64),
                     np.asarray(edges, dtype=np.int32).reshape(-1, 2),
                     np.asarray(tour, dtype=np.int32))


# --------------------------------------------------------------------------------------------
# IFC writing.


def _placement(origin: tuple[float, float, float], x_axis: tuple[float, float]
               ) -> NDArray[np.float64]:
    """(4, 4) world matrix: local x along ``x_axis`` (unit, horizontal), z up, at ``origin``."""
    m = np.eye(4)
    m[:3, 0] = [x_axis[0], x_axis[1], 0.0]
    m[:3, 1] = [-x_axis[1], x_axis[0], 0.0]
    m[:3, 3] = origin
    return m


@dataclass
class _IfcWriter:
    """The IFC file being written, its body context and the ``ifcopenshell.api.run`` entry."""

    f: ifcopenshell.file
    body: Any
    run: Any

    def place(self, product: Any, origin: tuple[float, float, float],
              x_axis: tuple[float, float] = (1.0, 0.0)) -> None:
        """Place ``product`` at ``origin`` (world metres), local x along ``x_axis``, z up."""
        self.run("geometry.edit_object_placement", self.f, product=product,
                 matrix=_placement(origin, x_axis), is_si=True)

    def contained(self, storey: Any, ifc_class: str, name: str, predefined_type: str) -> Any:
        """A new named element of ``ifc_class`` contained in ``storey``."""
        el = self.run("root.create_entity", self.f, ifc_class=ifc_class, name=name,
                      predefined_type=predefined_type)
        self.run("spatial.assign_container", self.f, relating_structure=storey, products=[el])
        return el

    def represent(self, product: Any, usecase: str, **settings: Any) -> None:
        """Give ``product`` a body representation made by the API usecase ``usecase``."""
        rep = self.run(usecase, self.f, context=self.body, **settings)
        self.run("geometry.assign_representation", self.f, product=product, representation=rep)


def _write_ifc(spec: BuildingSpec, storeys: list[_StoreyContent], design_seed: int,
               variant: Variant) -> ifcopenshell.file:
    """The IFC4 file of ``storeys``: spatial tree, elements, stable order and seeded GUIDs."""
    ifc, building = _new_ifc_file(design_seed, variant)
    for st in storeys:
        _write_storey(ifc, building, st)
    _sort_relations(ifc.f)
    _assign_guids(ifc.f, design_seed, variant)
    return ifc.f


def _new_ifc_file(design_seed: int, variant: Variant) -> tuple[_IfcWriter, Any]:
    """A new IFC4 file with header, project, units, contexts, site and building."""
    import ifcopenshell
    import ifcopenshell.api

    run = ifcopenshell.api.run
    f = ifcopenshell.file(schema="IFC4")
    f.header.file_name.time_stamp = HEADER_TIME_STAMP
    f.header.file_name.name = f"bimcap-building-{variant.value}-seed{design_seed}.ifc"
    project = run("root.create_entity", f, ifc_class="IfcProject", name="project")
    run("unit.assign_unit", f, length={"is_metric": True, "raw": "METRES"})
    model = run("context.add_context", f, context_type="Model")
    body = run("context.add_context", f, context_type="Model", context_identifier="Body",
               target_view="MODEL_VIEW", parent=model)
    site = run("root.create_entity", f, ifc_class="IfcSite", name="site")
    building = run("root.create_entity", f, ifc_class="IfcBuilding", name="building")
    run("aggregate.assign_object", f, relating_object=project, products=[site])
    run("aggregate.assign_object", f, relating_object=site, products=[building])
    return _IfcWriter(f, body, run), building


def _write_storey(ifc: _IfcWriter, building: Any, st: _StoreyContent) -> None:
    """One IfcBuildingStorey and its walls, openings and fills, columns, slabs and coverings."""
    s = st.truth
    storey = ifc.run("root.create_entity", ifc.f, ifc_class="IfcBuildingStorey", name=s.name)
    storey.Elevation = s.elevation
    ifc.run("aggregate.assign_object", ifc.f, relating_object=building, products=[storey])
    ifc.place(storey, (0.0, 0.0, s.elevation))
    ifc_walls = {w.id: _write_wall(ifc, storey, w) for w in st.walls}
    for o in (*st.doors, *st.windows):
        host = ifc_walls.get(o.host_wall)
        if host is None:
            continue
        t = next(w.thickness for w in st.walls if w.id == o.host_wall)
        opening = _write_opening(ifc, host, o, t)
        if o.fill_guid is not None:
            _write_fill(ifc, storey, opening, o, t)
    for c in st.columns:
        _write_column(ifc, storey, c)
    for sl in (*st.slabs, *st.coverings):
        el = ifc.contained(storey, sl.ifc_class, sl.id, sl.predefined_type)
        ifc.place(el, (0.0, 0.0, sl.z_min))
        ifc.represent(el, "geometry.add_slab_representation", depth=sl.z_max - sl.z_min,
                      polyline=[tuple(p) for p in sl.polygon])


def _write_wall(ifc: _IfcWriter, storey: Any, w: WallTruth) -> Any:
    """An IfcWall (extruded along its axis from ``w.start``, centred on it); returns it."""
    wall_type = "SOLIDWALL" if w.kind is WallKind.EXTERIOR else "PARTITIONING"
    wall = ifc.contained(storey, "IfcWall", w.id, wall_type)
    d = w.direction
    ifc.place(wall, (w.start[0], w.start[1], w.z_min), (float(d[0]), float(d[1])))
    ifc.represent(wall, "geometry.add_wall_representation", length=w.length,
                  height=w.z_max - w.z_min, thickness=w.thickness, offset=-w.thickness / 2)
    return wall


def _opening_corner(o: OpeningTruth) -> tuple[tuple[float, float], tuple[float, float]]:
    """``(corner, normal)``: the opening's start on the wall axis (world xy) and the wall normal."""
    d = o.direction
    n = (-d[1], d[0])
    corner = (o.center[0] - d[0] * o.width / 2, o.center[1] - d[1] * o.width / 2)
    return corner, n


def _write_opening(ifc: _IfcWriter, host: Any, o: OpeningTruth, t: float) -> Any:
    """An IfcOpeningElement through the host wall (``t`` m thick, 5 cm spare on each face)."""
    corner, n = _opening_corner(o)
    opening = ifc.run("root.create_entity", ifc.f, ifc_class="IfcOpeningElement",
                      name=o.id + "/opening", predefined_type="OPENING")
    eps = 0.05
    ifc.place(opening, (corner[0] - n[0] * (t / 2 + eps), corner[1] - n[1] * (t / 2 + eps),
                        o.z_min), o.direction)
    ifc.represent(opening, "geometry.add_wall_representation", length=o.width,
                  height=o.z_max - o.z_min, thickness=t + 2 * eps, offset=0.0)
    ifc.run("feature.add_feature", ifc.f, feature=opening, element=host)
    return opening


def _write_fill(ifc: _IfcWriter, storey: Any, opening: Any, o: OpeningTruth, t: float) -> None:
    """The IfcDoor or IfcWindow filling ``opening`` (lining ``t`` m deep)."""
    corner, n = _opening_corner(o)
    cls = "IfcDoor" if o.kind == "door" else "IfcWindow"
    fill = ifc.contained(storey, cls, o.id, "DOOR" if o.kind == "door" else "WINDOW")
    ifc.place(fill, (corner[0] - n[0] * t / 2, corner[1] - n[1] * t / 2, o.z_min), o.direction)
    height = o.z_max - o.z_min
    if o.kind == "door":
        ifc.represent(fill, "geometry.add_door_representation", overall_height=height,
                      overall_width=o.width,
                      lining_properties={"LiningDepth": t, "LiningThickness": 0.05})
    else:
        ifc.represent(fill, "geometry.add_window_representation", overall_height=height,
                      overall_width=o.width,
                      lining_properties={"LiningDepth": t, "LiningThickness": 0.05,
                                         "LiningOffset": 0.0})
    fill.OverallHeight = height
    fill.OverallWidth = o.width
    ifc.run("feature.add_filling", ifc.f, opening=opening, element=fill)


def _write_column(ifc: _IfcWriter, storey: Any, c: ColumnTruth) -> None:
    """An IfcColumn: a circle or rectangle profile extruded from ``c.z_min`` to ``c.z_max``."""
    col = ifc.contained(storey, "IfcColumn", c.id, "COLUMN")
    ifc.place(col, (c.center[0], c.center[1], c.z_min))
    if c.shape is ColumnShape.ROUND:
        profile = ifc.f.create_entity("IfcCircleProfileDef", ProfileType="AREA",
                                      ProfileName=c.id, Radius=c.radius)
    else:
        assert c.size is not None
        profile = ifc.f.create_entity("IfcRectangleProfileDef", ProfileType="AREA",
                                      ProfileName=c.id, XDim=c.size[0], YDim=c.size[1])
    ifc.represent(col, "geometry.add_profile_representation", profile=profile,
                  depth=c.z_max - c.z_min)


def _sort_relations(f: ifcopenshell.file) -> None:
    """Put the elements the API collects in sets into file order, for stable bytes."""
    for rel in f.by_type("IfcRelContainedInSpatialStructure"):
        rel.RelatedElements = sorted(rel.RelatedElements, key=lambda e: e.id())
    for rel in f.by_type("IfcRelAggregates"):
        rel.RelatedObjects = sorted(rel.RelatedObjects, key=lambda e: e.id())
    for units in f.by_type("IfcUnitAssignment"):
        units.Units = sorted(units.Units, key=lambda e: e.id())


def _assign_guids(f: ifcopenshell.file, design_seed: int, variant: Variant) -> None:
    """Seeded GUIDs: named elements keep theirs between design and as-built (hash of the id);
    relationships are numbered in file order."""
    counter: dict[str, int] = {}
    for ent in sorted(f.by_type("IfcRoot"), key=lambda e: e.id()):
        name = ent.Name
        if name is None:
            cls = ent.is_a()
            counter[cls] = counter.get(cls, 0) + 1
            name = f"{variant.value}:{cls}:{counter[cls]}"
        ent.GlobalId = _guid(design_seed, name)


# --------------------------------------------------------------------------------------------
# Public API.


def truth_path_for(ifc_path: str | PathLike[str]) -> Path:
    """The sidecar path of an IFC: ``NAME.ifc`` → ``NAME.truth.json``."""
    p = Path(ifc_path)
    return p.with_name(p.stem + ".truth.json")


@dataclass
class GeneratedBuilding:
    """A generated building: the IFC in memory, its ground truth, and where both were written.

    Attributes
    ----------
    spec: the parameters.
    seed: the design seed (layout jitter, door/window positions, GUIDs).
    ifc: the ``ifcopenshell.file``.
    truth: the ground truth; ``truth.to_dict()`` is the sidecar.
    ifc_path, truth_path: where they were written (None until :meth:`write`).
    """

    spec: BuildingSpec
    seed: int
    ifc: ifcopenshell.file
    truth: BuildingTruth
    ifc_path: Path | None = None
    truth_path: Path | None = None

    @property
    def variant(self) -> Variant:
        return self.truth.variant

    def ifc_text(self) -> str:
        """The IFC file's STEP text, exactly as :meth:`write` writes it."""
        return str(self.ifc.to_string())

    def write(self, ifc_path: str | PathLike[str]) -> Path:
        """Write the IFC and its sidecar ``NAME.truth.json`` atomically; returns the IFC path."""
        path = Path(ifc_path)
        if path.suffix.lower() != ".ifc":
            raise BuildingSpecError("output must end in .ifc", path)
        text = self.ifc_text()
        atomic_write_text(path, text)
        atomic_write_json(truth_path_for(path), self.truth.to_dict())
        # after the writes: a failed one is the command's one error line, nothing before it
        _log.info(f"wrote the {self.truth.variant.value} building {path} and its "
                  f"{truth_path_for(path).name}")
        _log.debug(f"{path}: {len(text)} characters of IFC, {len(self.truth.walls)} walls, "
                   f"{len(self.truth.columns)} columns")
        self.ifc_path, self.truth_path = path, truth_path_for(path)
        return path


def _assemble(spec: BuildingSpec, seed: int, plan: _Plan, variant: Variant,
              positions: list[dict[str, float]], column_offsets: dict[str, tuple[float, float]],
              missing: set[str], deviations: Deviations | None) -> tuple[ifcopenshell.file,
                                                                         BuildingTruth]:
    storeys = [_storey_content(spec, plan, k, positions[k], column_offsets, missing, seed)
               for k in range(spec.storeys)]
    f = _write_ifc(spec, storeys, seed, variant)
    counts = {cls: len(f.by_type(cls)) for cls in expected_counts(spec)}
    truth = BuildingTruth(
        variant=variant,
        seed=seed,
        spec=spec.to_dict(),
        storeys=tuple(s.truth for s in storeys),
        walls=tuple(w for s in storeys for w in s.walls),
        columns=tuple(c for s in storeys for c in s.columns),
        doors=tuple(d for s in storeys for d in s.doors),
        windows=tuple(w for s in storeys for w in s.windows),
        slabs=tuple(x for s in storeys for x in s.slabs),
        coverings=tuple(x for s in storeys for x in s.coverings),
        free_space=tuple(s.free_space for s in storeys if s.free_space is not None),
        counts=counts,
        deviations=deviations,
    )
    return f, truth


def generate_building(spec: BuildingSpec | None = None, seed: int = 0,
                      ifc_path: str | PathLike[str] | None = None) -> GeneratedBuilding:
    """Generate the design IFC4 building of ``spec`` (default: the demo world) with ``seed``.

    Parameters
    ----------
    spec: the parameters; ``None`` means ``BuildingSpec()``.
    seed: drives room widths, door and window positions and the GUIDs.
    ifc_path: if given, the IFC and its ``.truth.json`` sidecar are written there.

    Returns
    -------
    GeneratedBuilding
        The same seed always gives the same IFC text, byte for byte.
    """
    spec = BuildingSpec() if spec is None else spec
    seed = int(seed)
    plan = _make_plan(spec, np.random.default_rng(seed))
    f, truth = _assemble(spec, seed, plan, Variant.DESIGN,
                         [dict(plan.positions) for _ in range(spec.storeys)], {}, set(), None)
    out = GeneratedBuilding(spec, seed, f, truth)
    if ifc_path is not None:
        out.write(ifc_path)
    return out


def as_built(design: BuildingSpec | GeneratedBuilding, seed: int, shift_sigma_m: float = 0.03,
             missing_fraction: float = 0.1, *, design_seed: int | None = None,
             datum: Sequence[str] = (),
             ifc_path: str | PathLike[str] | None = None) -> GeneratedBuilding:
    """The building as built: walls shifted, columns offset, some interior elements missing.

    Parameters
    ----------
    design: the design building, or its spec (then ``design_seed`` names the design's seed,
        default ``seed``).
    seed: seed of the deviations.
    shift_sigma_m: standard deviation (m) of each wall's shift along its normal and of each
        column's offset per axis; clipped to ±2.5 sigma and to less than half an interior wall.
    missing_fraction: fraction of the removable elements (partitions, columns, door and window
        fills) left out; never exterior walls, corridor walls, slabs or ceilings.
    datum: plan keys of walls (``"ext-south"``) and columns (``"column/corridor-1"``) built
        exactly as designed on every storey and never left out, like surveyed control lines;
        recorded as ``truth.deviations.datum`` (element ids). The random draws of the other
        elements are those without a datum.
    ifc_path: if given, the IFC and sidecar are written there.

    Returns
    -------
    GeneratedBuilding
        Its ``truth.deviations`` records every shift, offset and missing element id; elements
        keep the design's GUIDs.
    """
    if isinstance(design, GeneratedBuilding):
        spec, dseed = design.spec, design.seed
    else:
        spec, dseed = design, int(seed if design_seed is None else design_seed)
    if not (math.isfinite(shift_sigma_m) and shift_sigma_m >= 0):
        raise BuildingSpecError(f"must be finite and >= 0 (got {shift_sigma_m})", None,
                                "shift_sigma_m")
    if not 0 <= missing_fraction <= 1:
        raise BuildingSpecError(f"must be in [0, 1] (got {missing_fraction})", None,
                                "missing_fraction")
    plan = _make_plan(spec, np.random.default_rng(dseed))
    known = set(plan.positions) | {c.key for c in plan.columns}
    for key in datum:
        if key not in known:
            raise BuildingSpecError(f"unknown wall or column key {key!r} (known: "
                                    f"{sorted(known)})", None, "datum")
    rng = np.random.default_rng([dseed, int(seed), 0xA5B1])
    limit = min(2.5 * shift_sigma_m, 0.45 * spec.interior_wall_thickness_m)
    positions: list[dict[str, float]] = []
    wall_shifts: dict[str, float] = {}
    col_offsets: dict[str, tuple[float, float]] = {}
    removable: list[str] = []
    for k in range(spec.storeys):
        pos = dict(plan.positions)
        for key in sorted(pos):
            shift = float(np.clip(rng.normal(0.0, shift_sigma_m) if shift_sigma_m else 0.0,
                                  -limit, limit))
            if key in datum:
                shift = 0.0
            # Positions are y for x-walls (normal +y) and x for y-walls (normal -x).
            pos[key] += shift if _is_x_wall(key) else -shift
            wall_shifts[f"S{k}/wall/{key}"] = shift
        positions.append(pos)
        for c in plan.columns:
            off = np.clip(rng.normal(0.0, shift_sigma_m, size=2) if shift_sigma_m
                          else np.zeros(2), -limit, limit)
            if c.key in datum:
                off = np.zeros(2)
            col_offsets[f"S{k}/{c.key}"] = (float(off[0]), float(off[1]))
            removable.append(f"S{k}/{c.key}")
        removable += [f"S{k}/wall/{key}" for key in sorted(pos) if key.startswith("part-")]
        removable += [f"S{k}/{o.key}" for o in plan.openings
                      if not (o.ground_floor_only and k != 0)]
    datum_ids = tuple(sorted(f"S{k}/wall/{key}" if key in plan.positions else f"S{k}/{key}"
                             for k in range(spec.storeys) for key in datum))
    removable = [r for r in removable if r not in datum_ids]
    n_missing = int(round(missing_fraction * len(removable)))  # noqa: RUF046 (numpy < 2)
    missing = sorted(str(x) for x in rng.choice(removable, size=n_missing, replace=False))
    # Elements that are missing have no shift/offset to speak of.
    wall_shifts = {k: v for k, v in wall_shifts.items() if k not in missing}
    col_offsets = {k: v for k, v in col_offsets.items() if k not in missing}
    dev = Deviations(int(seed), float(shift_sigma_m), float(missing_fraction), wall_shifts,
                     col_offsets, tuple(missing), datum_ids)
    f, truth = _assemble(spec, dseed, plan, Variant.AS_BUILT, positions, col_offsets,
                         set(missing), dev)
    out = GeneratedBuilding(spec, dseed, f, truth)
    if ifc_path is not None:
        out.write(ifc_path)
    return out


def replace_spec(spec: BuildingSpec, **changes: Any) -> BuildingSpec:
    """``dataclasses.replace`` that reports unknown fields as :class:`BuildingSpecError`."""
    unknown = sorted(set(changes) - set(BuildingSpec.__dataclass_fields__))
    if unknown:
        raise BuildingSpecError(f"unknown field(s) {unknown}", None, unknown[0])
    return replace(spec, **changes)
