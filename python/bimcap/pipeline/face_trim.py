"""Camera-pixel wall samples that are not on their wall face: window frames, counter
backsplashes, cabinet fronts and stair stringers a few centimetres in front of it.

The geometric segmenter labels every vertical plane a wall, and a window frame 3 cm in front of
the wall's face is an inlier of the wall's own plane. Such samples lie on one side of the face
(in front of it), 1–30 cm off: the solver's Cauchy loss at the 2 cm noise scale gives those
within a few centimetres their full pull, so where one side of a room has a kitchen counter or
windows and the other not, the walls pull every frame the same way (Duplex_A's fixed point:
−0.22 cm in y, half of its y pull from such pixel samples; docs/generalization.md, "What still
pulled Duplex_A's fixed point"). The pixels' samples are precise (planes fitted to the returns:
0.2 cm robust spread about their face at the truth), so they are told apart from their face
per frame and associated segment (a group):

1. the gate is ``sigmas`` robust spreads of every candidate's distance from its group's
   median, at least ``min_gate_m`` (1.2 cm on the standard setting);
2. the face is where the pose puts it: the median of the group's samples within the gate of
   the segment; with fewer than ``min_face_samples`` there (a frame still off, or samples that
   belong to no face of this segment), the group's median;
3. a face whose samples within the gate spread more than ``max_face_spread`` robust spreads is
   not one thin face (a curtain wall's mullions and glazing): the group is kept whole;
4. otherwise the group's samples further than the gate from the face are dropped.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.geometry import transform_points

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class FaceTrimOptions:
    """Settings of :func:`off_face_samples`.

    Attributes
    ----------
    sigmas: the gate in robust spreads (1.4826 × median absolute deviation of every candidate's
        distance from its group's median).
    min_gate_m: the gate's floor (metres): a face's samples never spread less than this.
    min_face_samples: a group with fewer samples within the gate of its face at the given
        pose is centred on its median instead (a frame still off, or samples that are not of
        this face at all: Office_A's 13 cm door jambs take samples 10–20 cm behind them).
    max_face_spread: a group whose samples within the gate of the face spread more than this
        many times the robust spread is kept whole: it is not one thin face (a curtain wall's
        mullions and glazing, 1–8 cm in front of its segment: SampleHouse4).
    """

    sigmas: float = 5.0
    min_gate_m: float = 0.01
    min_face_samples: int = 3
    max_face_spread: float = 2.0

    def __post_init__(self) -> None:
        if not (self.sigmas > 0 and self.min_gate_m >= 0 and self.min_face_samples >= 1
                and self.max_face_spread > 0):
            raise InputError(f"FaceTrimOptions: sigmas, min_face_samples and max_face_spread "
                             f"must be > 0 and min_gate_m >= 0, got {self.sigmas!r}, "
                             f"{self.min_face_samples!r}, {self.max_face_spread!r}, "
                             f"{self.min_gate_m!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields."""
        return asdict(self)


@dataclass(frozen=True)
class FaceTrim:
    """The result of :func:`off_face_samples`.

    Attributes
    ----------
    keep: (M,) bool, False for the samples dropped.
    gate_m: the gate used (metres). spread_m: the candidates' robust spread (metres).
    """

    keep: NDArray[np.bool_]
    gate_m: float
    spread_m: float

    @property
    def dropped(self) -> int:
        """How many samples were dropped."""
        return int((~self.keep).sum())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no per-sample array)."""
        return {"dropped": self.dropped, "samples": len(self.keep),
                "gate_m": self.gate_m, "spread_m": self.spread_m}


def signed_segment_distance(p_in_world: F64, segments: F64, segment_normal: F64,
                            segment_of: NDArray[np.integer]) -> F64:
    """Signed xy distance (M,) in metres of points (M, 3) to their segments (S, 4: x0, y0, x1,
    y1), clamped to the segment's ends, positive on the side of its free-side normal (S, 2; a
    zero normal: the segment's left); NaN where ``segment_of`` is -1."""
    out = np.full(len(p_in_world), np.nan)
    ok = np.asarray(segment_of) >= 0
    s = np.asarray(segment_of)[ok]
    a, b = segments[s, :2], segments[s, 2:]
    d = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-18)
    xy = p_in_world[ok, :2]
    t = np.clip(np.einsum("ij,ij->i", xy - a, d) / length2, 0.0, 1.0)
    diff = xy - (a + t[:, None] * d)
    n = segment_normal[s].copy()
    left = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.sqrt(length2)[:, None]
    zero = np.einsum("ij,ij->i", n, n) < 0.5
    n[zero] = left[zero]
    side = np.where(np.einsum("ij,ij->i", diff, n) >= 0, 1.0, -1.0)
    out[ok] = side * np.linalg.norm(diff, axis=1)
    return out


def off_face_samples(frame: NDArray[np.integer], p_in_cam: F64, segment_of: NDArray[np.integer],
                     world_from_cam: F64, segments: F64, segment_normal: F64,
                     candidates: NDArray[np.bool_],
                     options: FaceTrimOptions | None = None) -> FaceTrim:
    """Which segment samples to keep (module doc).

    Parameters
    ----------
    frame: (M,) frame of each sample. p_in_cam: (M, 3) sample points in the camera frame (m).
    segment_of: (M,) the segment each sample is associated with (-1: none; kept).
    world_from_cam: (N, 7) the poses of that association.
    segments: (S, 4) floor-plan segments (m). segment_normal: (S, 2) their free-side normals.
    candidates: (M,) the samples that may be dropped (the camera pixels'); the others are kept
        and do not enter the groups' medians.
    """
    opts = options or FaceTrimOptions()
    frame = np.asarray(frame)
    m = len(frame)
    seg = np.asarray(segment_of)
    if not (np.asarray(p_in_cam).shape == (m, 3) and seg.shape == (m,)
            and np.asarray(candidates).shape == (m,)):
        raise InputError(f"off_face_samples: frame {frame.shape}, p_in_cam "
                         f"{np.asarray(p_in_cam).shape}, segment_of {seg.shape} and candidates "
                         f"{np.asarray(candidates).shape} must describe the same samples")
    keep = np.ones(m, bool)
    use = np.asarray(candidates, bool) & (seg >= 0)
    if not use.any():
        return FaceTrim(keep=keep, gate_m=float("nan"), spread_m=float("nan"))
    idx = np.flatnonzero(use)
    poses = np.asarray(world_from_cam, np.float64)[frame[idx]]
    r = signed_segment_distance(transform_points(poses, np.asarray(p_in_cam)[idx]),
                                np.asarray(segments, np.float64),
                                np.asarray(segment_normal, np.float64), seg[idx])
    n_seg = len(segments)
    group = frame[idx].astype(np.int64) * n_seg + seg[idx]
    _, inverse = np.unique(group, return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    bounds = np.flatnonzero(np.diff(inverse[order])) + 1
    dev = np.empty(len(idx))
    for part in np.split(order, bounds):
        dev[part] = r[part] - np.median(r[part])
    spread = 1.4826 * float(np.median(np.abs(dev)))
    gate = max(opts.min_gate_m, opts.sigmas * spread)
    for part in np.split(order, bounds):
        near = part[np.abs(r[part]) <= gate]  # the face where the pose puts it
        if len(near) >= opts.min_face_samples:
            centre = float(np.median(r[near]))
            if 1.4826 * float(np.median(np.abs(r[near] - centre))) > opts.max_face_spread * spread:
                continue  # not one thin face: a curtain wall's mullions and glazing
        else:  # no face where the pose puts it: the group's median (a frame still off)
            centre = float(np.median(r[part]))
        keep[idx[part[np.abs(r[part] - centre) > gate]]] = False
    return FaceTrim(keep=keep, gate_m=gate, spread_m=spread)
