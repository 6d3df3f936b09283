"""Frames the bundle adjustment left inconsistent with their neighbours, re-placed from them.

The G term's robust loss makes the bundle adjustment ignore matches whose reprojection errors
are far out in its tail. A frame that starts several degrees off and that the BIM terms cannot
place (it sees one wall from half a metre, its labels are wrong) therefore keeps its error: all
its matches are outliers from the start. Its neighbours, placed by the BIM, know where it is:
their keypoints, back-projected with their depth, are 3-D points the frame's own keypoints see.
:func:`repair_inconsistent_frames` finds the frames whose matches disagree with their
neighbours (median reprojection error above ``max_median_px``), and re-places each from the
points of its consistent neighbours by PnP inside RANSAC (OpenCV's ``solvePnPRansac``, iterative
refinement on the inliers). Frames are repaired one after the other, so a run of bad frames is
repaired from its ends inwards. The caller solves again from the repaired poses, and keeps that
solve only when no repaired frame agrees less with the BIM than before (:func:`bim_agreement`):
a frame whose matches are a repeated texture's look-alikes is "inconsistent" though the BIM
holds it right, and PnP on those matches puts it where the texture repeats.

Arrays follow docs/architecture.md: poses ``(N, 7)`` TUM order ``world_from_cam``; matches in
undistorted pinhole pixels of one camera ``[fx, fy, cx, cy]``.
"""

from __future__ import annotations

import enum
import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.poses import invert, matrix_to_pose, pose_to_matrix, transform_points

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]


@dataclass(frozen=True)
class RepairOptions:
    """Settings of :func:`repair_inconsistent_frames`.

    Attributes
    ----------
    max_median_px: a frame whose matches' median reprojection error (both directions, under the
        current poses) exceeds this is inconsistent.
    min_matches: a frame needs this many matches with depth to be judged, and PnP this many
        correspondences from consistent neighbours.
    ransac_px: RANSAC inlier threshold (pixels).
    min_inliers, min_inlier_ratio: a PnP pose is used only with this many inliers and this
        share of the correspondences.
    ransac_iterations: RANSAC iterations; seed: its seed.
    """

    max_median_px: float = 10.0
    min_matches: int = 8
    ransac_px: float = 4.0
    min_inliers: int = 8
    min_inlier_ratio: float = 0.4
    ransac_iterations: int = 300
    seed: int = 0


@dataclass
class RepairResult:
    """What :func:`repair_inconsistent_frames` did.

    Attributes
    ----------
    poses: (N, 7) the poses with the repaired frames re-placed.
    median_px: (N,) each frame's median reprojection error before (NaN: too few matches).
    inconsistent: frames judged inconsistent; repaired: those re-placed by PnP.
    inliers: (frame → PnP inliers) of the repaired frames.
    """

    poses: F64
    median_px: F64
    inconsistent: list[int] = field(default_factory=list)
    repaired: list[int] = field(default_factory=list)
    inliers: dict[int, int] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"inconsistent": self.inconsistent, "repaired": self.repaired,
                "inliers": {str(k): v for k, v in self.inliers.items()},
                "median_px": [None if not np.isfinite(v) else float(v) for v in self.median_px]}


def _directed(match_frames: I32, match_uv: F64, match_depth: F64) -> tuple[I32, I32, F64, F64, F64]:
    """Both directions of every match with a source depth: (src, dst, uv_src, depth_src, uv_dst)."""
    fa, fb = match_frames[:, 0], match_frames[:, 1]
    src = np.concatenate([fa, fb])
    dst = np.concatenate([fb, fa])
    uv_src = np.concatenate([match_uv[:, :2], match_uv[:, 2:]])
    uv_dst = np.concatenate([match_uv[:, 2:], match_uv[:, :2]])
    depth = np.concatenate([match_depth[:, 0], match_depth[:, 1]])
    ok = depth > 0
    return src[ok], dst[ok], uv_src[ok], depth[ok], uv_dst[ok]


def _backproject(k: F64, uv: F64, depth: F64) -> F64:
    return np.column_stack([(uv[:, 0] - k[2]) / k[0] * depth, (uv[:, 1] - k[3]) / k[1] * depth,
                            depth])


def reprojection_errors(poses: F64, match_frames: I32, match_uv: F64, match_depth: F64,
                        intrinsics: F64) -> tuple[I32, I32, F64]:
    """Each match's reprojection error under ``poses``, both directions: a keypoint with depth
    back-projected in its frame and projected into the other frame.

    Parameters
    ----------
    poses: (N, 7) ``world_from_cam``. match_frames: (M, 2) frame pairs. match_uv: (M, 4)
        ``u_a v_a u_b v_b`` undistorted pixels. match_depth: (M, 2) metres, 0 = unknown.
    intrinsics: (4,) ``fx fy cx cy`` of the pinhole camera.

    Returns
    -------
    src, dst: (K,) the frames of each directed observation (K ≤ 2M: only keypoints with depth).
    err: (K,) pixels; 1e6 where the point falls behind the other camera.
    """
    src, dst, uv_src, depth, uv_dst = _directed(match_frames, match_uv, match_depth)
    if len(src) == 0:
        return src, dst, np.zeros(0)
    p_world = transform_points(poses[src], _backproject(intrinsics, uv_src, depth))
    p_dst = transform_points(invert(poses[dst]), p_world)
    front = p_dst[:, 2] > 1e-6
    z = np.where(front, p_dst[:, 2], 1.0)
    proj = np.column_stack([intrinsics[0] * p_dst[:, 0] / z + intrinsics[2],
                            intrinsics[1] * p_dst[:, 1] / z + intrinsics[3]])
    return src, dst, np.where(front, np.linalg.norm(proj - uv_dst, axis=1), 1e6)


def reprojection_medians(poses: F64, match_frames: I32, match_uv: F64, match_depth: F64,
                         intrinsics: F64, min_matches: int = 8) -> F64:
    """(N,) each frame's median reprojection error (pixels) over its matches, both directions,
    under ``poses``; NaN where it has fewer than ``min_matches``."""
    n = len(poses)
    src, dst, err = reprojection_errors(poses, match_frames, match_uv, match_depth, intrinsics)
    out = np.full(n, np.nan)
    for f in range(n):
        e = err[(src == f) | (dst == f)]
        if len(e) >= min_matches:
            out[f] = float(np.median(e))
    return out


def repair_inconsistent_frames(poses: F64, match_frames: I32, match_uv: F64, match_depth: F64,
                               intrinsics: F64,
                               options: RepairOptions | None = None) -> RepairResult:
    """Re-place the frames whose matches disagree with their neighbours (module docstring).

    Parameters
    ----------
    poses: (N, 7) current world_from_cam, TUM order.
    match_frames, match_uv, match_depth: (M, 2) i32, (M, 4), (M, 2) the G term's matches
        (depth <= 0: unknown).
    intrinsics: (4,) ``fx fy cx cy`` of the undistorted pinhole camera of the matches.
    options: :class:`RepairOptions`.

    Returns
    -------
    :class:`RepairResult`; frames that cannot be repaired keep their pose.
    """
    import cv2

    opt = options or RepairOptions()
    k = np.asarray(intrinsics, np.float64)
    out = np.array(poses, np.float64, copy=True)
    medians = reprojection_medians(out, match_frames, match_uv, match_depth, k, opt.min_matches)
    bad = {int(f) for f in np.flatnonzero(medians > opt.max_median_px)}
    result = RepairResult(out, medians, sorted(bad))
    if not bad:
        return result
    src, dst, uv_src, depth, uv_dst = _directed(np.asarray(match_frames), np.asarray(match_uv),
                                                np.asarray(match_depth))
    cv2.setRNGSeed(opt.seed)
    pending = set(bad)
    progress = True
    while pending and progress:
        progress = False
        # the frame with the most correspondences from consistent frames first
        counts = {f: int(((dst == f) & ~np.isin(src, list(pending))).sum()) for f in pending}
        for f in sorted(pending, key=lambda g: -counts[g]):
            sel = (dst == f) & ~np.isin(src, list(pending))
            if sel.sum() < opt.min_matches:
                continue
            placed, n_inl = _pnp(out, f, src[sel], uv_src[sel], depth[sel], uv_dst[sel], k, opt)
            if placed is None:
                continue
            out[f] = placed
            pending.discard(f)
            result.repaired.append(f)
            result.inliers[f] = n_inl
            progress = True
            break  # recount: this frame now helps its neighbours
    result.repaired.sort()
    result.poses = out
    return result


def _pnp(poses: F64, f: int, src: I32, uv_src: F64, depth: F64, uv_dst: F64, k: F64,
         opt: RepairOptions) -> tuple[F64 | None, int]:
    """Frame ``f``'s pose (7,) from the keypoints of frames ``src`` (placed at ``poses``,
    back-projected at ``uv_src`` with ``depth``) seen at ``uv_dst`` in ``f``: PnP inside RANSAC
    (:class:`RepairOptions`). Returns the pose (None: too few inliers) and the inlier count."""
    import cv2

    p_world = transform_points(poses[src], _backproject(k, uv_src, depth)).astype(np.float64)
    cam_k = np.array([[k[0], 0.0, k[2]], [0.0, k[1], k[3]], [0.0, 0.0, 1.0]])
    # PnP in a frame centred on the points: far from the origin (a georeferenced model) its
    # linear start is ill-conditioned (3.5° off at a 5.4e6 m northing)
    centre = p_world.mean(axis=0)
    cam_from_world = pose_to_matrix(invert(poses[f]))
    rvec, _ = cv2.Rodrigues(cam_from_world[:3, :3])
    t_guess = cam_from_world[:3, 3] + cam_from_world[:3, :3] @ centre
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        p_world - centre, uv_dst.astype(np.float64), cam_k, None,
        rvec=rvec, tvec=t_guess.reshape(3, 1).copy(),
        useExtrinsicGuess=False, iterationsCount=opt.ransac_iterations,
        reprojectionError=opt.ransac_px, confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE)
    n_inl = 0 if inl is None else len(inl)
    if not ok or n_inl < opt.min_inliers or n_inl < opt.min_inlier_ratio * len(src):
        return None, n_inl
    rot, _ = cv2.Rodrigues(rvec)
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = tvec.ravel() - rot @ centre  # cam_from_world from cam_from_centred
    return matrix_to_pose(np.linalg.inv(m)), n_inl


def bim_agreement(arrays: dict[str, Any], poses: F64, frames: list[int],
                  tol_m: float = 0.05) -> F64:
    """How well each of ``frames`` agrees with the BIM at ``poses``: the share of its wall and
    column samples within ``tol_m`` (in plan) of a segment of their class, and of its floor and
    ceiling samples within ``tol_m`` of their plane.

    Unlike the solve's cost, this does not improve when a frame moves where the association gate
    drops its samples: a sample nothing explains counts against the frame.

    Parameters
    ----------
    arrays: a problem's arrays (``bimcap.optimize.Problem.arrays()``).
    poses: (N, 7) ``world_from_cam``, TUM order. frames: the frames to judge.
    tol_m: metres.

    Returns
    -------
    (len(frames),) shares in [0, 1]; NaN for a frame without BIM samples.
    """
    from bimcap.registration.icp import point_segment_distance

    out = np.full(len(frames), np.nan)
    seg, seg_class = np.asarray(arrays["segments"]), np.asarray(arrays["segment_class"])
    planes = np.asarray(arrays["planes"]).reshape(-1, 4)
    for i, f in enumerate(frames):
        near = total = 0
        for term, label in (("wall", 1), ("column", 4)):
            sel = np.asarray(arrays[f"{term}_frame"]) == f
            segs = seg[seg_class == label]
            if not sel.any() or not len(segs):
                continue
            p_world = transform_points(np.repeat(poses[f][None], int(sel.sum()), 0),
                                       np.asarray(arrays[f"{term}_p_in_cam"])[sel])
            dist, _, _ = point_segment_distance(p_world[:, :2], segs)
            near += int((dist <= tol_m).sum())
            total += len(dist)
        for term in ("floor", "ceiling"):
            sel = (np.asarray(arrays[f"{term}_frame"]) == f) & (
                np.asarray(arrays[f"{term}_plane"]) >= 0)
            if not sel.any():
                continue
            p_world = transform_points(np.repeat(poses[f][None], int(sel.sum()), 0),
                                       np.asarray(arrays[f"{term}_p_in_cam"])[sel])
            plane = planes[np.asarray(arrays[f"{term}_plane"])[sel]]
            dist = np.abs((p_world * plane[:, :3]).sum(1) + plane[:, 3])
            near += int((dist <= tol_m).sum())
            total += len(dist)
        if total:
            out[i] = near / total
    return out


@dataclass
class OdometryCheck:
    """What :func:`odometry_outliers` found.

    Attributes
    ----------
    poses: (N, 7) the poses with the outliers put where their neighbours' input motion says.
    outliers: frames further than the limits from every neighbour's prediction.
    distance_m: (frame → metres) each outlier's distance to the prediction it was given.
    angle_deg: (frame → degrees) each outlier's rotation away from that prediction.
    max_distance_m, max_angle_deg: the limits the check used.
    """

    poses: F64
    outliers: list[int] = field(default_factory=list)
    distance_m: dict[int, float] = field(default_factory=dict)
    angle_deg: dict[int, float] = field(default_factory=dict)
    max_distance_m: float = float("inf")
    max_angle_deg: float = 180.0

    def to_dict(self) -> dict[str, Any]:
        return {"outliers": self.outliers,
                "distance_m": {str(k): v for k, v in self.distance_m.items()},
                "angle_deg": {str(k): v for k, v in self.angle_deg.items()},
                "max_distance_m": self.max_distance_m, "max_angle_deg": self.max_angle_deg}


def _prediction_gaps(m_pose: F64, m_in: F64, f: int, g: int) -> tuple[F64, float, float]:
    """Frame ``f`` predicted from neighbour ``g`` (``poses[g] ∘ input[g]⁻¹ ∘ input[f]``, 4×4) and
    how far the solved pose of ``f`` is from it: metres and degrees."""
    pred = np.asarray(m_pose[g] @ np.linalg.inv(m_in[g]) @ m_in[f])
    dist = float(np.linalg.norm(pred[:3, 3] - m_pose[f][:3, 3]))
    cos = (np.trace(pred[:3, :3].T @ m_pose[f][:3, :3]) - 1.0) / 2.0
    return pred, dist, float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def odometry_limits(poses: F64, input_poses: F64, max_distance_m: float, max_angle_deg: float,
                    floor_m: float = 0.15, floor_deg: float = 3.0,
                    k: float = 8.0) -> tuple[float, float]:
    """Limits of :func:`odometry_outliers` that follow how well the input's relative motion
    agrees with the solved poses on this trajectory: each frame's smallest gap to its
    neighbours' predictions, over all frames, gives ``median + k · 1.4826 · MAD`` (metres and
    degrees), at least ``floor_m`` / ``floor_deg`` and at most ``max_distance_m`` /
    ``max_angle_deg``. A smooth drift (the input's motion right to a centimetre) flags a frame
    left 0.4 m / 10° off; a noisy SLAM input keeps the looser fixed limits.

    Parameters
    ----------
    poses, input_poses: (N, 7) solved and input ``world_from_cam``, TUM order.
    max_distance_m, max_angle_deg: the loosest limits (e.g. 3 σ of the odometry term).
    """
    n = len(poses)
    if n < 3:
        return max_distance_m, max_angle_deg
    m_pose = pose_to_matrix(np.asarray(poses, np.float64))
    m_in = pose_to_matrix(np.asarray(input_poses, np.float64))
    dist = np.empty(n)
    ang = np.empty(n)
    for f in range(n):
        gaps = [_prediction_gaps(m_pose, m_in, f, g)[1:] for g in (f - 1, f + 1) if 0 <= g < n]
        dist[f] = min(d for d, _ in gaps)
        ang[f] = min(a for _, a in gaps)

    def limit(v: F64, floor: float, cap: float) -> float:
        med = float(np.median(v))
        return float(min(cap, max(floor, med + k * 1.4826 * float(np.median(np.abs(v - med))))))

    return limit(dist, floor_m, max_distance_m), limit(ang, floor_deg, max_angle_deg)


def odometry_outliers(poses: F64, input_poses: F64, max_distance_m: float,
                      max_angle_deg: float = 180.0) -> OdometryCheck:
    """Frames the solve placed far from where their neighbours and the input's relative motion
    put them, re-placed there.

    A frame that no match links to its neighbours is placed by its BIM samples, the odometry
    and the prior alone; a scan of a few walls can fit a place one room away as well as the
    right one, and each stage's odometry keeps the relative motion of the poses it starts from,
    so a frame pulled away in one stage stays away in the next (or one that the BIM holds where
    the drift put it never moves). The input's relative motion (the SLAM's, or the drifted
    poses') is still right to a few decimetres: the prediction of frame ``f`` from neighbour
    ``g`` is ``poses[g] ∘ input[g]⁻¹ ∘ input[f]``. A frame further than ``max_distance_m`` or
    turned more than ``max_angle_deg`` from the prediction of every neighbour (both, or the one
    at an end) is an outlier; it is moved to the prediction of its nearest neighbour that is
    not one. :func:`odometry_limits` gives limits that follow the trajectory.

    Parameters
    ----------
    poses: (N, 7) solved ``world_from_cam``, TUM order. input_poses: (N, 7) the input's.
    max_distance_m: metres. max_angle_deg: degrees.

    Returns
    -------
    :class:`OdometryCheck`; frames without a trusted neighbour keep their pose.
    """
    n = len(poses)
    out = np.array(poses, np.float64, copy=True)
    m_pose = pose_to_matrix(np.asarray(poses, np.float64))
    m_in = pose_to_matrix(np.asarray(input_poses, np.float64))
    far = []
    for f in range(n):
        gaps = [_prediction_gaps(m_pose, m_in, f, g)[1:] for g in (f - 1, f + 1) if 0 <= g < n]
        if gaps and all(d > max_distance_m or a > max_angle_deg for d, a in gaps):
            far.append(f)
    result = OdometryCheck(out, max_distance_m=max_distance_m, max_angle_deg=max_angle_deg)
    for f in far:
        nbs = sorted((g for g in (f - 1, f + 1) if 0 <= g < n and g not in far),
                     key=lambda g: abs(g - f))
        if not nbs:
            continue
        pred, dist, ang = _prediction_gaps(m_pose, m_in, f, nbs[0])
        result.distance_m[f] = dist
        result.angle_deg[f] = ang
        out[f] = matrix_to_pose(pred)
        result.outliers.append(f)
    result.poses = out
    return result


def odometry_candidates(poses: F64, input_poses: F64, frames: list[int]) -> list[F64]:
    """Where the poses of ``frames`` may lie, from their neighbours and the input's relative
    motion: one ``(N, 7)`` array per candidate, ``poses`` with ``frames`` re-placed.

    For each frame, each neighbour (``f ± 1``, nearest first, those not in ``frames``) predicts
    it (:func:`odometry_outliers`); each prediction gives two candidates, its position with the
    frame's solved rotation and with its own rotation. The input's relative rotation is only as
    good as its per-frame rotation noise (the paper's drift: several degrees per frame, drawn
    independently), while a frame the BIM terms placed in an alias (the storey above, a
    look-alike room) often has the right rotation, as the walls' directions repeat:
    AC20-FZK-Haus Exp 1 frame 30 was solved on the storey above, 2.7 m off but 0.9° from the
    truth, and its neighbour's prediction 24 cm but 12.5° off, outside the basin of its own
    walls. The solved rotation comes first: where the BIM agrees as well with either (a frame
    that sees too little to tell), it is the BIM's. Candidate ``k`` holds each frame's ``k``-th
    (its last, when it has fewer); frames without a neighbour outside ``frames`` keep their
    pose.

    Parameters
    ----------
    poses: (N, 7) solved ``world_from_cam``, TUM order. input_poses: (N, 7) the input's.
    frames: the frames to re-place.
    """
    n = len(poses)
    m_pose = pose_to_matrix(np.asarray(poses, np.float64))
    m_in = pose_to_matrix(np.asarray(input_poses, np.float64))
    per_frame: dict[int, list[F64]] = {}
    for f in frames:
        nbs = sorted((g for g in (f - 1, f + 1) if 0 <= g < n and g not in frames),
                     key=lambda g: (abs(g - f), g))
        own: list[F64] = []
        for g in nbs:
            pred = matrix_to_pose(_prediction_gaps(m_pose, m_in, f, g)[0])
            turned = pred.copy()
            turned[3:] = poses[f][3:]
            own += [turned, pred]
        if own:
            per_frame[f] = own
    count = max((len(v) for v in per_frame.values()), default=0)
    out = []
    for k in range(count):
        c = np.array(poses, np.float64, copy=True)
        for f, own in per_frame.items():
            c[f] = own[min(k, len(own) - 1)]
        out.append(c)
    return out


@dataclass(frozen=True)
class MotionBreak:
    """One place where the solved trajectory leaves the input's relative motion.

    Attributes
    ----------
    frame: the break lies between ``frame`` and ``frame + 1``.
    distance_m, angle_deg: how far the solved pose of ``frame + 1`` lies from where the solved
        pose of ``frame`` and the input's relative motion put it.
    spanning_matches: matches between a frame up to ``frame`` and one after it.
    spanning_median_px: their median reprojection error (pixels, both directions, keypoints
        with depth) at the solved poses; None without any (or without the matches).
    supported: the matches say the jump is right (enough of them, within the limit): the input
        jumped there, not the solve.
    """

    frame: int
    distance_m: float
    angle_deg: float
    spanning_matches: int
    spanning_median_px: float | None
    supported: bool

    def to_dict(self) -> dict[str, Any]:
        return {"frame": self.frame, "distance_m": self.distance_m, "angle_deg": self.angle_deg,
                "spanning_matches": self.spanning_matches,
                "spanning_median_px": self.spanning_median_px, "supported": self.supported}


@dataclass
class MotionCheck:
    """What :func:`motion_check` found: the breaks of the solved trajectory from the input's
    relative motion, and the blocks of frames between them.

    Attributes
    ----------
    breaks: every break (:class:`MotionBreak`), in frame order.
    segments: ``[start, stop)`` frame ranges between the breaks (one segment: no break).
    max_distance_m, max_angle_deg: the limits used (:func:`motion_check`).
    largest_distance_m: the largest step gap over the trajectory (metres).
    """

    breaks: list[MotionBreak]
    segments: list[tuple[int, int]]
    max_distance_m: float
    max_angle_deg: float
    largest_distance_m: float

    @property
    def failed(self) -> bool:
        """A break that no match supports: a block of frames may sit in an alias."""
        return any(not b.supported for b in self.breaks)

    def message(self) -> str:
        """One line for the log."""
        if not self.breaks:
            return (f"motion check ok: every step of the refined trajectory follows the input's "
                    f"relative motion (largest gap {self.largest_distance_m:.2f} m, limits "
                    f"{self.max_distance_m:.2f} m / {self.max_angle_deg:.1f}°)")
        where = ", ".join(
            f"{b.frame}-{b.frame + 1} ({b.distance_m:.2f} m, {b.angle_deg:.1f}°, "
            + ("supported by the matches" if b.supported else
               "no match links across" if b.spanning_matches == 0 else
               f"{b.spanning_matches} matches at {b.spanning_median_px:.0f} px")
            + ")" for b in self.breaks)
        blocks = ", ".join(f"{a}-{b - 1}" for a, b in self.segments)
        head = "motion check FAILED" if self.failed else "motion check ok"
        tail = (": a block of frames may be placed in an alias (a repeated or mirrored room)"
                if self.failed else ": the input jumped there")
        return (f"{head}: the refined trajectory leaves the input's relative motion (limits "
                f"{self.max_distance_m:.2f} m / {self.max_angle_deg:.1f}°) between frames "
                f"{where}; blocks {blocks}{tail}")

    def to_dict(self) -> dict[str, Any]:
        return {"failed": self.failed, "breaks": [b.to_dict() for b in self.breaks],
                "segments": [list(s) for s in self.segments],
                "max_distance_m": self.max_distance_m, "max_angle_deg": self.max_angle_deg,
                "largest_distance_m": self.largest_distance_m}


def motion_check(poses: F64, input_poses: F64, match_frames: I32 | None = None,
                 match_uv: F64 | None = None, match_depth: F64 | None = None,
                 intrinsics: F64 | None = None, floor_m: float = 0.5, floor_deg: float = 15.0,
                 k: float = 8.0, min_matches: int = 20, max_median_px: float = 10.0
                 ) -> MotionCheck:
    """Where the solved trajectory breaks from the input's relative motion, and whether the
    matches say the break is right.

    Drift bends the input slowly, so the correction that takes the input to the solved poses
    changes little from one frame to the next: the solved pose of frame ``f + 1`` lies near its
    prediction from frame ``f`` (``poses[f] ∘ input[f]⁻¹ ∘ input[f + 1]``, as in
    :func:`odometry_outliers`). A run of frames that the solve placed somewhere else as a
    block (a stretch of the walk registered to a look-alike room, held there by the BIM and by
    its own matches) keeps that prediction inside the block and breaks it at both ends, while
    every solve converges and every frame is observed. Each gap's limit is
    ``median + k · 1.4826 · MAD`` of all steps' gaps (metres and degrees), at least ``floor_m``
    / ``floor_deg``; a step is a break when its two gaps, each as a fraction of its limit's reach
    above the median, reach 1 together (``hypot``): past either limit alone, or far out in both
    at once (gen-small-s3 hard Exp 1: frames 56-59 1.27 m / 57° off with no match across, under
    the noisy input's limits 1.56 m / 69°; robust z-scores 6.1 / 6.3, where the input's own
    steps reach 3.9 together). The matches between a frame up to ``f`` and one after it judge
    the break: at least ``min_matches`` of them with a median reprojection error up to
    ``max_median_px`` at the solved poses support it (the input jumped, the images agree with
    the solve); otherwise it is unsupported and the check fails.

    Parameters
    ----------
    poses, input_poses: (N, 7) solved and input ``world_from_cam``, TUM order.
    match_frames, match_uv, match_depth, intrinsics: the matches (see
        :func:`reprojection_errors`); None: no break is supported.
    """
    n = len(poses)
    m_pose = pose_to_matrix(np.asarray(poses, np.float64))
    m_in = pose_to_matrix(np.asarray(input_poses, np.float64))
    if n < 3:
        return MotionCheck([], [(0, n)], floor_m, floor_deg, 0.0)
    gaps = np.array([_prediction_gaps(m_pose, m_in, f + 1, f)[1:] for f in range(n - 1)])
    med = np.median(gaps, axis=0)
    mad = 1.4826 * np.median(np.abs(gaps - med), axis=0)
    max_m = float(max(floor_m, med[0] + k * mad[0]))
    max_deg = float(max(floor_deg, med[1] + k * mad[1]))
    # each gap as a fraction of its limit's reach above the median: a break on either
    # alone, or on both together (a step far out in metres and degrees at once)
    reach = np.maximum(np.array([max_m, max_deg]) - med, 1e-12)
    at = np.flatnonzero(np.hypot(*((gaps - med) / reach).T) > 1.0)
    src = dst = err = None
    if match_frames is not None and len(match_frames) and intrinsics is not None:
        src, dst, err = reprojection_errors(np.asarray(poses, np.float64),
                                            np.asarray(match_frames), np.asarray(match_uv),
                                            np.asarray(match_depth), np.asarray(intrinsics))
    breaks = []
    for f in at.tolist():
        count, median = 0, None
        if err is not None:
            mf = np.asarray(match_frames)
            count = int(((mf.min(axis=1) <= f) & (mf.max(axis=1) > f)).sum())
            across = (np.minimum(src, dst) <= f) & (np.maximum(src, dst) > f)
            median = float(np.median(err[across])) if across.any() else None
        supported = count >= min_matches and median is not None and median <= max_median_px
        breaks.append(MotionBreak(frame=int(f), distance_m=float(gaps[f, 0]),
                                  angle_deg=float(gaps[f, 1]), spanning_matches=count,
                                  spanning_median_px=median, supported=supported))
    cuts = [0, *[b.frame + 1 for b in breaks], n]
    segments = list(itertools.pairwise(cuts))
    return MotionCheck(breaks, segments, max_m, max_deg, float(gaps[:, 0].max()))


def unlinked_blocks(match_frames: I32 | None, n: int, min_frames: int = 2) -> list[tuple[int, int]]:
    """Runs of frames that no match links to a frame outside them: ``[start, stop)`` ranges of
    ``n`` frames with no match between a frame inside and one outside, at least ``min_frames``
    long, the longest such run (the rest of the walk, the first on a tie) left out.

    Only the BIM and the input's relative motion place such a block relative to the others; a
    solve that puts it in the wrong place converges, and where its rotation stays near the
    input's the motion check cannot tell (gen-small-s3 hard Exp 1 with OpenCV's SIFT: frames
    56-59, matched only among themselves, 0.6-0.9 m off, their largest step gap 0.74 m under the
    check's 1.52 m).

    Parameters
    ----------
    match_frames: (M, 2) the frame pairs of the verified matches (None: no match).
    n: the number of frames. min_frames: the shortest block returned.
    """
    if n <= 0:
        return []
    spans = np.zeros(n + 1, np.int64)  # spans[c]: matches between a frame < c and one >= c
    if match_frames is not None and len(match_frames):
        mf = np.asarray(match_frames, np.int64)
        lo, hi = mf.min(axis=1), mf.max(axis=1)
        np.add.at(spans, lo[lo < hi] + 1, 1)
        np.add.at(spans, hi[lo < hi] + 1, -1)
        spans = np.cumsum(spans)
    cuts = [0, *(np.flatnonzero(spans[1:n] == 0) + 1).tolist(), n]
    runs = list(itertools.pairwise(cuts))
    rest = max(runs, key=lambda r: r[1] - r[0])
    return [r for r in runs if r is not rest and r[1] - r[0] >= min_frames]


class BlockMoveSource(enum.Enum):
    """What placed a moved block (:class:`BlockMove`): PnP on the ``matches`` across its
    break, or, with no usable match across, the input's relative ``motion`` from the frame
    across the break."""

    MATCHES = "matches"
    MOTION = "motion"


@dataclass(frozen=True)
class BlockMove:
    """One block of frames :func:`block_moves` moved rigidly.

    Attributes
    ----------
    start, stop: the block's frames ``[start, stop)``.
    frame: the block's frame whose new pose gave the correction (PnP on the outside frames'
        points, or its prediction from its neighbour across the break).
    matches, inliers: that PnP's correspondences and RANSAC inliers (0 by ``MOTION``).
    distance_m, angle_deg: the size of the rigid correction (at that frame).
    source: :class:`BlockMoveSource`.
    """

    start: int
    stop: int
    frame: int
    matches: int
    inliers: int
    distance_m: float
    angle_deg: float
    source: BlockMoveSource = BlockMoveSource.MATCHES

    def to_dict(self) -> dict[str, Any]:
        return {"start": self.start, "stop": self.stop, "frame": self.frame,
                "source": self.source.value,
                "matches": self.matches, "inliers": self.inliers,
                "distance_m": self.distance_m, "angle_deg": self.angle_deg}


@dataclass
class BlockRepair:
    """What :func:`block_moves` did: ``poses`` (N, 7) with the moved blocks moved, ``check``
    the motion check before, and the moves (:class:`BlockMove`, in the order made)."""

    poses: F64
    check: MotionCheck
    moves: list[BlockMove] = field(default_factory=list)

    @property
    def moved(self) -> list[int]:
        """The moved frames, sorted."""
        return sorted(f for m in self.moves for f in range(m.start, m.stop))

    def to_dict(self) -> dict[str, Any]:
        return {"check": self.check.to_dict(), "moves": [m.to_dict() for m in self.moves],
                "moved": self.moved}


def block_moves(poses: F64, input_poses: F64, match_frames: I32, match_uv: F64,
                match_depth: F64, intrinsics: F64, min_inliers: int = 20, max_moves: int = 4,
                options: RepairOptions | None = None, use_matches: bool = True) -> BlockRepair:
    """Blocks of frames that :func:`motion_check` finds broken off the others, moved rigidly
    back onto them by the matches across the break.

    A block placed in a look-alike of its true place (gen-small-s19 Exp 1: frames 0-13 solved
    1.3 m along the corridor, the BIM agreeing everywhere there) is held there by its own
    matches and the BIM, while the robust G term gives up the matches that link it to the rest
    (152 matches at 225 px). Frame by frame nothing is wrong (each frame agrees with its
    neighbours), so :func:`repair_inconsistent_frames` and the odometry repair leave it.

    The segments of the motion check joined by supported breaks form groups. The smallest
    group (never the largest) is moved by one rigid correction: its frame with the most matches
    with the frames outside it is re-placed from their points by PnP (:func:`_pnp`, RANSAC, at
    least ``min_inliers`` inliers), and the whole group follows it (``world_from_cam ← C ·
    world_from_cam``, ``C`` that frame's new pose times its old one's inverse). Then the check
    runs again on the moved poses, up to ``max_moves`` moves, each group at most once: a break
    that was only the other side of a moved block is gone then (gen-small-s52 Exp 1: frames
    24-30 sat 2.3 m off between two placed stretches, and frame 23's matches with 25-27 are a
    repeated texture's look-alikes, wrong at the true poses). A group that cannot be placed so
    (too few matches across, PnP failed) is moved by the input's relative motion from its
    neighbour across the break instead (:func:`_block_prediction`, rotations kept). The caller
    solves again and lets the BIM judge.

    Parameters
    ----------
    poses, input_poses: (N, 7) the solved and the input ``world_from_cam``, TUM order.
    match_frames, match_uv, match_depth, intrinsics: the matches (:func:`reprojection_errors`).
    min_inliers: PnP inliers a group's correction needs. max_moves: at most this many moves.
    options: the PnP's :class:`RepairOptions`.
    use_matches: False: every group moves by the input's relative motion
        (:func:`_block_prediction`), for the caller's second try when the matches' move was
        refused (gen-demo-s41 hard Exp 2: the 39 matches across the break of frames 17-18 are
        look-alikes whose PnP turns the block 49° away; the input's motion puts it back).

    Returns
    -------
    :class:`BlockRepair` (``check``: the motion check of ``poses``).
    """
    import cv2

    out = np.array(poses, np.float64, copy=True)
    mf = None if match_frames is None else np.asarray(match_frames)
    check = motion_check(out, input_poses, mf, match_uv, match_depth, intrinsics)
    result = BlockRepair(out, check)
    if not check.failed or mf is None or not len(mf):
        return result
    opt = options or RepairOptions()
    k = np.asarray(intrinsics, np.float64)
    muv, mdepth = np.asarray(match_uv, np.float64), np.asarray(match_depth, np.float64)
    directed = _directed(mf, muv, mdepth)
    cv2.setRNGSeed(opt.seed)
    tried: set[tuple[int, int]] = set()
    for _ in range(max_moves):
        if not check.failed:
            break
        groups: list[list[int]] = [list(check.segments[0])]
        for brk, seg in zip(check.breaks, check.segments[1:], strict=True):
            if brk.supported:
                groups[-1][1] = seg[1]
            else:
                groups.append(list(seg))
        anchor = max(groups, key=lambda g: g[1] - g[0])
        candidates = sorted((g for g in groups if g is not anchor), key=lambda g: g[1] - g[0])
        move = None
        for start, stop in candidates:
            if (start, stop) in tried:
                continue
            tried.add((start, stop))
            move = None
            if use_matches:
                move = _block_correction(out, start, stop, mf, muv, mdepth, k, directed,
                                         min_inliers, opt)
            if move is None:
                move = _block_prediction(out, np.asarray(input_poses, np.float64), start, stop)
            if move is not None:
                break
        if move is None:
            break
        block, corrected = move
        out = corrected
        result.moves.append(block)
        check = motion_check(out, input_poses, mf, muv, mdepth, k)
    result.poses = out
    return result


def _block_correction(poses: F64, start: int, stop: int, match_frames: I32, match_uv: F64,
                      match_depth: F64, k: F64, directed: tuple[Any, ...], min_inliers: int,
                      opt: RepairOptions, max_tries: int = 3) -> tuple[BlockMove, F64] | None:
    """The rigid correction of frames ``[start, stop)`` onto the frames outside them
    (:func:`block_moves`): up to ``max_tries`` of the block's frames with the most matches from
    outside (at least ``min_inliers``) are each re-placed by PnP, the whole block follows each,
    and the correction under which the most of the block's matches with the outside reproject
    within ``opt.ransac_px`` (both directions) is kept: a frame whose matches across are a
    repeated texture's look-alikes moves the block where the texture repeats, which the rest of
    its matches across deny. Returns the move and the poses (N, 7) after it, or None."""
    src, dst, uv_src, depth, uv_dst = directed
    inside_dst = (dst >= start) & (dst < stop)
    outside = ((src < start) | (src >= stop)) & inside_dst
    counts = np.bincount(dst[outside] - start, minlength=stop - start)
    inside = (match_frames >= start) & (match_frames < stop)
    across = inside[:, 0] != inside[:, 1]
    best: tuple[int, BlockMove, F64] | None = None
    for f in (start + np.argsort(-counts, kind="stable")[:max_tries]).tolist():
        sel = outside & (dst == f)
        if sel.sum() < min_inliers:
            break
        new, n_inl = _pnp(poses, f, src[sel], uv_src[sel], depth[sel], uv_dst[sel], k, opt)
        if new is None or n_inl < min_inliers:
            continue
        correction = pose_to_matrix(new) @ np.linalg.inv(pose_to_matrix(poses[f]))
        moved = np.array(poses, copy=True)
        moved[start:stop] = matrix_to_pose(correction[None] @ pose_to_matrix(poses[start:stop]))
        _, _, err = reprojection_errors(moved, match_frames[across], match_uv[across],
                                        match_depth[across], k)
        agree = int((err < opt.ransac_px).sum())
        if best is not None and agree <= best[0]:
            continue
        angle = float(np.degrees(np.arccos(np.clip((np.trace(correction[:3, :3]) - 1.0) / 2.0,
                                                   -1.0, 1.0))))
        block = BlockMove(start, stop, int(f), int(sel.sum()), n_inl,
                          float(np.linalg.norm(new[:3] - poses[f, :3])), angle)
        best = (agree, block, moved)
    return None if best is None else (best[1], best[2])


def _block_prediction(poses: F64, input_poses: F64, start: int, stop: int,
                      turn_deg: float = 45.0) -> tuple[BlockMove, F64] | None:
    """Frames ``[start, stop)`` that no usable match links to the rest, moved by one
    translation: their end frame next to the break (the first, or the last when the block
    starts the walk) to where the input's relative motion from its neighbour across the break
    puts it (as :func:`odometry_outliers`: ``poses[g] ∘ input[g]⁻¹ ∘ input[f]``), every
    rotation kept. A block solved on a look-alike storey or room keeps its rotation right; the
    input's rotation between two frames is good to the drift's per-frame rotation only
    (gen-twostorey-s90 Exp 1: frames 57-59 solved 3.1 m up on the storey above, 0.2° from the
    truth, 19° from the input's relative rotation), so only the prediction's position is used.
    A block whose correction turns it more than ``turn_deg`` is not trusted inside either: each
    of its frames goes to its own prediction from the neighbour across the break
    (``poses[g] ∘ input[g]⁻¹ ∘ input[f]``; gen-small-s3 hard Exp 1: frames 56-59 57° off and
    bent, 57-59 a further 0.8 m / 20° from 56, which one rigid correction left off);
    ``turn_deg = 0`` sends every frame of a block to its own prediction.
    Returns the move and the poses (N, 7) after it, or None (the block is the whole walk)."""
    n = len(poses)
    if start > 0:
        f, g = start, start - 1
    elif stop < n:
        f, g = stop - 1, stop
    else:
        return None
    m_pose = pose_to_matrix(poses)
    m_in = pose_to_matrix(input_poses)
    predicted = m_pose[g] @ np.linalg.inv(m_in[g]) @ m_in[f]
    correction = predicted @ np.linalg.inv(m_pose[f])
    angle = float(np.degrees(np.arccos(np.clip((np.trace(correction[:3, :3]) - 1.0) / 2.0,
                                               -1.0, 1.0))))
    moved = np.array(poses, copy=True)
    if angle > turn_deg:  # turned away from its place: each frame to its own prediction
        moved[start:stop] = matrix_to_pose(
            m_pose[g] @ np.linalg.inv(m_in[g]) @ m_in[start:stop])
    else:
        moved[start:stop, :3] += predicted[:3, 3] - poses[f, :3]
        angle = 0.0
    block = BlockMove(start, stop, f, 0, 0, float(np.linalg.norm(predicted[:3, 3] - poses[f, :3])),
                      angle, BlockMoveSource.MOTION)
    return block, moved
