"""A wall of the design BIM that the scan saw through: missing as built.

:func:`bimcap.registration.global_align` refuses a placement whose cameras see through plan walls
(more than ``max_see_through`` of the wall/column points: negative evidence against aliases).
A building that deviates from its design can lack a whole wall: the as-built sequence then sees
the rooms behind it, and at the *right* placement a quarter of the points cross that one wall
(the demo building with partition ``part-south-1`` missing, pipeline seed 3: 28 % seen through,
0.2 % without the wall's two faces). That is one wall, not the scattered crossings of a wrong
placement: :func:`align_without_missing_wall` finds the wall that the refused best placement's
rays cross most (:func:`dominant_seen_through_wall`), and when it alone explains the
see-through, runs the global alignment again on the plan without it. Every other test of the
alignment stands (fit, free space, see-through of the rest of the plan, ambiguity), and the
new best must be the refused one: a wall's removal may explain a refusal, never move the
placement elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.poses import transform_points
from bimcap.registration.coarse import FloorPlan, SemanticSamples
from bimcap.registration.errors import GlobalAlignmentError
from bimcap.registration.global_align import (
    _IDENTITY,
    GlobalAlignOptions,
    GlobalAlignResult,
    _cached_storey_maps,
    _frame_fit,
    _keep,
    _scan,
    _see_through_rays,
    _storeys,
    global_align,
    see_through_counts,
    see_through_fraction,
)

F64 = NDArray[np.float64]

#: The faces of one wall: plan segments parallel to the most-crossed one (within 5°) and at
#: most this far from it (metres; walls are 0.1-0.4 m thick).
MAX_WALL_THICKNESS_M = 0.6
#: ... and its pieces on the far side of a door: collinear segments within this gap (metres).
MAX_DOOR_GAP_M = 1.5
#: The wall must be crossed by at least this share of the seen-through points.
MIN_WALL_SHARE = 0.6
#: Seen-through points counted per segment to find the most-crossed one (every k-th of them).
MAX_COUNTED = 400
#: The placement found again without the wall must be the refused one: mean camera distance
#: (metres) and yaw difference (degrees) at most these.
SAME_PLACEMENT_M, SAME_PLACEMENT_DEG = 0.5, 5.0


@dataclass(frozen=True)
class SeenThroughWall:
    """The plan wall that most of the seen-through rays cross at a placement.

    Attributes
    ----------
    rows: (K,) its segment rows in the plan (its faces).
    segments: (K, 4) those segments, ``x1 y1 x2 y2`` metres (world).
    share: share of the seen-through points whose ray crosses it (0-1).
    see_through: share of the wall/column points seen through any plan wall (0-1).
    see_through_without: the same without this wall (0-1).
    """

    rows: NDArray[np.int64]
    segments: F64
    share: float
    see_through: float
    see_through_without: float

    def to_dict(self) -> dict[str, Any]:
        return {"rows": [int(r) for r in self.rows],
                "segments": np.round(self.segments, 3).tolist(), "share": self.share,
                "see_through": self.see_through, "see_through_without": self.see_through_without}

    def describe(self) -> str:
        ends = ", ".join(f"({s[0]:.2f}, {s[1]:.2f})-({s[2]:.2f}, {s[3]:.2f})"
                         for s in self.segments)
        return (f"{self.see_through:.0%} of the points were seen through the BIM's walls, "
                f"{self.share:.0%} of them through the one wall with face(s) {ends} m (missing "
                f"as built?); {self.see_through_without:.0%} without it")


def section_rows(plan: FloorPlan, floor_z: float | None, cut_m: float = 1.0
                 ) -> NDArray[np.int64]:
    """(S',) the plan's segment rows at ``cut_m`` above the floor ``floor_z`` (all of them for
    a plan without heights or an unknown floor)."""
    n = len(plan.segments)
    if plan.segment_z is None or floor_z is None:
        return np.arange(n)
    zc = floor_z + cut_m
    return np.flatnonzero((plan.segment_z[:, 0] <= zc) & (zc <= plan.segment_z[:, 1]))


def _wall_faces(seg: F64, k: int, max_thickness_m: float = MAX_WALL_THICKNESS_M,
                max_gap_m: float = MAX_DOOR_GAP_M) -> NDArray[np.int64]:
    """Indices into ``seg`` (S, 4) of the faces of the wall of segment ``k``: ``k`` and the
    segments parallel to it (within 5°), at most ``max_thickness_m`` from its line and
    overlapping it, or the ``max_gap_m`` beyond either of its ends, along its length (the
    pieces of one wall on both sides of a door)."""
    a, b = seg[k, :2], seg[k, 2:]
    length = float(np.linalg.norm(b - a))
    if length < 1e-9:
        return np.array([k])
    u = (b - a) / length
    n = np.array([-u[1], u[0]])
    d = seg[:, 2:] - seg[:, :2]
    lens = np.linalg.norm(d, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        parallel = np.abs(d @ u) >= np.cos(np.deg2rad(5.0)) * lens
    off = np.abs(np.c_[(seg[:, :2] - a) @ n, (seg[:, 2:] - a) @ n]).max(1)
    s0, s1 = (seg[:, :2] - a) @ u, (seg[:, 2:] - a) @ u
    overlap = (np.minimum(np.maximum(s0, s1), length + max_gap_m)
               - np.maximum(np.minimum(s0, s1), -max_gap_m))
    faces = parallel & (lens > 1e-9) & (off <= max_thickness_m) & (overlap > 0.1)
    faces[k] = True
    return np.flatnonzero(faces)


def polished_rays(world_from_cam: F64, samples: SemanticSamples, plan: FloorPlan,
                  floor_z: float | None, options: GlobalAlignOptions | None = None,
                  maps_cache: dict[bytes, Any] | None = None
                  ) -> tuple[NDArray[np.int64], F64, F64]:
    """The rays of the wall/column points as the global alignment's see-through test reads them
    at the placement ``world_from_cam`` (N, 7, TUM order, world frame, level): the storey
    whose floor is nearest ``floor_z`` (its section and wall band), each frame levelled by its
    floor, the placement polished by its frames' mean best turn and shift, each window of
    frames moved by its own bounded ICP and each frame turned by its own best turn
    (``bimcap.registration.global_align._see_through_rays``; at most ``max_points`` points,
    every k-th). A drifted trajectory's rotation and walk spread the rigid placement's rays
    over every wall (pipeline seed 13: 38 % of the seen-through points crossed the wall missing
    as built at the rigid placement, 67 % polished). ``maps_cache``: the storeys' maps kept by
    an alignment of ``plan`` (:func:`.global_align.global_align`), reused; None: built here.

    Returns
    -------
    The storey's segment rows (S,) in ``plan``, and each ray's camera (M, 2) and point (M, 2)
    (world, metres).
    """
    opt = GlobalAlignOptions() if options is None else options
    sections = _storeys(plan, opt.plan_cut_height_m)
    storey = min(sections, key=lambda st: 0.0 if st.floor_z is None or floor_z is None
                 else abs(st.floor_z - floor_z))
    sm = _cached_storey_maps(storey, plan, opt, maps_cache)
    scan = _scan(np.asarray(world_from_cam, np.float64), samples, opt.frame_level_max_deg)
    keep = np.flatnonzero(_keep(scan, storey, opt))
    keep = keep[::max(1, -(-len(keep) // opt.max_points))]
    xy, cls, view, frame = scan.xy[keep], scan.cls[keep], scan.view[keep], scan.frame[keep]
    cams = scan.cams[:, :2]
    if not len(xy):
        return storey.rows, np.zeros((0, 2)), np.zeros((0, 2))
    _, _, _, turn, shift = _frame_fit(_IDENTITY, xy, cls, view, frame, cams, sm.maps, opt)
    q, cam = _see_through_rays(_IDENTITY, turn, shift, xy, cls, view, frame, cams, sm.maps, opt)
    return storey.rows, cam, q


def dominant_seen_through_wall(world_from_cam: F64, samples: SemanticSamples, plan: FloorPlan,
                               floor_z: float | None, options: GlobalAlignOptions | None = None,
                               polished: bool = False,
                               maps_cache: dict[bytes, Any] | None = None
                               ) -> SeenThroughWall | None:
    """The plan wall that the most seen-through rays cross at the placement ``world_from_cam``
    (N, 7, TUM order, world frame): each wall/column point's ray from its camera, on the storey
    of ``floor_z``, crossed as :func:`see_through_fraction` counts it (``options``' margin);
    the rays as the cameras see them (``polished`` off) or as the global alignment's
    see-through test reads them (:func:`polished_rays`). None when no point is seen through a
    wall."""
    opt = GlobalAlignOptions() if options is None else options
    if polished:
        rows, cam, p = polished_rays(world_from_cam, samples, plan, floor_z, opt, maps_cache)
        seg = np.asarray(plan.segments, np.float64)[rows]
        if not len(p) or not len(seg):
            return None
    else:
        rows = section_rows(plan, floor_z)
        seg = np.asarray(plan.segments, np.float64)[rows]
        cams, pts = [], []
        for c in ("wall", "column"):
            fr = getattr(samples, f"{c}_frame")
            if len(fr):
                cams.append(world_from_cam[fr, :2])
                pts.append(transform_points(world_from_cam[fr],
                                            getattr(samples, f"{c}_p_in_cam"))[:, :2])
        if not pts or not len(seg):
            return None
        cam, p = np.concatenate(cams), np.concatenate(pts)

    def seen(s: F64, c: F64, q: F64) -> tuple[float, NDArray[np.bool_]]:
        return see_through_fraction(c, q, s, opt.see_through_margin_m,
                                    margin_from=opt.see_through_margin_from)

    total, flags = seen(seg, cam, p)
    if not flags.any():
        return None
    # The most-crossed segment, counted on at most MAX_COUNTED of the seen-through points.
    some = np.flatnonzero(flags)[::max(1, int(flags.sum()) // MAX_COUNTED)]
    _, counts = see_through_counts(cam[some], p[some], seg, opt.see_through_margin_m,
                                   margin_from=opt.see_through_margin_from)
    faces = _wall_faces(seg, int(np.argmax(counts)))
    crossing = seen(seg[faces], cam[flags], p[flags])[1]
    keep = np.ones(len(seg), bool)
    keep[faces] = False
    return SeenThroughWall(rows=rows[faces], segments=seg[faces],
                           share=float(crossing.mean()), see_through=total,
                           see_through_without=seen(seg[keep], cam, p)[0])


def without_rows(plan: FloorPlan, rows: NDArray[np.int64]) -> FloorPlan:
    """``plan`` without the segment ``rows``."""
    keep = np.ones(len(plan.segments), bool)
    keep[rows] = False
    return replace(plan, segments=plan.segments[keep], segment_class=plan.segment_class[keep],
                   segment_z=None if plan.segment_z is None else plan.segment_z[keep])


def _same_placement(a: F64, b: F64) -> bool:
    """Whether two placements of one trajectory (N, 7 each) agree: mean camera distance at most
    :data:`SAME_PLACEMENT_M` and yaw difference at most :data:`SAME_PLACEMENT_DEG`."""
    from scipy.spatial.transform import Rotation

    dist = float(np.linalg.norm(a[:, :3] - b[:, :3], axis=1).mean())
    rel = Rotation.from_quat(a[:, 3:]) * Rotation.from_quat(b[:, 3:]).inv()
    yaw = np.rad2deg(np.abs(rel.as_euler("ZYX")[:, 0]))
    return dist <= SAME_PLACEMENT_M and float(np.median(yaw)) <= SAME_PLACEMENT_DEG


def align_without_missing_wall(slam_from_cam: F64, samples: SemanticSamples, plan: FloorPlan,
                               refusal: GlobalAlignmentError,
                               options: GlobalAlignOptions | None = None,
                               maps_cache: dict[bytes, Any] | None = None
                               ) -> tuple[GlobalAlignResult, SeenThroughWall] | None:
    """The global alignment again without the one wall a refused placement was seen through.

    Only when ``refusal`` (what :func:`global_align` raised for ``slam_from_cam``, ``samples``
    and ``plan`` with ``options``) says that the best placement fits badly for its see-through
    alone (fit and free space enough), and one wall (:func:`dominant_seen_through_wall`) holds
    at least :data:`MIN_WALL_SHARE` of the seen-through points. Returns the new result and the
    wall, or None (then the refusal stands) when any of that fails, when the alignment without
    the wall refuses too (fits badly or ambiguous), or when its best placement is not the
    refused one. ``maps_cache``: the dict that the refused alignment kept its storeys' maps in
    (``global_align(..., maps_cache=...)``): the polished rays and every storey without the
    wall reuse them (the same maps, bit for bit); None: built again."""
    opt = GlobalAlignOptions() if options is None else options
    res = refusal.result
    if res is None or not res.hypotheses or (res.ambiguous and not opt.accept_ambiguous):
        return None
    best = res.hypotheses[0]
    if (best.fit_score < opt.min_score or best.free_fraction < opt.min_free_fraction
            or best.see_through <= opt.max_see_through):
        return None
    placed = np.asarray(res.poses, np.float64)
    # The rays as the refusal's see-through test read them (polished: the drift's rotation and
    # walk spread the rigid placement's rays over every wall); measured already when the
    # refusal decided not to search the turned scan (the same placement and rays).
    wall = (res.seen_through_wall if res.seen_through_wall is not None
            else dominant_seen_through_wall(placed, samples, plan, best.floor_z, opt,
                                            polished=True, maps_cache=maps_cache))
    # The alignment without the wall applies its own see-through test (:func:`global_align`):
    # ``wall.see_through_without`` is not the gate.
    if wall is None or wall.share < MIN_WALL_SHARE:
        return None
    try:
        again = global_align(slam_from_cam, samples, without_rows(plan, wall.rows), opt,
                             maps_cache)
    except GlobalAlignmentError:
        return None
    if not _same_placement(np.asarray(again.poses, np.float64), placed):
        return None
    return again, wall
