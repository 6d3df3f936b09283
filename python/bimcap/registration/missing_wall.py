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

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.registration.coarse import FloorPlan, SemanticSamples
from bimcap.registration.errors import GlobalAlignmentError
from bimcap.registration.global_align import (
    MIN_WALL_SHARE,
    GlobalAlignOptions,
    GlobalAlignResult,
    SeenThroughWall,
    dominant_seen_through_wall,
    global_align,
    polished_rays,
    section_rows,
)

# The wall that the seen-through rays cross is found in :mod:`.global_align` (its turned
# search reads it too, and a module here imports only downward); re-exported here.
__all__ = ["MIN_WALL_SHARE", "SeenThroughWall", "align_without_missing_wall",
           "dominant_seen_through_wall", "polished_rays", "section_rows", "without_rows"]

F64 = NDArray[np.float64]

#: The placement found again without the wall must be the refused one: mean camera distance
#: (metres) and yaw difference (degrees) at most these.
SAME_PLACEMENT_M, SAME_PLACEMENT_DEG = 0.5, 5.0


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
