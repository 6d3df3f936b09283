"""Wall and column samples the BIM cannot explain at the refined poses, found and dropped.

A label image's wrong labels make samples of the wrong class: a blob of a window or of clutter
labelled *wall* lies where no wall of the BIM is. When it lies inside the solver's association
gate (0.5 m) its samples are associated with the wall behind it, and although the robust loss
shrinks each one's pull, a frame that little else holds (one wall seen from close range, no
feature match) is turned by them: on gen-small-s3 hard, frame 55's nine samples of a window
blob labelled wall, 0.24-0.45 m in front of the wall, left the frame 2.6° off from the ground
truth. Once the solve has converged, every sample that a correct label would put on a wall face
lies within a few range-noise σ of one; :func:`inconsistent_samples` finds the others, and the
caller solves again without them (the second association pass with a tighter gate).

A frame whose samples are mostly far from the BIM is misplaced, not mislabelled: its samples
are kept (``max_fraction``), so that a later repair can still move it and the BIM judge it.

Arrays follow docs/architecture.md: poses ``(N, 7)`` TUM order ``world_from_cam``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.poses import transform_points

F64 = NDArray[np.float64]

#: The sample terms checked and the floor-plan segment class each is explained by.
CHECKED_TERMS = (("wall", 1), ("column", 4))


@dataclass
class SampleCheck:
    """What :func:`inconsistent_samples` found.

    Attributes
    ----------
    gate_m: the largest distance in plan (metres) from a segment of the sample's class that
        counts as explained.
    keep: term name (``"wall"``, ``"column"``) → (n,) bool, False for a sample to drop.
    dropped: term name → how many samples are dropped.
    frames: the frames that lose samples (sorted).
    misplaced: frames with more than ``max_fraction`` of their samples unexplained, whose
        samples are all kept (sorted).
    """

    gate_m: float
    keep: dict[str, NDArray[np.bool_]] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    frames: list[int] = field(default_factory=list)
    misplaced: list[int] = field(default_factory=list)

    @property
    def total_dropped(self) -> int:
        return int(sum(self.dropped.values()))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (without the masks)."""
        return {"gate_m": self.gate_m, "dropped": dict(self.dropped), "frames": self.frames,
                "misplaced": self.misplaced}


def inconsistent_samples(arrays: dict[str, Any], poses: F64, gate_m: float,
                         max_fraction: float = 0.5) -> SampleCheck:
    """The wall and column samples further than ``gate_m`` in plan from every floor-plan
    segment of their class at ``poses``.

    Parameters
    ----------
    arrays: a problem's arrays (``bimcap.optimize.Problem.arrays()`` or the front end's
        ``to_problem_arrays()`` plus ``segments`` (S, 4) ``x1 y1 x2 y2`` metres and
        ``segment_class`` (S,)): ``wall_frame`` (W,) int, ``wall_p_in_cam`` (W, 3) metres,
        likewise ``column_*``.
    poses: (N, 7) ``world_from_cam``, TUM order, at which the samples are judged (a converged
        solve's).
    gate_m: metres, > 0.
    max_fraction: a frame with more than this share of its wall and column samples beyond the
        gate keeps them all (it is misplaced; its samples are its only way back).

    Returns
    -------
    :class:`SampleCheck`.
    """
    from bimcap.registration.icp import point_segment_distance

    if not gate_m > 0:
        raise ValueError(f"gate_m must be > 0, got {gate_m!r}")
    poses = np.asarray(poses, np.float64).reshape(-1, 7)
    seg = np.asarray(arrays["segments"], np.float64).reshape(-1, 4)
    seg_class = np.asarray(arrays["segment_class"]).ravel()
    far: dict[str, NDArray[np.bool_]] = {}
    frame_of: dict[str, NDArray[np.int64]] = {}
    for term, label in CHECKED_TERMS:
        frames = np.asarray(arrays.get(f"{term}_frame", np.zeros(0)), np.int64).ravel()
        p_cam = np.asarray(arrays.get(f"{term}_p_in_cam", np.zeros((0, 3))),
                           np.float64).reshape(-1, 3)
        segs = seg[seg_class == label]
        frame_of[term] = frames
        if not len(frames) or not len(segs):
            far[term] = np.zeros(len(frames), bool)
            continue
        p_world = transform_points(poses[frames], p_cam)
        dist, _, _ = point_segment_distance(p_world[:, :2], segs)
        far[term] = ~(dist <= gate_m)  # NaN (a non-finite sample) counts as far
    n = len(poses)
    total = sum(np.bincount(frame_of[t], minlength=n) for t, _ in CHECKED_TERMS)
    bad = sum(np.bincount(frame_of[t][far[t]], minlength=n) for t, _ in CHECKED_TERMS)
    misplaced = bad > max_fraction * np.maximum(total, 1)
    check = SampleCheck(gate_m=float(gate_m),
                        misplaced=[int(i) for i in np.flatnonzero(misplaced & (bad > 0))])
    lose = np.zeros(n, bool)
    for term, _ in CHECKED_TERMS:
        drop = far[term] & ~misplaced[frame_of[term]]
        check.keep[term] = ~drop
        check.dropped[term] = int(drop.sum())
        lose[frame_of[term][drop]] = True
    check.frames = [int(i) for i in np.flatnonzero(lose)]
    return check
