"""Which BIM floor / ceiling plane each semantic sample lies on, verified by its own height.

:func:`bimcap.bim.planes.plane_under` answers "which plane is under this world point"; a sample
mapped to the world with a drifted pose (1.4 m, 10° off at the start of a bundle adjustment)
does not sit where it is, so on a storey with several floor heights (finishes, sunken areas,
landings) or over a basement the nearest plane by height is often the wrong one, and a wrong
plane pulls the solver as hard as a right one. :func:`choose_planes` therefore decides per
**frame**, from everything the frame sees.

A pose error moves a frame's samples rigidly. For the heights that matter here, a small rotation
error ω about the camera centre c and a height error δ of the camera change the height of a
sample at p by ``δ + g·(p_xy − c_xy)`` with the tilt gradient ``g = (−ω_y, ω_x)``; a yaw or xy
error does not change heights. So, with ``e_iq = z_i − h_q(x_i, y_i)`` the height of sample i
above plane q (for every plane q of the sample's kind whose polygon contains its xy):

1. **The frame's tilt and offset.** ``e_iq ≈ a + g·(p_xy − c_xy)`` for the right planes. A
   RANSAC over the frame's (sample, plane) pairs (three pairs per hypothesis, and one pair with
   g = 0) keeps the hypothesis most samples agree with (within ``vote_tolerance_m``), discounted
   by its size (``|a| + 3 m·|g|`` over ``2·max_offset_m``: a storey-wide plane a storey away
   must not win by containing a few more samples than the floor they are on) and by the samples
   it puts behind their plane (``behind_weight`` each: a floor sample under the floor, a wall
   sample under the floor or over the ceiling, which is what a hypothesis that snaps a table
   top or a lintel onto the plane does to the real floor and the walls), refined by least
   squares on its inliers; ``|g|`` is bounded by ``max_tilt_deg`` and ``|a|`` by
   ``max_offset_m``. Floor and ceiling samples, and steps between floors, all take part.
2. **Neighbours.** A pose's height error drifts slowly, and a frame that sees mostly a table
   top or a lintel must not be moved by its height: when a frame's offset ``a`` is more than
   ``max_offset_jump_m`` from the median of its well-supported neighbours' (``neighbour_frames``
   either side), its fit is repeated with ``a`` restricted to that window. A frame with fewer
   than ``min_support`` agreeing samples keeps its pose's tilt (g = 0) and takes the neighbours'
   offset (0 without neighbours).
3. **The plane of each sample.** Among the planes containing the sample's xy, the nearest after
   the tilt and offset; a sample farther than ``tolerance_m`` (``unlevelled_tolerance_m`` in a
   frame with too little support to measure its tilt) from every candidate is dropped and
   counted: it is clutter, a mislabelled pixel, a ramp, or drift has put it over the wrong area.

The pipeline re-chooses at the poses of every solver stage, and after the last one with
``frame_model=False`` (the poses have converged: no tilt or offset, the strict tolerance), so
that what drift got wrong at the start is corrected and samples that only a frame's offset made
fit (a sofa labelled floor that a frame seeing little else snapped onto the floor) are dropped
(``bimcap.pipeline.refine``). :func:`plane_residual_check` is the matching check after a solve:
a term whose samples sit far from their planes is reported, not hidden by the robust loss.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.bim.planes import ReferencePlane
from bimcap.labels import Label

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


class Rejection(IntEnum):
    """Why a sample got no plane."""

    NONE = 0  #: it has one
    NO_PLANE = 1  #: no plane of its kind contains its xy
    HEIGHT = 2  #: farther than the tolerance in height from every plane containing its xy
    NO_OFFSET = 3  #: its frame found no offset (none of its samples is over a plane)


@dataclass(frozen=True)
class PlaneChoiceOptions:
    """Settings of :func:`choose_planes` (module docstring).

    Attributes
    ----------
    tolerance_m: largest height difference between a sample (after its frame's tilt and offset)
        and its plane.
    unlevelled_tolerance_m: the same in a frame whose tilt could not be measured (its samples'
        heights carry the pose's tilt error).
    vote_tolerance_m: half-width of the tilt and offset votes.
    max_tilt_deg: largest tilt correction of a frame.
    max_offset_m: largest height offset of a frame (the pose's height error).
    neighbour_frames: frames either side whose offsets a frame is compared with.
    max_offset_jump_m: largest difference between a frame's offset and its neighbours' median.
    min_support: agreeing samples a frame's tilt and offset need.
    behind_weight: a hypothesis loses this many votes per sample it puts behind its plane (a
        floor sample below the floor, a ceiling sample above the ceiling).
    ransac_iterations: tilt hypotheses per frame.
    max_vote_samples: samples per frame and kind used for the votes (evenly thinned).
    max_wall_samples: wall and column samples per frame used as evidence (evenly thinned).
    frame_model: estimate each frame's tilt and offset (steps 1–2); False trusts the poses
        (tilt 0, offset 0, ``tolerance_m`` everywhere), for poses that have converged.
    edge_margin_m: a plane is a candidate for samples within this of its outline (its polygon
        leaves out the footprints of the walls standing on it).
    seed: RANSAC seed.
    """

    tolerance_m: float = 0.12
    unlevelled_tolerance_m: float = 0.25
    vote_tolerance_m: float = 0.04
    max_tilt_deg: float = 20.0
    max_offset_m: float = 1.5
    neighbour_frames: int = 3
    max_offset_jump_m: float = 0.3
    min_support: int = 10
    behind_weight: float = 2.0
    ransac_iterations: int = 96
    max_vote_samples: int = 300
    max_wall_samples: int = 150
    frame_model: bool = True
    edge_margin_m: float = 0.1
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class PlaneChoice:
    """The plane of each sample of one kind.

    Attributes
    ----------
    plane: (M,) int32 index into the reference's planes, −1 = none.
    rejection: (M,) uint8 :class:`Rejection`.
    height_error_m: (M,) sample height (after the offset) minus its plane's height; NaN if none.
    """

    plane: I32
    rejection: NDArray[np.uint8]
    height_error_m: F64

    def counts(self) -> dict[str, int]:
        """Samples kept and dropped, by reason."""
        return {
            "samples": len(self.plane),
            "assigned": int((self.plane >= 0).sum()),
            "no_plane": int((self.rejection == Rejection.NO_PLANE).sum()),
            "rejected_height": int((self.rejection == Rejection.HEIGHT).sum()),
            "no_offset": int((self.rejection == Rejection.NO_OFFSET).sum()),
        }


@dataclass
class PlaneChoiceResult:
    """:func:`choose_planes` for every kind, with what was decided per frame.

    Attributes
    ----------
    choices: per kind (Label.FLOOR, Label.CEILING) a :class:`PlaneChoice`.
    frame_offset_m: (N,) height offset of each frame (NaN: no sample over a plane).
    frame_tilt: (N, 2) tilt gradient g of each frame (metres per metre; 0 where not measured).
    tilt_measured: (N,) True where the tilt came from the frame's samples.
    """

    choices: dict[Label, PlaneChoice]
    frame_offset_m: F64
    frame_tilt: F64
    tilt_measured: NDArray[np.bool_]

    def to_dict(self) -> dict[str, Any]:
        off = self.frame_offset_m[np.isfinite(self.frame_offset_m)]
        tilt = np.degrees(np.arctan(np.linalg.norm(self.frame_tilt[self.tilt_measured], axis=1)))
        return {
            **{k.name.lower(): c.counts() for k, c in self.choices.items()},
            "frames_tilt_measured": int(self.tilt_measured.sum()),
            "frame_tilt_deg": {
                "median": float(np.median(tilt)) if len(tilt) else None,
                "max": float(tilt.max()) if len(tilt) else None,
            },
            "frame_offset_m": {
                "median_abs": float(np.median(np.abs(off))) if len(off) else None,
                "max_abs": float(np.abs(off).max()) if len(off) else None,
            },
        }


def _fit_tilt(e: F64, u: F64, sample: NDArray[np.int64], side: F64, h_pair: F64,
              walls: tuple[F64, F64], rng: np.random.Generator, opts: PlaneChoiceOptions,
              a_window: tuple[float, float] | None = None) -> tuple[float, F64, int]:
    """RANSAC of ``e ≈ a + g·u`` over the (sample, plane) pairs of one frame.

    Parameters
    ----------
    e: (P,) height of the pair's sample above the pair's plane; u: (P, 2) the sample's xy
    relative to the camera; sample: (P,) sample id of each pair (sorted); side: (P,) +1 for a
    floor sample, −1 for a ceiling sample (the side of its plane the room is on); h_pair: (P,)
    the pair's plane height; walls: the frame's wall / column samples, heights (W,) and xy
    relative to the camera (W, 2): they stand on the floor and end at the ceiling.
    a_window: (lo, hi) bounds of the offset ``a`` (default ``±max_offset_m``).

    Returns
    -------
    (a, g (2,), support): the model and how many distinct samples agree with it.
    """
    p = len(e)
    starts = np.flatnonzero(np.r_[True, sample[1:] != sample[:-1]])
    g_max = np.tan(np.deg2rad(opts.max_tilt_deg))
    # hypotheses: g = 0 through single pairs, and planes through three pairs
    singles = rng.integers(0, p, size=min(p, opts.ransac_iterations // 3))
    hyp = [np.column_stack([e[singles], np.zeros((len(singles), 2))])]
    owner = [singles]  # the pair whose plane a hypothesis puts the frame's floor (ceiling) on
    tri = rng.integers(0, p, size=(opts.ransac_iterations, 3))
    a_mat = np.concatenate([np.ones((len(tri), 3, 1)), u[tri]], axis=2)
    det = np.linalg.det(a_mat)
    good = np.abs(det) > 0.05  # the three samples span some area (m²)
    if good.any():
        sol = np.linalg.solve(a_mat[good], e[tri[good]][..., None])[..., 0]
        ok = np.linalg.norm(sol[:, 1:], axis=1) <= g_max
        hyp.append(sol[ok])
        owner.append(tri[good][ok, 0])
    h = np.concatenate(hyp)
    own = np.concatenate(owner)
    lo, hi = a_window if a_window is not None else (-opts.max_offset_m, opts.max_offset_m)
    keep = (h[:, 0] >= lo) & (h[:, 0] <= hi)
    h, own = h[keep], own[keep]
    if len(h) == 0:
        return 0.0, np.zeros(2), 0
    signed = e[None, :] - h[:, :1] - h[:, 1:] @ u.T
    resid = np.abs(signed)
    inl = np.logical_or.reduceat(resid <= opts.vote_tolerance_m, starts, axis=1)
    support = inl.sum(axis=1).astype(np.float64)
    # samples the hypothesis puts behind their nearest plane (a floor sample under the floor):
    # what a hypothesis that snaps a table top or a lintel onto the plane does to the real ones
    nearest = np.repeat(np.minimum.reduceat(resid, starts, axis=1),
                        np.diff(np.r_[starts, p]), axis=1)
    behind = (resid <= nearest + 1e-9) & (side[None, :] * signed < -opts.tolerance_m)
    impossible = np.logical_or.reduceat(behind, starts, axis=1).sum(axis=1)
    z_w, u_w = walls
    if len(z_w):
        # walls do not reach below the floor (above the ceiling) the hypothesis puts them on
        zc = z_w[None, :] - h[:, :1] - h[:, 1:] @ u_w.T
        impossible = impossible + (side[own][:, None] * (zc - h_pair[own][:, None])
                                   < -opts.tolerance_m).sum(axis=1)
    # the prior: large corrections need more agreement (a catch-all plane a storey away, e.g. a
    # floor guessed over a whole storey, contains a few more samples than the real one)
    size = np.abs(h[:, 0]) + 3.0 * np.linalg.norm(h[:, 1:], axis=1)
    raw = support - opts.behind_weight * impossible
    score = np.where(raw > 0, raw * (1.0 - size / (2.0 * opts.max_offset_m)), raw)
    best = int(np.argmax(score - 1e-6 * size))
    model = h[best]
    # least squares on the inliers (the closest pair per sample), a light ridge on g
    for _ in range(2):
        r = np.abs(e - model[0] - u @ model[1:])
        ok = r <= opts.vote_tolerance_m
        if ok.sum() < 3:
            break
        x = np.column_stack([np.ones(ok.sum()), u[ok]])
        lhs = x.T @ x + np.diag([0.0, 1e-2, 1e-2]) * ok.sum()
        model = np.linalg.solve(lhs, x.T @ e[ok])
        model[0] = np.clip(model[0], lo, hi)
        if np.linalg.norm(model[1:]) > g_max:
            model[1:] *= g_max / np.linalg.norm(model[1:])
    r = np.abs(e - model[0] - u @ model[1:])
    support_final = int(np.logical_or.reduceat(r <= opts.vote_tolerance_m, starts).sum())
    return float(model[0]), np.asarray(model[1:], np.float64), support_final


def _candidates(planes: list[ReferencePlane], plane_array: F64, kind: Label,
                p_in_world: F64, margin: float = 0.0
                ) -> tuple[NDArray[np.int64], NDArray[np.int64], F64]:
    """Every (sample, plane) pair with the plane of ``kind`` containing the sample's xy (or
    within ``margin`` metres of its outline): sample indices, plane indices and the plane's
    height at the sample's xy (vertical)."""
    import shapely

    si, qi, hz = [], [], []
    for q, pl in enumerate(planes):
        if pl.kind != kind:
            continue
        shp = pl.shape()
        xmin, ymin, xmax, ymax = (np.asarray(shp.bounds)
                                  + np.array([-margin, -margin, margin, margin]))
        cand = np.flatnonzero((p_in_world[:, 0] >= xmin) & (p_in_world[:, 0] <= xmax)
                              & (p_in_world[:, 1] >= ymin) & (p_in_world[:, 1] <= ymax))
        if len(cand) == 0:
            continue
        inside = shapely.contains_xy(shp, p_in_world[cand, 0], p_in_world[cand, 1])
        if margin > 0.0 and not inside.all():
            # within the margin of the outline: a sample at the foot of a wall, whose footprint
            # the floor plane leaves out, still stands on that floor
            grown = shp.buffer(margin, join_style="mitre")
            out = ~inside
            inside[out] = shapely.contains_xy(grown, p_in_world[cand[out], 0],
                                              p_in_world[cand[out], 1])
        cand = cand[inside]
        if len(cand) == 0:
            continue
        n, d = plane_array[q, :3], plane_array[q, 3]
        h = -(p_in_world[cand, :2] @ n[:2] + d) / n[2]
        si.append(cand)
        qi.append(np.full(len(cand), q))
        hz.append(h)
    if not si:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(si), np.concatenate(qi), np.concatenate(hz)


@dataclass
class _VotePairs:
    """The (sample, plane) pairs of every frame, sorted by (frame, sample key).

    key: (P,) sample id (unique over kinds); e: (P,) height of the sample above the plane, m;
    u: (P, 2) sample xy relative to the camera, m; side: (P,) +1 floor, −1 ceiling;
    h: (P,) plane height at the sample, m; cut: (N+1,) start of each frame's pairs.
    """

    key: NDArray[np.int64]
    e: F64
    u: F64
    side: F64
    h: F64
    cut: NDArray[np.int64]


@dataclass
class _WallEvidence:
    """Thinned wall / column samples sorted by frame: z (W,) m, u (W, 2) xy relative to the
    camera in m, cut (N+1,) start of each frame's samples."""

    z: F64
    u: F64
    cut: NDArray[np.int64]


@dataclass
class _KindSamples:
    """The floor / ceiling samples in the world: per kind, frame (M,), p_in_world (M, 3) m and
    the candidate pairs of :func:`_candidates` (sample, plane, plane height)."""

    kinds: list[Label]
    frames: dict[Label, NDArray[np.int64]]
    p_world: dict[Label, F64]
    cands: dict[Label, tuple[NDArray[np.int64], NDArray[np.int64], F64]]


@dataclass
class _FrameModel:
    """Per frame: tilt (N, 2) m/m, offset (N,) m (NaN: not fitted), support (N,) samples."""

    tilt: F64
    offset: F64
    support: NDArray[np.int64]


def _world_samples(planes: list[ReferencePlane], plane_array: F64,
                   samples: dict[Label, tuple[NDArray[np.integer], F64]], poses: F64,
                   opts: PlaneChoiceOptions) -> _KindSamples:
    """Floor / ceiling samples mapped to the world at ``poses`` (N, 7), with their candidates."""
    from bimcap.geometry.poses import transform_points

    n = len(poses)
    kinds: list[Label] = [k for k in (Label.FLOOR, Label.CEILING) if k in samples]
    frames: dict[Label, NDArray[np.int64]] = {
        k: np.asarray(samples[k][0], np.int64).reshape(-1) for k in kinds}
    p_cam = {k: np.asarray(samples[k][1], np.float64).reshape(-1, 3) for k in kinds}
    for k in kinds:
        if len(frames[k]) and (frames[k].min() < 0 or frames[k].max() >= n):
            raise ValueError(f"{k.name.lower()} sample frames outside 0..{n - 1}")
    p_world: dict[Label, F64] = {k: transform_points(poses[frames[k]], p_cam[k]) if len(frames[k])
                                 else np.zeros((0, 3)) for k in kinds}
    cands = {k: _candidates(planes, plane_array, k, p_world[k], opts.edge_margin_m)
             for k in kinds}
    return _KindSamples(kinds=kinds, frames=frames, p_world=p_world, cands=cands)


def _vote_pairs(ks: _KindSamples, poses: F64, opts: PlaneChoiceOptions) -> _VotePairs:
    """Every (sample, plane) pair of both kinds, each frame's samples evenly thinned."""
    n = len(poses)
    fr, key, ee, uu, sd, hh = [], [], [], [], [], []
    base = 0
    for k in ks.kinds:
        si, _, hz = ks.cands[k]
        frames, p_world = ks.frames[k], ks.p_world[k]
        f_of = frames[si]
        # thin each frame's samples evenly for the votes
        counts = np.bincount(frames, minlength=n)
        every = np.maximum(1, counts // max(opts.max_vote_samples, 1))
        keep = (si % every[f_of]) == 0
        fr.append(f_of[keep])
        key.append(si[keep] + base)
        ee.append(p_world[si[keep], 2] - hz[keep])
        uu.append(p_world[si[keep], :2] - poses[f_of[keep], :2])
        sd.append(np.full(int(keep.sum()), 1.0 if k == Label.FLOOR else -1.0))
        hh.append(hz[keep])
        base += len(frames)
    fr_a, key_a = np.concatenate(fr), np.concatenate(key)
    e_a, u_a, side_a = np.concatenate(ee), np.concatenate(uu), np.concatenate(sd)
    h_a = np.concatenate(hh)
    order = np.lexsort((key_a, fr_a))
    return _VotePairs(key=key_a[order], e=e_a[order], u=u_a[order], side=side_a[order],
                      h=h_a[order], cut=np.searchsorted(fr_a[order], np.arange(n + 1)))


def _wall_evidence(samples: dict[Label, tuple[NDArray[np.integer], F64]], poses: F64,
                   opts: PlaneChoiceOptions) -> _WallEvidence:
    """Wall and column samples, evenly thinned per frame: evidence of where floor and ceiling
    are."""
    from bimcap.geometry.poses import transform_points

    n = len(poses)
    wf, wp = [], []
    for k in (Label.WALL, Label.COLUMN):
        if k in samples and len(samples[k][0]):
            wf.append(np.asarray(samples[k][0], np.int64).reshape(-1))
            wp.append(np.asarray(samples[k][1], np.float64).reshape(-1, 3))
    if wf:
        w_frame, w_cam = np.concatenate(wf), np.concatenate(wp)
        counts = np.bincount(w_frame, minlength=n)
        every = np.maximum(1, counts // max(opts.max_wall_samples, 1))
        keep = (np.arange(len(w_frame)) % every[w_frame]) == 0
        w_frame, w_cam = w_frame[keep], w_cam[keep]
        o = np.argsort(w_frame, kind="stable")
        w_frame, w_world = w_frame[o], transform_points(poses[w_frame[o]], w_cam[o])
        wall_z, wall_u = w_world[:, 2], w_world[:, :2] - poses[w_frame, :2]
    else:
        w_frame, wall_z, wall_u = np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2))
    return _WallEvidence(z=wall_z, u=wall_u, cut=np.searchsorted(w_frame, np.arange(n + 1)))


def _fit_frame(f: int, pairs: _VotePairs, walls: _WallEvidence, model: _FrameModel,
               rng: np.random.Generator, opts: PlaneChoiceOptions,
               window: tuple[float, float] | None = None) -> None:
    """Fit frame ``f``'s tilt and offset (:func:`_fit_tilt`) into ``model``, in place."""
    s0, s1 = pairs.cut[f], pairs.cut[f + 1]
    w0, w1 = walls.cut[f], walls.cut[f + 1]
    a, g, sup = _fit_tilt(pairs.e[s0:s1], pairs.u[s0:s1], pairs.key[s0:s1], pairs.side[s0:s1],
                          pairs.h[s0:s1], (walls.z[w0:w1], walls.u[w0:w1]), rng, opts, window)
    # the model says e = a + g·u; the offset that brings the samples onto it is -a
    model.tilt[f], model.offset[f], model.support[f] = g, -a, sup


def _neighbour_offsets(offset: F64, strong: NDArray[np.bool_], k: int) -> F64:
    """(N,) median offset of each frame's strong neighbours (``k`` either side); NaN if none."""
    n = len(offset)
    ref_off = np.full(n, np.nan)
    for f in range(n):
        nb = [j for j in range(max(0, f - k), min(n, f + k + 1)) if j != f and strong[j]]
        if nb:
            ref_off[f] = float(np.median(offset[nb]))
    return ref_off


def _fit_frames(pairs: _VotePairs, walls: _WallEvidence,
                opts: PlaneChoiceOptions) -> tuple[_FrameModel, NDArray[np.bool_]]:
    """Steps 1 and 2: each frame's tilt and offset, held near its neighbours'; also (N,) True
    where the tilt was measured (the strict tolerance applies)."""
    n = len(pairs.cut) - 1
    rng = np.random.default_rng(opts.seed)
    model = _FrameModel(tilt=np.zeros((n, 2)), offset=np.full(n, np.nan),
                        support=np.zeros(n, np.int64))
    cut = pairs.cut
    # 1. tilt and offset per frame against the BIM
    for f in range(n):
        if opts.frame_model and cut[f + 1] - cut[f] >= 3:
            _fit_frame(f, pairs, walls, model, rng, opts)
    # 2. neighbours: a frame's offset stays near theirs; weak frames take theirs
    strong = model.support >= opts.min_support
    ref_off = _neighbour_offsets(model.offset, strong, opts.neighbour_frames)
    jump = opts.max_offset_jump_m
    for f in np.flatnonzero(strong & np.isfinite(ref_off)):
        if abs(model.offset[f] - ref_off[f]) > jump:
            _fit_frame(int(f), pairs, walls, model, rng, opts,
                       (-ref_off[f] - jump, -ref_off[f] + jump))
            strong[f] = model.support[f] >= opts.min_support
    weak = ~strong & (cut[1:] > cut[:-1])
    model.tilt[weak] = 0.0
    model.offset[weak] = np.where(np.isfinite(ref_off[weak]), ref_off[weak], 0.0)
    measured = strong
    if not opts.frame_model:
        measured = cut[1:] > cut[:-1]  # the poses are trusted: the strict tolerance everywhere
    return model, measured


def _assign_kind(ks: _KindSamples, kind: Label, poses: F64, model: _FrameModel,
                 measured: NDArray[np.bool_], opts: PlaneChoiceOptions) -> PlaneChoice:
    """Step 3 for one kind: the nearest candidate after tilt and offset, within the tolerance."""
    frames, p_world = ks.frames[kind], ks.p_world[kind]
    m = len(frames)
    plane = np.full(m, -1, np.int32)
    rej = np.full(m, Rejection.NO_PLANE, np.uint8)
    err = np.full(m, np.nan)
    si, qi, hz = ks.cands[kind]
    if len(si):
        f_of = frames[si]
        u = p_world[si, :2] - poses[f_of, :2]
        e = (p_world[si, 2] - hz - np.einsum("ij,ij->i", u, model.tilt[f_of])
             + model.offset[f_of])
        has_offset = np.isfinite(e)
        rej[si[~has_offset]] = Rejection.NO_OFFSET
        si, qi, e = si[has_offset], qi[has_offset], e[has_offset]
        # the candidate of smallest |e| per sample: sort by (sample, |e|), keep the first
        o = np.lexsort((np.abs(e), si))
        si, qi, e = si[o], qi[o], e[o]
        first = np.ones(len(si), bool)
        first[1:] = si[1:] != si[:-1]
        si, qi, e = si[first], qi[first], e[first]
        err[si] = e
        tol = np.where(measured[frames[si]], opts.tolerance_m, opts.unlevelled_tolerance_m)
        ok = np.abs(e) <= tol
        plane[si[ok]] = qi[ok].astype(np.int32)
        rej[si[ok]] = Rejection.NONE
        rej[si[~ok]] = Rejection.HEIGHT
    return PlaneChoice(plane=plane, rejection=rej, height_error_m=err)


def choose_planes(
    planes: list[ReferencePlane],
    plane_array: F64,
    samples: dict[Label, tuple[NDArray[np.integer], F64]],
    world_from_cam: F64,
    options: PlaneChoiceOptions | None = None,
) -> PlaneChoiceResult:
    """The plane of every floor / ceiling sample (module docstring).

    Parameters
    ----------
    planes: the reference planes (polygons); plane_array: (Q, 4) their ``[nx, ny, nz, d]``.
    samples: per kind (Label.FLOOR, Label.CEILING) ``(frame (M,) int, p_in_cam (M, 3) m)``;
        Label.WALL / Label.COLUMN entries, if given, are evidence only: a hypothesis that puts
        the frame's walls below its floor or above its ceiling loses their votes.
    world_from_cam: (N, 7) TUM-order poses the samples are seen from (e.g. the initial ones).
    options: see :class:`PlaneChoiceOptions`.

    Returns
    -------
    :class:`PlaneChoiceResult`; ``choices[kind].plane`` is aligned with ``samples[kind]``.
    """
    opts = options or PlaneChoiceOptions()
    poses = np.asarray(world_from_cam, np.float64).reshape(-1, 7)
    ks = _world_samples(planes, plane_array, samples, poses, opts)
    pairs = _vote_pairs(ks, poses, opts)
    walls = _wall_evidence(samples, poses, opts)
    model, measured = _fit_frames(pairs, walls, opts)
    choices = {k: _assign_kind(ks, k, poses, model, measured, opts) for k in ks.kinds}
    return PlaneChoiceResult(choices=choices, frame_offset_m=model.offset,
                             frame_tilt=model.tilt, tilt_measured=measured)


@dataclass
class PlaneTermCheck:
    """How well one plane term's samples sit on their planes after a solve.

    Attributes
    ----------
    term: ``"F"`` or ``"Ce"``.
    samples: samples in the term. median_abs_m, p90_abs_m: of |signed distance| to their plane.
    far: samples farther than ``far_m`` from their plane.
    limit_m: the median |distance| above which the term, or one of its planes, fails.
    far_m: the distance counted as far.
    failed_planes: planes holding at least ``min_plane_share`` of the term's samples (and at
        least ``min_plane_samples``) whose median |distance| exceeds ``limit_m``.
    failed: the term's median exceeds ``limit_m``, or some plane failed.
    worst_planes: up to 5 planes with the largest median |distance|: index, samples, median.
    """

    term: str
    samples: int
    median_abs_m: float | None
    p90_abs_m: float | None
    far: int
    limit_m: float
    far_m: float
    failed_planes: list[int]
    failed: bool
    worst_planes: list[dict[str, Any]]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def message(self) -> str:
        if self.median_abs_m is None:
            return f"{self.term}: no samples"
        state = "FAILED" if self.failed else "ok"
        text = (f"{self.term} plane check {state}: median |residual| "
                f"{100 * self.median_abs_m:.1f} cm (limit {100 * self.limit_m:.0f} cm), "
                f"{self.far}/{self.samples} samples beyond {100 * self.far_m:.0f} cm")
        for w in self.worst_planes:
            if w["plane"] in self.failed_planes:
                text += (f"; plane {w['plane']}: median {100 * w['median_abs_m']:.1f} cm over "
                         f"{w['samples']} samples")
        return text


def plane_residual_check(
    term: str,
    frames: NDArray[np.integer],
    p_in_cam: F64,
    plane_index: NDArray[np.integer],
    plane_array: F64,
    world_from_cam: F64,
    limit_m: float = 0.05,
    far_m: float = 0.15,
    min_plane_share: float = 0.05,
    min_plane_samples: int = 20,
) -> PlaneTermCheck:
    """Signed distances of a plane term's samples to their planes at ``world_from_cam``.

    Parameters
    ----------
    term: name for the report (``"F"``, ``"Ce"``).
    frames: (M,) frame per sample; p_in_cam: (M, 3) metres; plane_index: (M,) into
    plane_array (Q, 4). world_from_cam: (N, 7) TUM-order poses (e.g. the refined ones).
    limit_m: the term, or a plane with enough of its samples, fails when its median |distance|
        exceeds this (a whole room's floor on the wrong plane is a failure even when the rest
        of the term is right).
    far_m: distance from which a sample counts as far.
    min_plane_share, min_plane_samples: what "enough samples" means for a plane.
    """
    from bimcap.geometry.poses import transform_points

    frames = np.asarray(frames, np.int64).reshape(-1)
    idx = np.asarray(plane_index, np.int64).reshape(-1)
    if len(frames) == 0:
        return PlaneTermCheck(term, 0, None, None, 0, limit_m, far_m, [], False, [])
    p = transform_points(np.asarray(world_from_cam)[frames], np.asarray(p_in_cam, np.float64))
    pl = np.asarray(plane_array, np.float64)[idx]
    r = np.abs(np.einsum("ij,ij->i", p, pl[:, :3]) + pl[:, 3])
    med = float(np.median(r))
    per_plane = []
    failed_planes = []
    enough = max(min_plane_samples, min_plane_share * len(r))
    for q in np.unique(idx):
        rq = r[idx == q]
        per_plane.append({"plane": int(q), "samples": len(rq),
                          "median_abs_m": float(np.median(rq))})
        if len(rq) >= enough and per_plane[-1]["median_abs_m"] > limit_m:
            failed_planes.append(int(q))
    per_plane.sort(key=lambda d: -d["median_abs_m"])
    return PlaneTermCheck(term, len(r), med, float(np.percentile(r, 90)),
                          int((r > far_m).sum()), limit_m, far_m, failed_planes,
                          med > limit_m or bool(failed_planes), per_plane[:5])
