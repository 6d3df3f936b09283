"""Where a person can walk in an arbitrary building: storeys, floors, doors and clearance.

The building generator writes free-space polygons next to its IFC; a real model has none. This
module finds the walkable space of any model from its triangles alone, per **level** (a storey
of the model, or a height given by the user), on a grid of ``resolution_m`` cells:

1. **Floor under the cell**: a ray cast down from ``level.z + probe_m`` must first hit an almost
   horizontal FLOOR triangle between ``level.z - below_m`` and ``level.z + above_m``. So walls
   (a probe inside a wall hits its base), stairs, furniture and table tops are not floor; several
   floor heights on one storey (finishes, sunken areas, landings, steps) each keep their own
   height in ``FreeSpace.floor_z``.
2. **Indoors**: a ray cast up hits something within ``max_headroom_m``, and at least
   ``enclosure_share`` of ``enclosure_rays`` horizontal rays cast at 1.3 m above the local floor
   hit the building within ``enclosure_range_m`` (walls, windows, a door frame). A terrace, a
   porch under an overhang, the ground around the house are outside; rays that leave through a
   few open doorways are tolerated.
3. **Clearance** (``FreeSpace``): the exact 3-D distance to the nearest triangle at several
   heights above the local floor, capped by the distance to the region's border (a stairwell, the
   edge of a landing).
4. **Doors**: door leaves are not part of the world (the simulator removes them); the cells of a
   door's footprint (``door_polygons``) are *passages* where the walker needs only
   ``WalkConfig.door_clearance_m``, so a 0.76 m door leads into the room behind it.
5. **Connectivity**: neighbouring walkable cells connect when their floors differ by at most
   ``WalkConfig.max_step_m``; the level's walkable area is its largest connected piece.

:func:`choose_free_space` surveys every level (or the one asked for) and keeps the one with the
largest connected walkable area; it raises :class:`~bimcap.sim.render.SimError` naming the model
and the levels tried when nothing is walkable. A survey takes seconds: the rays and distance
queries are batched through Open3D's ``RaycastingScene``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from bimcap.labels import Label
from bimcap.sim.render import SimError, World
from bimcap.sim.walk import FreeSpace, WalkConfig

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Level:
    """A candidate floor to walk on.

    Attributes
    ----------
    name: the storey's name (``"z=+1.25"`` for a height given by the user).
    z: reference floor height in metres (the storey's elevation); the actual floor heights are
        found by ray casting around it.
    """

    name: str
    z: float


@dataclass(frozen=True)
class WalkableOptions:
    """How the walkable space of a level is found (see the module docstring).

    Attributes
    ----------
    resolution_m: grid cell size.
    probe_m: height above ``level.z`` of the rays cast down to find the floor.
    below_m, above_m: accepted floor heights ``level.z - below_m .. level.z + above_m``.
    max_floor_tilt_deg: steepest surface that counts as floor (ramps up to this).
    max_headroom_m: an upward ray must hit something within this (indoors).
    enclosure_rays, enclosure_share, enclosure_range_m: horizontal rays at 1.3 m; the share that
        must hit within the range.
    heights_m: heights above the local floor at which clearance is measured.
    """

    resolution_m: float = 0.1
    probe_m: float = 1.2
    below_m: float = 1.0
    above_m: float = 0.6
    max_floor_tilt_deg: float = 15.0
    max_headroom_m: float = 8.0
    enclosure_rays: int = 16
    enclosure_share: float = 0.75
    enclosure_range_m: float = 40.0
    heights_m: tuple[float, ...] = (0.5, 1.0, 1.3, 1.6)

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass
class LevelSurvey:
    """What one level offers.

    Attributes
    ----------
    name, z: the level.
    floor_m2: area with a floor under it (indoors or not).
    indoor_m2: floor area that is indoors.
    walkable_m2: the largest connected walkable area (clearance and steps respected).
    floor_heights_m: (min, median, max) floor height over the walkable piece (None if none).
    seconds: time of the survey.
    """

    name: str
    z: float
    floor_m2: float
    indoor_m2: float
    walkable_m2: float
    floor_heights_m: tuple[float, float, float] | None
    seconds: float

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass
class WalkableChoice:
    """The level chosen to walk on, its free space and the survey of every level tried."""

    free: FreeSpace
    level: Level
    surveys: list[LevelSurvey]
    seconds: float

    def to_dict(self) -> dict[str, object]:
        return {
            "storey": self.level.name,
            "z_level": self.level.z,
            "z_floor": self.free.z_floor,
            "surveys": [s.to_dict() for s in self.surveys],
            "seconds": self.seconds,
        }


def door_footprints(parts: Sequence[object], depth_margin_m: float = 0.3) -> list[F64]:
    """xy footprints of door elements: each door's minimum rotated rectangle, widened by
    ``depth_margin_m`` so that it spans the wall the door sits in.

    Parameters
    ----------
    parts: :class:`~bimcap.sim.render.MeshPart` objects (only their vertices are used).

    Returns
    -------
    list of (K, 2) float64 world xy rings (not closed).
    """
    import shapely

    out = []
    for part in parts:
        v = np.asarray(part.vertices, np.float64).reshape(-1, 3)
        if len(v) < 3:
            continue
        rect = shapely.MultiPoint(v[:, :2]).minimum_rotated_rectangle
        if rect.geom_type != "Polygon":
            rect = rect.buffer(0.05)
        grown = rect.buffer(depth_margin_m, join_style="mitre")
        out.append(np.asarray(grown.exterior.coords, np.float64)[:-1])
    return out


def levels_from_floors(world: World, min_area_m2: float = 4.0) -> list[Level]:
    """Levels at the heights of the world's up-facing floor triangles (5 cm bins holding at
    least ``min_area_m2``), for worlds without storeys."""
    tri = world.world_vertices()[world.faces]
    sel = world.tri_label == Label.FLOOR
    n = np.cross(tri[sel, 1] - tri[sel, 0], tri[sel, 2] - tri[sel, 0])
    norm = np.linalg.norm(n, axis=1)
    up = n[:, 2] > 0.95 * np.maximum(norm, 1e-12)
    if not up.any():
        return []
    z = tri[sel][up][:, :, 2].mean(axis=1)
    area = 0.5 * norm[up]
    bins = np.round(z / 0.05).astype(np.int64)
    uniq, inv = np.unique(bins, return_inverse=True)
    weight = np.bincount(inv, weights=area)
    out: list[Level] = []
    for b in uniq[weight >= min_area_m2]:
        zb = float(b * 0.05)
        if not out or zb - out[-1].z > 1.5:
            out.append(Level(f"z={zb:+.2f}", zb))
    return out


def _rasterize(polygons: Sequence[F64], origin_xy: F64, shape: tuple[int, int],
               resolution: float) -> NDArray[np.bool_]:
    import cv2

    mask = np.zeros(shape, np.uint8)
    for poly in polygons:
        px = (np.asarray(poly, np.float64).reshape(-1, 2) - origin_xy) / resolution
        cv2.fillPoly(mask, [np.rint(px * 16).astype(np.int32)], 1, shift=4)
    return mask.astype(bool)


class _Grid:
    """The cell centres over the world's xy extent."""

    def __init__(self, world: World, resolution: float) -> None:
        v = world.world_vertices()
        self.origin = v[:, :2].min(axis=0).astype(np.float64) - 0.5
        hi = v[:, :2].max(axis=0).astype(np.float64) + 0.5
        w, h = (np.ceil((hi - self.origin) / resolution).astype(int) + 1)
        self.shape = (int(h), int(w))
        self.resolution = resolution
        ys, xs = np.mgrid[0:h, 0:w]
        self.xy = np.stack([xs.ravel(), ys.ravel()], axis=-1) * resolution + self.origin


def survey_level(
    world: World,
    level: Level,
    door_polygons: Sequence[F64] = (),
    walk: WalkConfig | None = None,
    options: WalkableOptions | None = None,
    grid: _Grid | None = None,
) -> tuple[LevelSurvey, FreeSpace]:
    """The free space of one level (module docstring) and what it offers.

    Returns
    -------
    (LevelSurvey, FreeSpace): ``FreeSpace.region`` is the indoor floor, ``floor_z`` the local
    floor height per cell, ``passage`` the door cells, ``z_floor`` the median floor height of
    the largest walkable piece (``level.z`` when there is none).
    """
    t0 = time.perf_counter()
    opts = options or WalkableOptions()
    cfg = walk or WalkConfig()
    g = grid or _Grid(world, opts.resolution_m)
    res = g.resolution
    cell_m2 = res * res
    n = len(g.xy)

    # 1. floor under each cell
    origins = np.concatenate([g.xy, np.full((n, 1), level.z + opts.probe_m)], axis=1)
    down = world.cast(origins, np.tile([0.0, 0.0, -1.0], (n, 1)))
    t = down["t_hit"]
    hit = np.isfinite(t)
    prim = np.where(hit, down["primitive_ids"], 0).astype(np.int64)
    floor_z = np.where(hit, level.z + opts.probe_m - t, np.nan)
    flat = np.abs(down["primitive_normals"][:, 2]) >= np.cos(np.deg2rad(opts.max_floor_tilt_deg))
    floor = (hit & flat & (world.tri_label[prim] == Label.FLOOR)
             & (floor_z >= level.z - opts.below_m) & (floor_z <= level.z + opts.above_m))
    floor_m2 = float(floor.sum() * cell_m2)

    # 2. indoors: a roof or ceiling above, walls around
    idx = np.flatnonzero(floor)
    up = world.cast(origins[idx], np.tile([0.0, 0.0, 1.0], (len(idx), 1)))["t_hit"]
    idx = idx[up < opts.max_headroom_m]
    k = opts.enclosure_rays
    ang = 2.0 * np.pi * (np.arange(k) + 0.5) / k
    dirs = np.stack([np.cos(ang), np.sin(ang), np.zeros(k)], axis=1)
    o = np.concatenate([g.xy[idx], floor_z[idx, None] + 1.3], axis=1)
    t_h = world.cast(np.repeat(o, k, axis=0), np.tile(dirs, (len(idx), 1)))["t_hit"]
    share = (t_h.reshape(-1, k) < opts.enclosure_range_m).mean(axis=1)
    idx = idx[share >= opts.enclosure_share]
    region = np.zeros(n, bool)
    region[idx] = True
    region = region.reshape(g.shape)
    indoor_m2 = float(region.sum() * cell_m2)

    fz = np.full(g.shape, np.nan, np.float32)
    fz.reshape(-1)[idx] = floor_z[idx]
    passage = _rasterize(door_polygons, g.origin, g.shape, res) if door_polygons else None
    free = FreeSpace._with_clearance(world, region, g.origin, res, level.z, opts.heights_m,
                                     floor_z=fz, passage=passage)
    free.storey = level.name

    # 3. the largest connected walkable piece
    comp, sizes = free.components(cfg)
    walkable_m2 = float(sizes.max() * cell_m2) if len(sizes) else 0.0
    heights = None
    if len(sizes):
        zs = fz[comp == int(np.argmax(sizes))]
        heights = (float(zs.min()), float(np.median(zs)), float(zs.max()))
        free.z_floor = heights[1]
    survey = LevelSurvey(level.name, level.z, floor_m2, indoor_m2, walkable_m2, heights,
                         time.perf_counter() - t0)
    return survey, free


def choose_free_space(
    world: World,
    levels: Sequence[Level],
    storey: str | None = None,
    z_floor: float | None = None,
    door_polygons: Sequence[F64] = (),
    walk: WalkConfig | None = None,
    options: WalkableOptions | None = None,
    model_name: str = "the model",
) -> WalkableChoice:
    """Survey the levels and keep the one with the largest connected walkable area.

    Parameters
    ----------
    world: the world as rendered (door leaves removed).
    levels: candidate levels (the model's storeys); when empty, :func:`levels_from_floors`.
    storey: walk this storey (by name) instead of choosing.
    z_floor: walk at this floor height instead (a level named ``z=...``); wins over ``storey``.
    door_polygons: door footprints (:func:`door_footprints`), passable with less clearance.
    walk: the walker (clearance, door clearance, largest step).
    model_name: named in error messages.

    Raises
    ------
    SimError: an unknown storey name, or no walkable space on the level(s) tried (the message
        names the model, each level and what it offered).
    """
    t0 = time.perf_counter()
    opts = options or WalkableOptions()
    cfg = walk or WalkConfig()
    if z_floor is not None:
        todo = [Level(f"z={z_floor:+.2f}", float(z_floor))]
    elif storey is not None:
        todo = [lv for lv in levels if lv.name == storey]
        if not todo:
            names = ", ".join(repr(lv.name) for lv in levels) or "none"
            raise SimError(f"{model_name}: no storey named {storey!r} (storeys: {names})")
    else:
        todo = list(levels) or levels_from_floors(world)
        if not todo:
            raise SimError(f"{model_name}: no storeys and no floor surfaces to walk on; "
                           "pass z_floor (--z-floor) explicitly")
    grid = _Grid(world, opts.resolution_m)
    results = [survey_level(world, lv, door_polygons, cfg, opts, grid) for lv in todo]
    surveys = [s for s, _ in results]
    best = int(np.argmax([s.walkable_m2 for s in surveys]))
    if surveys[best].walkable_m2 <= 0.0:
        tried = "; ".join(
            f"{s.name!r} (z {s.z:+.2f} m): floor {s.floor_m2:.1f} m², "
            f"indoors {s.indoor_m2:.1f} m², walkable 0 m²" for s in surveys)
        raise SimError(
            f"{model_name}: nothing to walk on: no connected space with a floor, a roof and "
            f"{cfg.min_clearance_m} m clearance ({tried})"
        )
    return WalkableChoice(results[best][1], todo[best], surveys, time.perf_counter() - t0)


def free_space_from_world(
    world: World,
    z_floor: float | None = None,
    resolution: float = 0.1,
    heights_m: Sequence[float] = (0.5, 1.0, 1.3, 1.6),
    door_polygons: Sequence[F64] = (),
    config: WalkConfig | None = None,
) -> FreeSpace:
    """The walkable region of an arbitrary building at one floor height (no polygons available).

    ``z_floor`` defaults to :func:`bimcap.sim.walk.detect_floor_height`. A cell is inside when a
    ray cast down from ``z_floor + 1.2`` first hits a FLOOR surface near ``z_floor``, a ray cast up
    hits a roof or ceiling, and horizontal rays find walls around it (:func:`survey_level`, which
    also explains ``door_polygons``).
    """
    from bimcap.sim.walk import detect_floor_height

    if z_floor is None:
        z_floor = detect_floor_height(world)
    opts = WalkableOptions(resolution_m=resolution, heights_m=tuple(heights_m))
    _, free = survey_level(world, Level(f"z={z_floor:+.2f}", float(z_floor)), door_polygons,
                           config, opts)
    return free
