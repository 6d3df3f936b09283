"""Which degrees of freedom of each pose the BIM terms observe.

A frame that sees one wall from close range pins its distance to the wall and its yaw, but not
where along the wall it stands nor its height; a frame that sees only floor pins height, pitch and
roll. This module measures that, per frame, from the BIM terms alone (F, Ce, W, Co) at given poses:
the information matrix

    I = Σ_i  w_i / σ² · J_iᵀ J_i,      J_i = [ n_iᵀ , ((p_i − c) × n_i)ᵀ ]      (1 × 6)

of the frame's samples, where p_i is the sample in the world, c the camera centre, n_i the unit
normal of the residual (the plane's normal for F / Ce, the horizontal normal from the associated
floor-plan segment for W / Co), σ the term's noise scale and w_i the robust loss's weight at the
sample's residual (iteratively reweighted least squares), with the pose perturbed as
``t + δt``, ``exp([δθ]×) R`` about the camera centre. Its inverse gives the standard deviation of
each degree of freedom in a heading-aligned frame: ``along`` (the camera's viewing direction in
the horizontal plane), ``across`` (horizontal, to its left), ``up`` (world z), and the rotations
``roll`` (about along), ``pitch`` (about across), ``yaw`` (about up). A degree of freedom is
*observed* when its standard deviation is below a threshold.

These are the directions the bundle adjustment can take from the BIM for that frame; the others
are held by G (the neighbouring frames), and the pose prior.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.poses import quat_to_rotmat, transform_points
from bimcap.optimize.options import Loss, PlaneMode, SolverOptions, TermOptions

F64 = NDArray[np.float64]

#: The degrees of freedom, in the order of :attr:`FrameObservability.sigma`.
DOF_NAMES: tuple[str, ...] = ("along", "across", "up", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class ObservabilityOptions:
    """Thresholds of :func:`bim_observability`.

    Attributes
    ----------
    max_sigma_m: a translation is observed when its standard deviation is at most this (m).
    max_sigma_deg: a rotation is observed when its standard deviation is at most this (deg).
        The standard deviations follow from the terms' noise scales (5 cm per sample by
        default), so they are conservative: "observed" means the BIM alone would place the frame
        to within these bounds.
    """

    max_sigma_m: float = 0.05
    max_sigma_deg: float = 1.0


@dataclass
class FrameObservability:
    """One frame's BIM observability.

    Attributes
    ----------
    frame: frame index.
    samples: samples per term that count (associated, non-zero weight), e.g. ``{"W": 120}``.
    sigma: (6,) standard deviations of along, across, up (m) and roll, pitch, yaw (deg) from the
        BIM terms alone; ``inf`` where unobserved.
    observed: the names (:data:`DOF_NAMES`) whose sigma is within the thresholds.
    """

    frame: int
    samples: dict[str, int]
    sigma: F64
    observed: list[str]

    @property
    def unobserved(self) -> list[str]:
        return [d for d in DOF_NAMES if d not in self.observed]

    def to_dict(self) -> dict[str, Any]:
        return {
            "frame": self.frame,
            "samples": dict(self.samples),
            "sigma": {d: (None if not np.isfinite(s) else float(s))
                      for d, s in zip(DOF_NAMES, self.sigma, strict=True)},
            "observed": list(self.observed),
        }


@dataclass
class Observability:
    """Per-frame BIM observability of a trajectory (:func:`bim_observability`)."""

    frames: list[FrameObservability]
    options: ObservabilityOptions = field(default_factory=ObservabilityOptions)

    def count_unobserved(self) -> dict[str, int]:
        """How many frames leave each degree of freedom unobserved by the BIM terms."""
        return {d: sum(d not in f.observed for f in self.frames) for d in DOF_NAMES}

    def fully_observed(self) -> int:
        """Frames whose six degrees of freedom the BIM terms all observe."""
        return sum(len(f.observed) == len(DOF_NAMES) for f in self.frames)

    def sigma(self) -> F64:
        """(N, 6) standard deviations, columns as :data:`DOF_NAMES` (m, deg)."""
        return np.array([f.sigma for f in self.frames]).reshape(-1, len(DOF_NAMES))

    def to_dict(self) -> dict[str, Any]:
        return {
            "dof": list(DOF_NAMES),
            "units": {"along": "m", "across": "m", "up": "m", "roll": "deg", "pitch": "deg",
                      "yaw": "deg"},
            "thresholds": {"max_sigma_m": self.options.max_sigma_m,
                           "max_sigma_deg": self.options.max_sigma_deg},
            "fully_observed_frames": self.fully_observed(),
            "unobserved_frames_per_dof": self.count_unobserved(),
            "frames": [f.to_dict() for f in self.frames],
        }

    def summary_line(self) -> str:
        """One line for the log: frames fully observed and, per degree of freedom, how many not."""
        counts = ", ".join(f"{d} {n}" for d, n in self.count_unobserved().items() if n)
        n = len(self.frames)
        tail = f"; unobserved by the BIM in: {counts} (held by G and the prior)" if counts else ""
        return f"BIM observability: {self.fully_observed()}/{n} frames fully observed" + tail


def irls_weight(loss: Loss, scale: float, r: F64) -> F64:
    """The robust loss's weight ρ'(r²) of whitened residuals ``r`` (in sigmas), loss scale ``scale``
    (in sigmas): 1 for plain squares, less for outliers (Ceres' definitions)."""
    s2 = np.asarray(r, np.float64) ** 2 / (scale * scale)
    if loss is Loss.NONE:
        return np.ones_like(s2)
    if loss is Loss.HUBER:
        return np.where(s2 <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(s2, 1e-300)))
    if loss is Loss.CAUCHY:
        return 1.0 / (1.0 + s2)
    if loss is Loss.SOFT_L1:
        return 1.0 / np.sqrt(1.0 + s2)
    if loss is Loss.ARCTAN:
        return 1.0 / (1.0 + s2 * s2)
    if loss is Loss.TUKEY:
        return np.where(s2 <= 1.0, (1.0 - s2) ** 2, 0.0)
    raise ValueError(f"unknown loss {loss!r}")


def _segment_normals(p_xy: F64, segments: F64) -> tuple[F64, F64]:
    """Unit horizontal normals (n, 3) from each point's segment towards the point, and the
    point-to-segment distances (n,)."""
    a, b = segments[:, :2], segments[:, 2:]
    d = b - a
    t = np.clip(((p_xy - a) * d).sum(1) / np.maximum((d * d).sum(1), 1e-300), 0.0, 1.0)
    off = p_xy - (a + t[:, None] * d)
    dist = np.linalg.norm(off, axis=1)
    perp = np.stack([-d[:, 1], d[:, 0]], 1) / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
    n2 = np.where(dist[:, None] > 1e-9, off / np.maximum(dist, 1e-300)[:, None], perp)
    return np.column_stack([n2, np.zeros(len(n2))]), dist


def _add_term(info: F64, counts: NDArray[np.int64], frames: NDArray[np.int32], p_world: F64,
              normals: F64, residual_m: F64, centres: F64, term: TermOptions) -> None:
    """Accumulate one term's samples into the per-frame information ``info`` (N, 6, 6)."""
    if len(frames) == 0:
        return
    w = irls_weight(Loss(term.loss), term.loss_scale, residual_m / term.sigma) * term.weight
    w = w / term.sigma**2
    lever = p_world - centres[frames]
    jac = np.concatenate([normals, np.cross(lever, normals)], axis=1)  # (n, 6)
    np.add.at(info, frames, w[:, None, None] * jac[:, :, None] * jac[:, None, :])
    np.add.at(counts, frames[w > 0], 1)


def _heading_frame(world_from_cam: F64) -> F64:
    """(3, 3) rows: along (horizontal viewing direction), across (left), up."""
    rot = quat_to_rotmat(world_from_cam[3:7])
    fwd = rot[:, 2].copy()
    fwd[2] = 0.0
    if np.linalg.norm(fwd) < 1e-6:  # looking straight up or down: use the camera's y axis
        fwd = -rot[:, 1].copy()
        fwd[2] = 0.0
    fwd /= np.linalg.norm(fwd)
    up = np.array([0.0, 0.0, 1.0])
    return np.stack([fwd, np.cross(up, fwd), up])


#: One term's per-frame information (N, 6, 6) and counted samples (N,).
_TermInformation = tuple[F64, NDArray[np.int64]]


def _no_information(n: int) -> _TermInformation:
    """Zero information (n, 6, 6) and zero sample counts (n,) for ``n`` frames."""
    return np.zeros((n, 6, 6)), np.zeros(n, np.int64)


def _term_array(arrays: dict[str, Any], name: str) -> Any:
    """``arrays[name]``, or an empty array (indices for ``*frame`` / ``*plane``, else (0, 3))."""
    v = arrays.get(name)
    if v is not None:
        return v
    return np.zeros(0, np.int32) if name.endswith(("frame", "plane")) else np.zeros((0, 3))


def _sample_planes(arrays: dict[str, Any], prefix: str, all_planes: F64, facap_slot: int | None,
                   count: int) -> F64 | None:
    """(count, 4) each sample's plane: the fitted plane ``facap_slot`` (None if not finite) in
    FACaP plane mode, else the BIM plane of the sample's ``<prefix>_plane`` index."""
    if facap_slot is None:
        planes: F64 = all_planes[np.asarray(_term_array(arrays, f"{prefix}_plane"), np.int64)]
        return planes
    if len(all_planes) <= facap_slot or not np.isfinite(all_planes[facap_slot]).all():
        return None
    return np.repeat(all_planes[facap_slot][None], count, 0)


def _plane_term_information(arrays: dict[str, Any], poses: F64, term: TermOptions, prefix: str,
                            all_planes: F64, facap_slot: int | None) -> _TermInformation:
    """Per-frame information of a plane term (F: ``prefix`` "floor", Ce: "ceiling") at ``poses``."""
    info, counts = _no_information(len(poses))
    frames = np.asarray(_term_array(arrays, f"{prefix}_frame"), np.int32)
    if not term.enabled or len(frames) == 0:
        return info, counts
    pl = _sample_planes(arrays, prefix, all_planes, facap_slot, len(frames))
    if pl is None:
        return info, counts
    p_in_cam = np.asarray(_term_array(arrays, f"{prefix}_p_in_cam"), np.float64)
    p_world = transform_points(poses[frames], p_in_cam)
    res = (p_world * pl[:, :3]).sum(1) + pl[:, 3]
    _add_term(info, counts, frames, p_world, pl[:, :3], res, poses[:, :3], term)
    return info, counts


def _segment_term_information(arrays: dict[str, Any], poses: F64, term: TermOptions, prefix: str,
                              assoc: NDArray[np.integer] | None,
                              segments: F64) -> _TermInformation:
    """Per-frame information of a segment term (W: ``prefix`` "wall", Co: "column") at ``poses``,
    its samples associated to ``segments`` by ``assoc`` (-1 = none; None: term left out)."""
    info, counts = _no_information(len(poses))
    frames = np.asarray(_term_array(arrays, f"{prefix}_frame"), np.int32)
    if not term.enabled or assoc is None or len(frames) == 0:
        return info, counts
    seg = np.asarray(assoc, np.int64)
    ok = seg >= 0
    frames = frames[ok]
    p_in_cam = np.asarray(_term_array(arrays, f"{prefix}_p_in_cam"), np.float64)[ok]
    p_world = transform_points(poses[frames], p_in_cam)
    normals, dist = _segment_normals(p_world[:, :2], segments[seg[ok]])
    _add_term(info, counts, frames, p_world, normals, dist, poses[:, :3], term)
    return info, counts


def _frame_observability(frame: int, world_from_cam: F64, info: F64,
                         per_term: dict[str, _TermInformation],
                         th: ObservabilityOptions) -> FrameObservability:
    """One frame's sigmas and observed DOFs from its total (6, 6) information ``info``."""
    basis = _heading_frame(world_from_cam)
    rot6 = np.zeros((6, 6))
    rot6[:3, :3] = basis
    rot6[3:, 3:] = basis
    info_local = rot6 @ info @ rot6.T
    sigma = _marginal_sigma(info_local)
    sigma[3:] = np.degrees(sigma[3:])
    limits = np.array([th.max_sigma_m] * 3 + [th.max_sigma_deg] * 3)
    observed = [d for d, s, lim in zip(DOF_NAMES, sigma, limits, strict=True) if s <= lim]
    samples = {name: int(c[frame]) for name, (_, c) in per_term.items() if c[frame]}
    return FrameObservability(frame=frame, samples=samples, sigma=sigma, observed=observed)


def bim_observability(
    arrays: dict[str, Any],
    poses: F64,
    options: SolverOptions,
    wall_segment: NDArray[np.integer] | None = None,
    column_segment: NDArray[np.integer] | None = None,
    planes: F64 | None = None,
    thresholds: ObservabilityOptions | None = None,
) -> Observability:
    """Per-frame observability of ``poses`` by the enabled BIM terms of a problem.

    Parameters
    ----------
    arrays: the problem's arrays (``Problem.arrays()``): ``floor_frame``, ``floor_p_in_cam``,
        ``floor_plane``, ``planes``, likewise ceiling; ``wall_*``, ``column_*``, ``segments``.
    poses: (N, 7) world_from_cam (TUM order) at which to evaluate, normally the solution.
    options: the solve's options (which terms are on, their sigma, loss and weight).
    wall_segment, column_segment: (W,), (W',) association of the solve (-1 = none); None
        leaves the term out.
    planes: planes to use instead of ``arrays["planes"]`` (the fitted (2, 4) floor / ceiling
        planes of FACaP plane mode).
    thresholds: when a degree of freedom counts as observed.

    Returns
    -------
    :class:`Observability` with one entry per frame.
    """

    th = thresholds or ObservabilityOptions()
    poses = np.asarray(poses, np.float64)
    facap = PlaneMode(options.plane_mode) is PlaneMode.FACAP
    all_planes = np.asarray(planes if planes is not None
                            else arrays.get("planes", np.zeros((0, 4))))
    segments = np.asarray(arrays.get("segments", np.zeros((0, 4))), np.float64)
    per_term: dict[str, _TermInformation] = {
        "F": _plane_term_information(arrays, poses, options.floor, "floor", all_planes,
                                     facap_slot=0 if facap else None),
        "Ce": _plane_term_information(arrays, poses, options.ceiling, "ceiling", all_planes,
                                      facap_slot=1 if facap else None),
        "W": _segment_term_information(arrays, poses, options.wall, "wall", wall_segment,
                                       segments),
        "Co": _segment_term_information(arrays, poses, options.column, "column", column_segment,
                                        segments),
    }
    n = len(poses)
    total: F64 = sum((i for i, _ in per_term.values()), np.zeros((n, 6, 6)))
    frames = [_frame_observability(f, poses[f], total[f], per_term, th) for f in range(n)]
    return Observability(frames=frames, options=th)


def _marginal_sigma(info: F64) -> F64:
    """(6,) standard deviations from a 6×6 information matrix; ``inf`` along directions it does
    not constrain (a pseudo-inverse restricted to the well-conditioned eigen-directions)."""
    vals, vecs = np.linalg.eigh(0.5 * (info + info.T))
    top = max(float(vals.max()), 0.0)
    keep = vals > max(top * 1e-10, 1e-12)
    sigma = np.full(6, np.inf)
    if not keep.any():
        return sigma
    cov = (vecs[:, keep] / vals[keep]) @ vecs[:, keep].T
    # a degree of freedom with a component along a dropped direction is unobserved
    leak = (vecs[:, ~keep] ** 2).sum(1) > 1e-6
    sigma[~leak] = np.sqrt(np.maximum(np.diag(cov)[~leak], 0.0))
    return sigma


def unanchored_frames(match_frames: NDArray[np.integer] | None, observability: Observability,
                      min_matches: int = 1) -> list[int]:
    """Frames whose G component the BIM terms do not fully observe.

    The frames are joined into components by G: two frames are linked when at least
    ``min_matches`` matches join them (``match_frames``, (M, 2) frame indices, one row per
    match). A component is *anchored* when each of the six degrees of freedom
    (:data:`DOF_NAMES`, in each frame's heading-aligned axes) is observed by the BIM terms in
    at least one of its frames (:attr:`FrameObservability.observed`): G carries it to the
    others. The frames of the other components — a frame with no matches that sees one wall,
    an island of frames matched only to each other that see no floor — have directions that
    nothing but their own noisy samples and the weak pose prior decide. Returns their indices,
    ascending.
    """
    n = len(observability.frames)
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    if match_frames is not None and len(match_frames):
        pairs, counts = np.unique(np.sort(np.asarray(match_frames, np.int64), axis=1), axis=0,
                                  return_counts=True)
        for (a, b), c in zip(pairs, counts, strict=True):
            if c >= min_matches and a != b and 0 <= a < n and 0 <= b < n:
                parent[find(int(a))] = find(int(b))
    seen: dict[int, set[str]] = {}
    for f in observability.frames:
        if 0 <= f.frame < n:
            seen.setdefault(find(f.frame), set()).update(f.observed)
    anchored = {root for root, dofs in seen.items() if dofs >= set(DOF_NAMES)}
    return [i for i in range(n) if find(i) not in anchored]
