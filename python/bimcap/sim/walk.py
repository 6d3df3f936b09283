"""A handheld walking trajectory through the free space of one storey.

Planning happens on a 2-D grid over the storey:

1. **Region** (:class:`FreeSpace`): the cells that are inside the walkable space — rasterised from
   free-space polygons (rooms, corridors, door passages; e.g. the building generator's sidecar),
   or, for an arbitrary IFC, derived from the meshes by :mod:`bimcap.sim.walkable` (a floor
   under the cell, a roof over it, walls around it; the local floor height per cell in
   ``FreeSpace.floor_z``, door footprints as ``FreeSpace.passage``).
2. **Clearance**: the exact 3-D distance from each cell, at several heights above its floor, to
   the nearest triangle of the world (Open3D ``compute_distance``), capped by the distance to
   the region's border. Cells with clearance below ``min_clearance_m`` (``door_clearance_m`` in
   door passages) are not walkable; neighbouring cells whose floors differ by more than
   ``max_step_m`` are not connected.
3. **Tour**: way-points are spread over the well-clear cells (farthest-point sampling); the walker
   goes from one to the nearest unvisited one (geodesic, Dijkstra on the 8-connected grid with a
   cost that prefers clearance), so rooms are entered through their doors, until the path is long
   enough.
4. **Smoothing and timing**: the grid path is resampled, Gaussian-smoothed (pulled back towards the
   raw path wherever smoothing would cut a corner into the clearance margin), and walked at
   ``speed_mps`` (slower in turns, with a slow speed variation).
5. **Orientation**: yaw looks ahead along the path, plus occasional head turns toward the wall on
   the more open side; yaw rate is limited so consecutive frames overlap; pitch and roll sway at
   the step frequency plus slow drifts around the walking pitch ``pitch_deg`` (a little down, so
   that the floor is in view), and now and then the walker looks up (a smooth glance of up to
   ``pitch_amplitude_deg`` above the walking pitch, every ``look_up_interval_s`` on average), as
   people do, so that the camera and the rigidly mounted LiDAR see the ceiling; the camera
   height stays within ``height_range_m`` above the local floor (smoothed along the path, so a
   step down is taken, not jumped).

Poses are ``world_from_cam`` in the OpenCV optical convention (x right, y down, z forward): with
yaw ψ (heading in the world xy plane, from +x toward +y), pitch θ (positive = looking up) and
roll φ (about the optical axis), ``R = R_level(ψ) · Rx(θ) · Rz(φ)`` where ``R_level(ψ)`` has
columns right = (sin ψ, −cos ψ, 0), down = (0, 0, −1), forward = (cos ψ, sin ψ, 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.poses import rotmat_to_quat
from bimcap.labels import Label
from bimcap.sim.render import SimConfigError, SimError, World

F64 = NDArray[np.float64]


#: The walking pitch of the handheld camera, degrees (negative = looking down). One default for
#: the simulator, its command line and ``bimcap demo``: a ConSLAM-like narrow view (about ±18°
#: vertically) sees the floor a few metres ahead only when it looks a little down.
DEFAULT_PITCH_DEG = -12.0


@dataclass(frozen=True)
class WalkConfig:
    """Parameters of the handheld walk.

    Attributes
    ----------
    speed_mps: nominal walking speed.
    height_range_m: (min, max) camera height above the storey floor.
    min_clearance_m: hard minimum distance from the camera path to any surface.
    door_clearance_m: the minimum in door passages (``FreeSpace.passage``): a walker squeezes
        through a 0.76 m door whose middle is 0.38 m from the jambs.
    max_step_m: largest floor-height difference between neighbouring cells the walker steps over.
    preferred_clearance_m: clearance below which the path cost rises (keeps to the middle).
    grid_m: planning grid cell size.
    max_yaw_rate_dps: yaw rate limit (degrees per second).
    look_ahead_m: how far along the path the walker looks.
    head_turn_interval_s: mean time between head turns (toward the wall on the more open side).
    head_turn_deg: (min, max) head-turn amplitude.
    pitch_deg: mean pitch while walking (negative = looking down), :data:`DEFAULT_PITCH_DEG`.
    pitch_amplitude_deg: largest upward glance above ``pitch_deg`` (each glance draws its peak
        uniformly in [0.6, 1] × this); 0 = never look up.
    look_up_interval_s: mean time between glances up (exponential gaps).
    look_up_s: (min, max) duration of a glance (up and back down, a sin² profile).
    sway_pitch_deg, sway_roll_deg: amplitudes of the step-frequency sway.
    step_hz: step frequency at nominal speed.
    """

    speed_mps: float = 1.0
    height_range_m: tuple[float, float] = (1.2, 1.7)
    min_clearance_m: float = 0.42
    door_clearance_m: float = 0.28
    max_step_m: float = 0.2
    preferred_clearance_m: float = 0.9
    grid_m: float = 0.1
    max_yaw_rate_dps: float = 35.0
    look_ahead_m: float = 1.5
    head_turn_interval_s: float = 9.0
    head_turn_deg: tuple[float, float] = (20.0, 45.0)
    pitch_deg: float = DEFAULT_PITCH_DEG
    pitch_amplitude_deg: float = 25.0
    look_up_interval_s: float = 8.0
    look_up_s: tuple[float, float] = (2.5, 4.5)
    sway_pitch_deg: float = 1.0
    sway_roll_deg: float = 1.5
    step_hz: float = 1.8

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> SimConfigError:
            return SimConfigError(f"{why} (got {getattr(self, name)!r})", None, f"walk.{name}")

        if not -60.0 <= self.pitch_deg <= 60.0:
            raise bad("pitch_deg", "must be in [-60, 60] degrees")
        if not 0.0 <= self.pitch_amplitude_deg <= 80.0:
            raise bad("pitch_amplitude_deg", "must be in [0, 80] degrees")
        if not self.look_up_interval_s > 0:
            raise bad("look_up_interval_s", "must be > 0")
        lo, hi = self.look_up_s
        if not 0 < lo <= hi:
            raise bad("look_up_s", "need 0 < min <= max")
        if not self.speed_mps > 0:
            raise bad("speed_mps", "must be > 0")

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass
class FreeSpace:
    """Walkable region and clearance of one storey on a grid.

    Attributes
    ----------
    region: (H, W) bool, cell inside the walkable space (row = y index, column = x index).
    clearance: (H, W) float32 metres to the nearest surface (0 outside the region).
    origin_xy: (2,) world xy of the centre of cell (0, 0).
    resolution: cell size in metres.
    z_floor: storey floor height (world z, metres): the reference height, and the floor
        wherever ``floor_z`` does not say otherwise.
    floor_z: (H, W) float32 local floor height per cell (NaN outside the region), or None for a
        flat floor at ``z_floor``.
    passage: (H, W) bool door cells, where ``WalkConfig.door_clearance_m`` suffices; None = none.
    storey: name of the storey (or level) walked, if known.
    """

    region: NDArray[np.bool_]
    clearance: NDArray[np.float32]
    origin_xy: F64
    resolution: float
    z_floor: float
    floor_z: NDArray[np.float32] | None = None
    passage: NDArray[np.bool_] | None = None
    storey: str | None = None

    def cell_centres(self) -> F64:
        """(H, W, 2) world xy of every cell centre."""
        h, w = self.region.shape
        ys, xs = np.mgrid[0:h, 0:w]
        return np.stack([xs, ys], axis=-1) * self.resolution + self.origin_xy

    def to_cell(self, xy: F64) -> NDArray[np.int64]:
        """(M, 2) integer ``(row, col)`` of world points ``xy`` (M, 2) (not clipped)."""
        cr = np.rint((np.asarray(xy) - self.origin_xy) / self.resolution).astype(np.int64)
        return cr[:, ::-1]

    def clearance_at(self, xy: F64) -> F64:
        """(M,) bilinearly interpolated clearance at world points (M, 2); 0 outside the grid."""
        from scipy.ndimage import map_coordinates

        rc = ((np.asarray(xy) - self.origin_xy) / self.resolution)[:, ::-1]
        return map_coordinates(self.clearance, rc.T, order=1, mode="constant", cval=0.0)

    def floor_at(self, xy: F64) -> F64:
        """(M,) local floor height (metres) at world points (M, 2): the nearest cell's, and
        ``z_floor`` outside the grid or the region."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        out = np.full(len(xy), self.z_floor, np.float64)
        if self.floor_z is None:
            return out
        rc = self.to_cell(xy)
        h, w = self.region.shape
        ok = (rc[:, 0] >= 0) & (rc[:, 0] < h) & (rc[:, 1] >= 0) & (rc[:, 1] < w)
        z = self.floor_z[rc[ok, 0], rc[ok, 1]].astype(np.float64)
        out[np.flatnonzero(ok)[np.isfinite(z)]] = z[np.isfinite(z)]
        return out

    def required_clearance(self, config: WalkConfig) -> NDArray[np.float32]:
        """(H, W) clearance a cell needs to be walkable: ``min_clearance_m``, and
        ``door_clearance_m`` in door passages."""
        req = np.full(self.region.shape, config.min_clearance_m, np.float32)
        if self.passage is not None:
            req[self.passage] = min(config.door_clearance_m, config.min_clearance_m)
        return req

    def walkable(self, config: WalkConfig) -> NDArray[np.bool_]:
        """(H, W) cells inside the region with the clearance they need."""
        return self.region & (self.clearance >= self.required_clearance(config))

    def components(self, config: WalkConfig) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Connected pieces of the walkable cells (8-neighbours whose floors differ by at most
        ``max_step_m``): (H, W) piece index per cell (-1 = not walkable) and (K,) cell counts."""
        from scipy.sparse.csgraph import connected_components

        walkable = self.walkable(config)
        graph, node = _grid_graph(walkable, self.clearance, self.resolution,
                                  config.preferred_clearance_m, self.floor_z, config.max_step_m)
        comp = np.full(walkable.shape, -1, np.int64)
        if graph.shape[0] == 0:
            return comp, np.zeros(0, np.int64)
        _, labels = connected_components(graph, directed=False)
        comp[node >= 0] = labels[node[node >= 0]]
        return comp, np.bincount(labels)

    @classmethod
    def from_polygons(
        cls,
        world: World,
        polygons: Sequence[F64],
        z_floor: float,
        doors_xy: F64 | None = None,
        door_radius_m: float = 0.6,
        resolution: float = 0.1,
        heights_m: Sequence[float] = (0.5, 1.0, 1.3, 1.6),
    ) -> FreeSpace:
        """Region from free-space polygons (each (K, 2) world xy) plus discs at door centres."""
        import cv2

        if not polygons:
            raise SimError("no free-space polygons given")
        pts = np.concatenate([np.asarray(p, np.float64).reshape(-1, 2) for p in polygons])
        lo = pts.min(axis=0) - 1.0
        hi = pts.max(axis=0) + 1.0
        shape = tuple(np.ceil((hi - lo) / resolution).astype(int)[::-1] + 1)
        region = np.zeros(shape, np.uint8)
        for poly in polygons:
            px = (np.asarray(poly, np.float64).reshape(-1, 2) - lo) / resolution
            # fixed-point polygon fill (4 fractional bits) so edges land on cell centres exactly
            cv2.fillPoly(region, [np.rint(px * 16).astype(np.int32)], 1, shift=4)
        if doors_xy is not None and len(doors_xy):
            r = max(1, int(round(door_radius_m / resolution)))  # noqa: RUF046 (numpy < 2)
            for d in np.asarray(doors_xy, np.float64).reshape(-1, 2):
                c = np.rint((d - lo) / resolution).astype(int)
                cv2.circle(region, (int(c[0]), int(c[1])), r, 1, -1)
        return cls._with_clearance(world, region.astype(bool), lo, resolution, z_floor, heights_m)

    @classmethod
    def _with_clearance(
        cls,
        world: World,
        region: NDArray[np.bool_],
        origin_xy: F64,
        resolution: float,
        z_floor: float,
        heights_m: Sequence[float],
        floor_z: NDArray[np.float32] | None = None,
        passage: NDArray[np.bool_] | None = None,
    ) -> FreeSpace:
        """Clearance of the ``region`` cells at ``heights_m`` above the floor (``floor_z`` per
        cell, or ``z_floor``), capped by the distance to the region's border."""
        from scipy.ndimage import distance_transform_edt

        h, w = region.shape
        rows, cols = np.nonzero(region)
        xy = np.stack([cols, rows], axis=-1) * resolution + origin_xy
        base = (np.full(len(xy), z_floor) if floor_z is None
                else floor_z[rows, cols].astype(np.float64))
        clearance = np.zeros((h, w), np.float32)
        if len(xy):
            q = np.concatenate([np.tile(xy, (len(heights_m), 1)),
                                np.concatenate([base + hz for hz in heights_m])[:, None]], axis=1)
            dist = world.distance(q).reshape(len(heights_m), -1).min(axis=0)
            border = distance_transform_edt(np.pad(region, 1)).astype(np.float32)[1:-1, 1:-1]
            clearance[rows, cols] = np.minimum(dist, (border[rows, cols] - 0.5) * resolution)
        return cls(region, clearance, np.asarray(origin_xy, np.float64), resolution, z_floor,
                   floor_z, passage)


def detect_floor_height(world: World, min_share: float = 0.2) -> float:
    """The lowest floor height carrying at least ``min_share`` of the largest floor's area.

    Floor triangles (label FLOOR, facing up) are binned by height in 5 cm bins weighted by area.
    """
    tri = world.world_vertices()[world.faces]
    up = world.tri_label == Label.FLOOR
    if not up.any():
        raise SimError("the world has no floor triangles: pass z_floor explicitly")
    n = np.cross(tri[up, 1] - tri[up, 0], tri[up, 2] - tri[up, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    facing = n[:, 2] > 0.9 * np.linalg.norm(n, axis=1)
    z = tri[up][:, :, 2].mean(axis=1)
    z, area = z[facing], area[facing]
    if len(z) == 0:
        raise SimError("no upward-facing floor triangles: pass z_floor explicitly")
    bins = np.round(z / 0.05).astype(np.int64)
    uniq, inv = np.unique(bins, return_inverse=True)
    weight = np.bincount(inv, weights=area)
    ok = weight >= min_share * weight.max()
    return float(uniq[ok].min() * 0.05)


@dataclass
class Walk:
    """A dense (100 Hz) handheld trajectory; sample frame poses with :meth:`poses`.

    Attributes
    ----------
    t: (T,) seconds from the start.
    xyz: (T, 3) camera centre in the world (metres).
    yaw, pitch, roll: (T,) radians (see the module docstring for the convention).
    path_xy: (P, 2) the smoothed planned path (for clutter placement and pictures).
    """

    t: F64
    xyz: F64
    yaw: F64
    pitch: F64
    roll: F64
    path_xy: F64

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def poses(self, times: F64) -> F64:
        """(N, 7) ``world_from_cam`` TUM-order poses at ``times`` (N,) seconds (interpolated)."""
        times = np.asarray(times, np.float64)
        if times.min() < self.t[0] - 1e-9 or times.max() > self.t[-1] + 1e-9:
            raise SimError(f"times outside the walk [0, {self.duration:.2f}] s")
        xyz = np.stack([np.interp(times, self.t, self.xyz[:, k]) for k in range(3)], axis=1)
        yaw = np.interp(times, self.t, self.yaw)
        pitch = np.interp(times, self.t, self.pitch)
        roll = np.interp(times, self.t, self.roll)
        rot = camera_rotation(yaw, pitch, roll)
        out = np.empty((len(times), 7))
        out[:, :3] = xyz
        out[:, 3:] = rotmat_to_quat(rot)
        return out


def camera_rotation(yaw: F64, pitch: F64, roll: F64) -> F64:
    """(N, 3, 3) ``world_from_cam`` rotations from yaw, pitch, roll (N,) radians (see module)."""
    yaw, pitch, roll = (np.atleast_1d(np.asarray(a, np.float64)) for a in (yaw, pitch, roll))
    cy, sy = np.cos(yaw), np.sin(yaw)
    zero, one = np.zeros_like(yaw), np.ones_like(yaw)
    level = np.stack(
        [
            np.stack([sy, zero, cy], axis=-1),
            np.stack([-cy, zero, sy], axis=-1),
            np.stack([zero, -one, zero], axis=-1),
        ],
        axis=-2,
    )  # rows = world x, y, z; columns = cam right, down, forward
    cp, sp = np.cos(pitch), np.sin(pitch)
    rx = np.zeros((len(pitch), 3, 3))
    rx[:, 0, 0] = 1.0
    rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2] = cp, -sp, sp, cp
    cr, sr = np.cos(roll), np.sin(roll)
    rz = np.zeros((len(roll), 3, 3))
    rz[:, 2, 2] = 1.0
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1] = cr, -sr, sr, cr
    return level @ rx @ rz


def _grid_graph(walkable: NDArray[np.bool_], clearance: NDArray[np.float32], res: float,
                preferred: float, floor_z: NDArray[np.float32] | None = None,
                max_step: float = np.inf) -> tuple[Any, NDArray[np.int64]]:
    """8-connected graph over walkable cells whose floors (``floor_z``, if given) differ by at
    most ``max_step``: (CSR matrix, node id per cell, -1 = none)."""
    from scipy.sparse import coo_matrix

    h, w = walkable.shape
    node = np.full((h, w), -1, np.int64)
    rr, cc = np.nonzero(walkable)
    node[rr, cc] = np.arange(len(rr))
    penalty = 1.0 + 4.0 * np.clip((preferred - clearance) / preferred, 0.0, 1.0)
    src_l, dst_l, wt_l = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = rr + dr, cc + dc
        ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        ok[ok] &= walkable[r2[ok], c2[ok]]
        if floor_z is not None:
            ok[ok] &= np.abs(floor_z[rr[ok], cc[ok]] - floor_z[r2[ok], c2[ok]]) <= max_step
        a = node[rr[ok], cc[ok]]
        b = node[r2[ok], c2[ok]]
        step = res * np.hypot(dr, dc)
        cost = step * 0.5 * (penalty[rr[ok], cc[ok]] + penalty[r2[ok], c2[ok]])
        src_l += [a, b]
        dst_l += [b, a]
        wt_l += [cost, cost]
    n = len(rr)
    if n == 0:
        return coo_matrix((0, 0)).tocsr(), node
    graph = coo_matrix(
        (np.concatenate(wt_l), (np.concatenate(src_l), np.concatenate(dst_l))), shape=(n, n)
    ).tocsr()
    return graph, node


def _smooth_signal(rng: np.random.Generator, t: F64, amplitude: float, fmin: float,
                   fmax: float, n: int = 3) -> F64:
    """A smooth random signal: a sum of ``n`` sinusoids with random frequencies and phases."""
    out = np.zeros_like(t)
    for _ in range(n):
        f = rng.uniform(fmin, fmax)
        out += np.sin(2.0 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return amplitude * out / np.sqrt(n / 2.0)


@dataclass
class _WalkGraph:
    """The walkable grid of the largest connected piece: its graph and cells."""

    graph: Any  # CSR matrix over the walkable cells
    node: NDArray[np.int64]  # (H, W) node id per cell, -1 = none
    rr: NDArray[np.int64]  # (n,) row of each node
    cc: NDArray[np.int64]  # (n,) column of each node

    def xy(self, nodes: Any, res: float) -> F64:
        """(k, 2) grid xy (metres, without the grid origin) of node ids ``nodes``."""
        return np.stack([self.cc[nodes], self.rr[nodes]], axis=-1) * res


@dataclass
class _Timeline:
    """The walk's 100 Hz time base and the walker's position along the path."""

    dt: float  # seconds
    t: F64  # (T,) seconds
    s_t: F64  # (T,) arc length along the path, metres
    xy: F64  # (T, 2) world xy, metres


def plan_walk(
    free: FreeSpace, duration_s: float, rng: np.random.Generator, config: WalkConfig | None = None
) -> Walk:
    """Plan a handheld walk of ``duration_s`` seconds through ``free`` (module docstring)."""
    cfg = config or WalkConfig()
    grid = _walk_graph(free, cfg)
    waypoints = _spread_waypoints(free, grid, rng)
    nodes_path = _tour(grid, waypoints, duration_s * cfg.speed_mps * 1.4 + 5.0, free.resolution,
                       rng)
    raw = grid.xy(nodes_path, free.resolution) + free.origin_xy
    path, s_path = _smooth_path(free, cfg, raw)
    heading = np.unwrap(np.arctan2(np.gradient(path[:, 1]), np.gradient(path[:, 0])))
    tl = _walk_along(path, s_path, heading, duration_s, cfg, rng)
    yaw = _yaw(free, tl, path, s_path, heading, duration_s, cfg, rng)
    pitch, roll, height = _sway(tl, cfg, rng)
    # glances up (drawn last, so that the path, yaw and the rest of the motion do not depend on
    # whether the walker looks up)
    if cfg.pitch_amplitude_deg > 0 and cfg.look_up_interval_s > 0:
        pitch = pitch + np.deg2rad(_glances_up(tl, duration_s, cfg, rng))
    xyz = _camera_centres(free, tl, height, cfg)
    return Walk(tl.t, xyz, yaw, pitch, roll, path)


def _walk_graph(free: FreeSpace, cfg: WalkConfig) -> _WalkGraph:
    """The grid graph of the largest walkable piece of ``free``; raises if there is none."""
    comp, sizes = free.components(cfg)
    if len(sizes) == 0:
        where = f" on storey {free.storey!r}" if free.storey else ""
        raise SimError(
            f"no cell{where} has {cfg.min_clearance_m} m clearance: the free space is too narrow "
            "to walk"
        )
    walkable = comp == int(np.argmax(sizes))
    graph, node = _grid_graph(walkable, free.clearance, free.resolution,
                              cfg.preferred_clearance_m, free.floor_z, cfg.max_step_m)
    rr, cc = np.nonzero(walkable)
    return _WalkGraph(graph, node, rr, cc)


def _spread_waypoints(free: FreeSpace, grid: _WalkGraph, rng: np.random.Generator
                      ) -> NDArray[np.int64]:
    """(k,) way-point node ids: farthest-point sampling over the well-clear cells (one draw)."""
    res = free.resolution
    rr, cc = grid.rr, grid.cc
    clear = free.clearance[rr, cc]
    good = np.flatnonzero(clear >= min(0.75, 0.9 * float(clear.max())))
    cand_xy = np.stack([cc[good], rr[good]], axis=-1) * res
    area = len(rr) * res * res
    k = int(np.clip(np.ceil(area / 10.0), 4, 60))
    k = min(k, len(good))
    first = int(rng.integers(len(good)))
    chosen = [first]
    d = np.linalg.norm(cand_xy - cand_xy[first], axis=1)
    for _ in range(k - 1):
        nxt = int(np.argmax(d))
        if d[nxt] < 0.5:
            break
        chosen.append(nxt)
        d = np.minimum(d, np.linalg.norm(cand_xy - cand_xy[nxt], axis=1))
    return grid.node[rr[good[chosen]], cc[good[chosen]]]


def _tour(grid: _WalkGraph, waypoints: NDArray[np.int64], need_m: float, res: float,
          rng: np.random.Generator) -> list[int]:
    """Node ids of a geodesic tour from way-point to a near unvisited one, ``need_m`` long."""
    from scipy.sparse.csgraph import dijkstra

    current = int(waypoints[0])
    unvisited = {int(w) for w in waypoints[1:]}
    nodes_path = [current]
    length = 0.0
    guard = 0
    while length < need_m:
        guard += 1
        if guard > 10 * len(waypoints) + 20:
            raise SimError("walk planning did not reach the requested length")
        if not unvisited:
            unvisited = {int(w) for w in waypoints} - {current}
            if not unvisited:
                raise SimError("the walkable space has a single way-point: too small to walk")
        dist, pred = dijkstra(grid.graph, indices=current, return_predecessors=True)
        cands = sorted((float(dist[w]), w) for w in unvisited if np.isfinite(dist[w]))
        if not cands:
            raise SimError("way-points are unreachable from each other")
        pick = cands[int(rng.integers(min(2, len(cands))))][1]
        seg = [pick]
        while seg[-1] != current:
            seg.append(int(pred[seg[-1]]))
        seg = seg[::-1]
        length += float(np.linalg.norm(np.diff(grid.xy(seg, res), axis=0), axis=1).sum())
        nodes_path += seg[1:]
        unvisited.discard(pick)
        current = pick
    return nodes_path


def _smooth_path(free: FreeSpace, cfg: WalkConfig, raw: F64) -> tuple[F64, F64]:
    """Resample the raw path (P, 2) at 5 cm, smooth it, pull it back where the smoothing cuts
    into the clearance margin; returns the path (Q, 2) and its arc length (Q,) in metres."""
    from scipy.ndimage import gaussian_filter1d

    seg_len = np.linalg.norm(np.diff(raw, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg_len)])
    s_new = np.arange(0.0, s[-1], 0.05)
    raw_rs = np.stack([np.interp(s_new, s, raw[:, 0]), np.interp(s_new, s, raw[:, 1])], axis=1)
    path = gaussian_filter1d(raw_rs, sigma=10.0, axis=0, mode="nearest")
    required = free.required_clearance(cfg)
    for _ in range(12):
        need = required[tuple(np.clip(free.to_cell(path), 0, np.array(required.shape) - 1).T)]
        bad = free.clearance_at(path) < need + 0.03
        if not bad.any():
            break
        bad = np.convolve(bad.astype(float), np.ones(9), mode="same") > 0
        path[bad] = 0.5 * (path[bad] + raw_rs[bad])
    seg_len = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s_path = np.concatenate([[0.0], np.cumsum(seg_len)])
    return path, s_path


def _walk_along(path: F64, s_path: F64, heading: F64, duration_s: float, cfg: WalkConfig,
                rng: np.random.Generator) -> _Timeline:
    """Walk the path (Q, 2) at a curvature-limited, slowly varying speed (draws its variation)."""
    from scipy.ndimage import gaussian_filter1d

    curv = np.abs(np.gradient(gaussian_filter1d(heading, 4.0))) / 0.05  # rad per metre
    dt = 0.01
    n_t = int(np.ceil(duration_s / dt)) + 1
    t = np.arange(n_t) * dt
    speed_mod = 1.0 + _smooth_signal(rng, t, 0.06, 0.03, 0.15)
    s_t = np.zeros(n_t)
    for i in range(1, n_t):
        kappa = np.interp(s_t[i - 1], s_path, curv)
        v = cfg.speed_mps * speed_mod[i] / (1.0 + 0.8 * kappa)
        s_t[i] = s_t[i - 1] + max(v, 0.3 * cfg.speed_mps) * dt
    if s_t[-1] > s_path[-1]:
        raise SimError("planned path shorter than the walk")
    xy = np.stack([np.interp(s_t, s_path, path[:, 0]), np.interp(s_t, s_path, path[:, 1])], axis=1)
    return _Timeline(dt=dt, t=t, s_t=s_t, xy=xy)


def _yaw(free: FreeSpace, tl: _Timeline, path: F64, s_path: F64, heading: F64,
         duration_s: float, cfg: WalkConfig, rng: np.random.Generator) -> F64:
    """(T,) yaw, radians: look ahead along the path, add head turns toward the nearer wall
    (drawn here), limit the rate."""
    from scipy.ndimage import gaussian_filter1d

    s_t, xy = tl.s_t, tl.xy
    ahead = np.stack(
        [np.interp(s_t + cfg.look_ahead_m, s_path, path[:, 0]),
         np.interp(s_t + cfg.look_ahead_m, s_path, path[:, 1])], axis=1,
    )
    d_ahead = ahead - xy
    near_end = np.linalg.norm(d_ahead, axis=1) < 0.2
    yaw_path = np.arctan2(d_ahead[:, 1], d_ahead[:, 0])
    if near_end.any():
        yaw_path[near_end] = np.interp(s_t[near_end], s_path, heading)
    yaw_path = np.unwrap(yaw_path)
    turns = _head_turns(free, tl, yaw_path, duration_s, cfg, rng)
    target = gaussian_filter1d(yaw_path + turns, sigma=0.3 / tl.dt, mode="nearest")
    max_step = np.deg2rad(cfg.max_yaw_rate_dps) * tl.dt
    yaw = np.empty(len(tl.t))
    yaw[0] = target[0]
    for i in range(1, len(tl.t)):
        yaw[i] = yaw[i - 1] + np.clip(target[i] - yaw[i - 1], -max_step, max_step)
    return yaw


def _head_turns(free: FreeSpace, tl: _Timeline, yaw_path: F64, duration_s: float,
                cfg: WalkConfig, rng: np.random.Generator) -> F64:
    """(T,) head-turn yaw offsets, radians, at exponential gaps (drawn here)."""
    t, dt, xy = tl.t, tl.dt, tl.xy
    turns = np.zeros(len(t))
    t_next = rng.exponential(cfg.head_turn_interval_s)
    while t_next < duration_s:
        length_s = rng.uniform(2.0, 4.0)
        amp = np.deg2rad(rng.uniform(*cfg.head_turn_deg))
        # toward the wall on the more open side (probed 1.5 m left and right): looking at the
        # nearer wall from 0.5 m fills the image with a featureless close-up
        i = int(t_next / dt)
        side_dir = 1.5 * np.array([-np.sin(yaw_path[i]), np.cos(yaw_path[i])])
        cl = free.clearance_at(np.stack([xy[i] + side_dir, xy[i] - side_dir]))
        sign = 1.0 if cl[0] >= cl[1] else -1.0
        tau = (t - t_next) / length_s
        inside = (tau >= 0.0) & (tau <= 1.0)
        turns[inside] += sign * amp * np.sin(np.pi * tau[inside]) ** 2
        t_next += length_s + rng.exponential(cfg.head_turn_interval_s)
    return turns


def _sway(tl: _Timeline, cfg: WalkConfig, rng: np.random.Generator) -> tuple[F64, F64, F64]:
    """Step sway, bob and slow drifts: (T,) pitch and roll (radians) and camera height above
    the floor (metres), drawn in that order."""
    t = tl.t
    phase = 2.0 * np.pi * np.cumsum(cfg.step_hz * np.ones(len(t)) * tl.dt)
    pitch = np.deg2rad(
        cfg.pitch_deg + cfg.sway_pitch_deg * np.sin(phase) + _smooth_signal(rng, t, 2.0, 0.02, 0.2)
    )
    roll = np.deg2rad(
        cfg.sway_roll_deg * np.sin(0.5 * phase + 0.3) + _smooth_signal(rng, t, 1.0, 0.02, 0.2)
    )
    h_lo, h_hi = cfg.height_range_m
    h_mid = rng.uniform(h_lo + 0.15, h_hi - 0.15)
    height = h_mid + _smooth_signal(rng, t, 0.05, 0.01, 0.1) + 0.015 * np.sin(phase)
    height = np.clip(height, h_lo + 0.01, h_hi - 0.01)
    return pitch, roll, height


def _glances_up(tl: _Timeline, duration_s: float, cfg: WalkConfig, rng: np.random.Generator
                ) -> F64:
    """(T,) upward glances, degrees: sin² bumps at exponential gaps (drawn here)."""
    t = tl.t
    look = np.zeros(len(t))
    t_next = rng.exponential(cfg.look_up_interval_s)
    while t_next < duration_s:
        length_s = rng.uniform(*cfg.look_up_s)
        amp = rng.uniform(0.6, 1.0) * cfg.pitch_amplitude_deg
        tau = (t - t_next) / length_s
        inside = (tau >= 0.0) & (tau <= 1.0)
        look[inside] += amp * np.sin(np.pi * tau[inside]) ** 2
        t_next += length_s + rng.exponential(cfg.look_up_interval_s)
    return look


def _camera_centres(free: FreeSpace, tl: _Timeline, height: F64, cfg: WalkConfig) -> F64:
    """(T, 3) camera centres: ``height`` above the local floor, smoothed over ~0.3 m of path
    (a step is climbed, not jumped)."""
    from scipy.ndimage import gaussian_filter1d

    floor = gaussian_filter1d(free.floor_at(tl.xy), sigma=0.3 / max(cfg.speed_mps, 0.1) / tl.dt,
                              mode="nearest")
    return np.concatenate([tl.xy, (floor + height)[:, None]], axis=1)
