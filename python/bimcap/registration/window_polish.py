"""Windows of frames polished rigidly before the see-through test of a global placement.

A drifted trajectory is not rigid: its translation walks (Exp 2: 0.3 m RMS, up to 0.46 m
at the end of pipeline seed 8's 60 frames) and each frame's rotation is off by its own error
(8.8 deg RMS). :func:`bimcap.registration.global_align` places it as one rigid scan, and its
see-through test (:func:`~bimcap.registration.global_align.see_through_fraction`: the share of
wall/column points whose ray from the camera crosses a plan wall) turned each frame by its own
best turn but left the walk to the rigid placement: at the *true* rigid placement of seed 8's
drifted trajectory 24 % of the points were still seen through walls (3 % at the true poses),
and the right placement was refused (maximum 15 %).

The walk is local: over a few seconds of frames it is a small rigid offset. Here each window
of ``window_frames`` consecutive frames is refined on its own by a point-to-segment ICP
(:func:`~bimcap.registration.icp.icp_2d`, same-class, ray-direction-aware association), and the
refinement is taken only when it stays within ``max_yaw_deg`` / ``max_shift_m`` of where the
placement put the window: enough for the drift of a window, too little to pull a window's
points through a wall into the next room (a partition is 2-6 m away in the buildings tested;
docs/global_align.md, "The see-through under drift").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bimcap.registration.icp import Correction2D, icp_2d, rot2
from bimcap.registration.plan_maps import PlanMaps

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


@dataclass(frozen=True)
class WindowPolish:
    """The settings of :func:`polish_windows` (metres, degrees).

    Attributes
    ----------
    window_frames: frames per window (consecutive frame indices; 0: no polish).
    max_yaw_deg, max_shift_m: a window's ICP correction is taken only when its turn (about the
        window's camera centroid) and shift are at most these; otherwise the window is left as
        the placement put it.
    min_points: a window with fewer wall/column points is left as it is.
    radius_start_m, radius_end_m, iterations, huber_m: the ICP of each window
        (:func:`~bimcap.registration.icp.icp_2d`).
    """

    window_frames: int = 10
    max_yaw_deg: float = 5.0
    max_shift_m: float = 0.5
    min_points: int = 50
    radius_start_m: float = 0.5
    radius_end_m: float = 0.12
    iterations: int = 10
    huber_m: float = 0.05

    def __post_init__(self) -> None:
        if self.window_frames < 0 or self.min_points < 1 or self.iterations < 1:
            raise ValueError(f"window_frames must be >= 0, min_points and iterations >= 1 "
                             f"(got {self.window_frames}, {self.min_points}, {self.iterations})")
        for name in ("max_yaw_deg", "max_shift_m", "radius_start_m", "radius_end_m", "huber_m"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {value}")


def polish_windows(q_xy: F64, p_cls: I32, view_xy: F64, p_frame: I32, cams_xy: F64,
                   maps: PlanMaps, opt: WindowPolish
                   ) -> tuple[F64, F64, F64, NDArray[np.bool_]]:
    """Each window of frames moved by its own bounded rigid ICP onto the plan.

    Parameters
    ----------
    q_xy: (M, 2) wall/column points where a placement puts them (world, metres).
    p_cls: (M,) their class (``Label.WALL`` / ``Label.COLUMN``).
    view_xy: (M, 2) their ray directions camera → point (world).
    p_frame: (M,) their frame index into ``cams_xy``.
    cams_xy: (N, 2) the cameras where the placement puts them (world, metres).
    maps: the storey's plan maps (:class:`~bimcap.registration.plan_maps.PlanMaps`; the ICP
        associates with :meth:`~bimcap.registration.plan_maps.PlanMaps.nearest`).
    opt: :class:`WindowPolish`.

    Returns
    -------
    The points (M, 2), ray directions (M, 2) and cameras (N, 2) with each window's correction
    applied, and (W,) whether each window was moved (``W = ceil(N / window_frames)``; none
    when ``window_frames`` is 0).
    """
    q, view, cams = q_xy.copy(), view_xy.copy(), cams_xy.copy()
    n, w = len(cams_xy), opt.window_frames
    if w <= 0 or n == 0:
        return q, view, cams, np.zeros(0, dtype=bool)

    def associate(qq: F64, cc: I32, vv: F64) -> tuple[F64, F64]:
        return maps.nearest(qq, maps.layer_of(cc, vv))

    # Equal windows (the last one no shorter than half a window: it joins the one before).
    starts = list(range(0, n, w))
    if len(starts) > 1 and n - starts[-1] < w / 2:
        starts.pop()
    ends = [*starts[1:], n]
    moved = np.zeros(len(starts), dtype=bool)
    max_yaw = np.deg2rad(opt.max_yaw_deg)
    for k, (a, b) in enumerate(zip(starts, ends, strict=True)):
        m = (p_frame >= a) & (p_frame < b)
        if int(m.sum()) < opt.min_points:
            continue
        pivot = cams[a:b].mean(0)
        fit = icp_2d(q[m], p_cls[m], associate, Correction2D(0.0, np.zeros(2), pivot), view[m],
                     opt.radius_start_m, opt.radius_end_m, opt.iterations, opt.huber_m)
        c = fit.correction
        if (not np.isfinite(c.yaw) or not np.isfinite(c.t).all() or abs(c.yaw) > max_yaw
                or float(np.linalg.norm(c.t)) > opt.max_shift_m):
            continue
        q[m] = c.apply(q[m])
        view[m] = view[m] @ rot2(c.yaw).T
        cams[a:b] = c.apply(cams[a:b])
        moved[k] = True
    return q, view, cams, moved
