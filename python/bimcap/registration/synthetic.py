"""Synthetic semantic samples for tests and benchmarks of the coarse stage (no renderer needed).

A scene is a floor plan (2-D segments with a class) extruded from ``floor_z`` to ``ceiling_z``
plus the floor and ceiling planes. A camera (OpenCV optical frame) casts a grid of rays; each
ray stops at the first wall/column face, floor or ceiling, and the hit becomes a labelled point
in the camera frame with noise along the ray. Clutter is simulated by moving a fraction of the
wall hits forward along their ray (an object in front of the wall mislabelled as wall); walls
missing from the as-built world are simply left out of the scene that is ray-cast while the BIM
keeps them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bimcap.geometry.poses import compose, invert, pose_to_matrix
from bimcap.labels import Label
from bimcap.registration.coarse import FloorPlan, SemanticSamples

F64 = NDArray[np.float64]

#: World-from-camera rotation of a level camera looking along world +x (optical z → +x,
#: x right → -y, y down → -z).
_R_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class Scene:
    """An extruded floor plan: ``segments (S, 4)``, ``segment_class (S,)``, floor/ceiling z."""

    segments: F64
    segment_class: NDArray[np.int32]
    floor_z: float = 0.0
    ceiling_z: float = 2.8

    def floor_plan(self) -> FloorPlan:
        """The BIM view of this scene (all segments, one floor and one ceiling)."""
        return FloorPlan(self.segments, self.segment_class, None, np.array([self.floor_z]),
                         np.array([self.ceiling_z]))

    def without(self, box_xy: tuple[float, float, float, float]) -> Scene:
        """The scene with every segment whose midpoint lies in ``box_xy`` removed (a wall
        missing from the as-built world)."""
        mid = 0.5 * (self.segments[:, :2] + self.segments[:, 2:])
        x0, y0, x1, y1 = box_xy
        drop = (mid[:, 0] > x0) & (mid[:, 0] < x1) & (mid[:, 1] > y0) & (mid[:, 1] < y1)
        return Scene(self.segments[~drop], self.segment_class[~drop], self.floor_z,
                     self.ceiling_z)


def demo_scene(seed: int = 0) -> Scene:
    """The demo building's ground storey (``bimcap.sim``), cut 1 m above the floor."""
    from bimcap.sim.building import BuildingSpec, generate_building

    truth = generate_building(BuildingSpec.demo(), seed=seed).truth
    st = truth.storeys[0]
    outline = truth.plan_outline(0, st.floor_z + 1.0)
    return Scene(outline.segments, outline.segment_class.astype(np.int32), st.floor_z,
                 st.ceiling_z)


def demo_tour(seed: int = 0) -> F64:
    """(T, 2) the demo building's walk-graph tour (closed polyline), metres."""
    from bimcap.sim.building import BuildingSpec, generate_building

    return generate_building(BuildingSpec.demo(), seed=seed).truth.free_space[0].tour_xy()


def rectangle(x0: float, y0: float, x1: float, y1: float) -> F64:
    """(4, 4) the outline segments of an axis-aligned rectangle."""
    return np.array([[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]])


def solids(rects: list[tuple[float, float, float, float]], segment_class: int = int(Label.WALL)
           ) -> Scene:
    """A scene of solid rectangles ``(x0, y0, x1, y1)`` (walls as thick solids, as a BIM plan
    section gives them); the rectangles must not overlap (butt joints are fine) so that every
    outline stays a closed curve with a well-defined inside."""
    seg = np.concatenate([rectangle(*r) for r in rects]) if rects else np.zeros((0, 4))
    return Scene(seg, np.full(len(seg), segment_class, np.int32))


def merge(*scenes: Scene) -> Scene:
    """One scene with the segments of all (floor/ceiling of the first)."""
    return Scene(np.concatenate([s.segments for s in scenes]),
                 np.concatenate([s.segment_class for s in scenes]), scenes[0].floor_z,
                 scenes[0].ceiling_z)


def symmetric_scene(room_column_xy: tuple[float, float] = (2.2, 1.8)) -> Scene:
    """A room ``[0.2, 8.2] × [-3, 3]`` with a 1.2 m door in its west and east walls, each
    opening onto a 10 m corridor 2.4 m wide closed at its far end: the walls are symmetric
    under a 180° turn about (4.2, 0). A column in the west corridor at (-6, 0.8) breaks the
    symmetry there; a second column stands in the room at ``room_column_xy`` (put it at the
    mirror image in the as-built world to make the room's own data favour the flipped pose).
    Walls 0.2 m thick, as solids."""
    t = 0.2
    walls = [
        (-10.0, -1.2 - t, 0.0, -1.2), (-10.0, 1.2, 0.0, 1.2 + t),
        (-10.0 - t, -1.2 - t, -10.0, 1.2 + t),
        (0.0, -3.0 - t, t, -0.6), (0.0, 0.6, t, 3.0 + t),
        (8.2, -3.0 - t, 8.2 + t, -0.6), (8.2, 0.6, 8.2 + t, 3.0 + t),
        (t, -3.0 - t, 8.2, -3.0), (t, 3.0, 8.2, 3.0 + t),
        (8.4, -1.2 - t, 18.4, -1.2), (8.4, 1.2, 18.4, 1.2 + t), (18.4, -1.2 - t, 18.4 + t, 1.2 + t),
    ]
    cx, cy = room_column_xy
    columns = [(-6.15, 0.65, -5.85, 0.95), (cx - 0.15, cy - 0.15, cx + 0.15, cy + 0.15)]
    return merge(solids(walls), solids(columns, int(Label.COLUMN)))


def level_pose(x: float, y: float, yaw: float, height: float = 1.5) -> F64:
    """(7,) ``world_from_cam`` of a level camera at ``(x, y, height)`` looking along ``yaw``."""
    rot = Rotation.from_euler("z", yaw) * Rotation.from_matrix(_R_LEVEL)
    return np.r_[x, y, height, rot.as_quat()]


def poses_along(path_xy: NDArray[np.float64], step_m: float, height: float = 1.5,
                yaw_offset: float = 0.0) -> F64:
    """(N, 7) level cameras every ``step_m`` along a polyline, looking along the motion."""
    path = np.asarray(path_xy, dtype=np.float64)
    seg = np.diff(path, axis=0)
    keep = np.linalg.norm(seg, axis=1) > 1e-9
    path = np.vstack([path[:1], path[1:][keep]])
    seg = np.diff(path, axis=0)
    length = np.r_[0.0, np.cumsum(np.linalg.norm(seg, axis=1))]
    s = np.arange(0.0, length[-1], step_m)
    k = np.clip(np.searchsorted(length, s, side="right") - 1, 0, len(seg) - 1)
    xy = path[k] + (s - length[k])[:, None] * seg[k] / np.linalg.norm(seg[k], axis=1)[:, None]
    yaw = np.arctan2(seg[k, 1], seg[k, 0]) + yaw_offset
    return np.array([level_pose(p[0], p[1], a, height) for p, a in zip(xy, yaw, strict=True)])


def displace(world_from_cam: NDArray[np.float64], yaw: float, t_xyz: NDArray[np.float64],
             pivot_xyz: NDArray[np.float64], tilt_xy: tuple[float, float] = (0.0, 0.0)) -> F64:
    """Apply one rigid world-from-world error ``p ↦ R (p - pivot) + pivot + t`` to poses.

    ``R = Rz(yaw) · Rx(tilt_x) · Ry(tilt_y)``; angles in radians.
    """
    rot = Rotation.from_euler("z", yaw) * Rotation.from_euler("xy", tilt_xy)
    pivot = np.asarray(pivot_xyz, dtype=np.float64)
    err = np.r_[pivot + np.asarray(t_xyz, dtype=np.float64) - rot.apply(pivot), rot.as_quat()]
    return compose(err, np.asarray(world_from_cam, dtype=np.float64))


def scan(
    world_from_cam: NDArray[np.float64],
    scene: Scene,
    rng: np.random.Generator,
    hfov_deg: float = 90.0,
    vfov_deg: float = 70.0,
    n_az: int = 90,
    n_el: int = 50,
    max_range_m: float = 10.0,
    noise_m: float = 0.03,
    clutter_fraction: float = 0.0,
) -> dict[int, F64]:
    """Labelled points of one camera: ``{Label: (M, 3) p_in_cam}`` for WALL, COLUMN, FLOOR,
    CEILING (metres, OpenCV frame)."""
    ax = np.tan(np.deg2rad(hfov_deg) / 2) * np.linspace(-1, 1, n_az)
    ay = np.tan(np.deg2rad(vfov_deg) / 2) * np.linspace(-1, 1, n_el)
    gx, gy = np.meshgrid(ax, ay)
    d_cam = np.c_[gx.ravel(), gy.ravel(), np.ones(gx.size)]
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    m = pose_to_matrix(world_from_cam)
    d = d_cam @ m[:3, :3].T
    o = m[:3, 3]
    s_best = np.full(len(d), np.inf)
    label = np.zeros(len(d), dtype=np.int32)
    # Walls/columns: 2-D ray-segment intersection; the ray parameter is shared with 3-D.
    a, b = scene.segments[:, :2], scene.segments[:, 2:]
    e = b - a
    dx, dy = d[:, 0:1], d[:, 1:2]
    den = dx * e[None, :, 1] - dy * e[None, :, 0]
    wx, wy = a[None, :, 0] - o[0], a[None, :, 1] - o[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (wx * e[None, :, 1] - wy * e[None, :, 0]) / den
        u = (wx * dy - wy * dx) / den
    ok = (np.abs(den) > 1e-12) & (s > 1e-6) & (u >= 0) & (u <= 1)
    s = np.where(ok, s, np.inf)
    j = s.argmin(1)
    s_seg = s[np.arange(len(d)), j]
    hit = np.isfinite(s_seg)
    s_best[hit] = s_seg[hit]
    label[hit] = scene.segment_class[j[hit]]
    with np.errstate(divide="ignore", invalid="ignore"):
        s_floor = np.where(d[:, 2] < -1e-9, (scene.floor_z - o[2]) / d[:, 2], np.inf)
        s_ceil = np.where(d[:, 2] > 1e-9, (scene.ceiling_z - o[2]) / d[:, 2], np.inf)
    f = s_floor < s_best
    s_best[f], label[f] = s_floor[f], Label.FLOOR
    c = s_ceil < s_best
    s_best[c], label[c] = s_ceil[c], Label.CEILING
    keep = s_best < max_range_m
    s_best = s_best + rng.normal(0.0, noise_m, len(s_best))
    if clutter_fraction > 0:
        wall = np.flatnonzero(keep & (label == Label.WALL))
        pick = rng.choice(wall, round(clutter_fraction * len(wall)), replace=False)
        s_best[pick] *= rng.uniform(0.3, 0.95, len(pick))
    p_in_cam = d_cam * s_best[:, None]
    return {int(k): p_in_cam[keep & (label == k)]
            for k in (Label.WALL, Label.COLUMN, Label.FLOOR, Label.CEILING)}


def scan_sequence(world_from_cam: NDArray[np.float64], scene: Scene, seed: int,
                  **scan_kwargs: float | int) -> SemanticSamples:
    """:func:`scan` every pose and pack the points as :class:`SemanticSamples`."""
    rng = np.random.default_rng(seed)
    per = [scan(p, scene, rng, **scan_kwargs) for p in np.asarray(world_from_cam)]
    arrays: dict[str, NDArray[np.float64] | NDArray[np.int32]] = {}
    for name, lab in (("wall", Label.WALL), ("column", Label.COLUMN), ("floor", Label.FLOOR),
                      ("ceiling", Label.CEILING)):
        arrays[f"{name}_frame"] = np.concatenate(
            [np.full(len(p[int(lab)]), i, np.int32) for i, p in enumerate(per)])
        arrays[f"{name}_p_in_cam"] = np.concatenate([p[int(lab)] for p in per]).reshape(-1, 3)
    return SemanticSamples.from_arrays(**arrays)


def pose_errors(estimate: NDArray[np.float64], truth: NDArray[np.float64]) -> tuple[F64, F64]:
    """Per-frame (translation error m, rotation error deg) between two (N, 7) trajectories."""
    rel = compose(invert(np.asarray(truth)), np.asarray(estimate))
    t_err = np.linalg.norm(np.asarray(estimate)[:, :3] - np.asarray(truth)[:, :3], axis=1)
    r_err = np.rad2deg(Rotation.from_quat(rel[:, 3:7]).magnitude())
    return t_err, r_err


__all__ = ["Scene", "demo_scene", "demo_tour", "displace", "level_pose", "merge", "pose_errors",
           "poses_along", "rectangle", "scan", "scan_sequence", "solids", "symmetric_scene"]
