"""Pairs of frames whose matches contradict the chain of consecutive frames between them.

A texture that repeats (the same wall finish, tiles, panels) makes SIFT match two views of
*different* pieces of it. Where each view is one plane, the two-view verification cannot tell:
a plane maps onto the copy of its texture by a homography as well as onto itself, so COLMAP
keeps the wrong matches as a ``PLANAR`` pair, and they agree with each other. Such a pair then
asks the solve for a relative pose metres or a wall's turn away from the truth, with more
matches than the right pairs around it (gen-small-s3, hard setting: frames 19–21 look at one
wall, 22–26 at the wall beside it, with the same finish; pairs 19-22 … 22-26 match the two
walls, 2–4 m and 80–105° off, and pull frames 24–26 by 25 cm / 17° from the ground truth).

The check: each pair's relative pose ``cam_b_from_cam_a`` by PnP (the matches' points in
camera a from their depth, their pixels in b). A pair of frames ``i < j`` more than one frame
apart is dropped when the composition of the consecutive pairs ``(i, i+1) … (j-1, j)`` moves
its matches' points (from their depth in i) to more than ``max_median_px`` (median) from their
matched pixels in j. Consecutive frames see the most of the same surface, so their pairs are the
ones least often fooled. The test is in pixels, not on the poses: on a plane seen through a
narrow view, a translation along the plane and a turn are nearly the same image motion, so PnP
poses of right pairs differ by tens of centimetres and degrees (8 cm range noise) while their
pixels agree. On gen-small-s3 (hard) the chain predicts every right pair's matches within
17 px (median) and every copied pair's 230–4600 px off, as far as the ground truth does. A
pair with no chain of posed consecutive pairs is kept (nothing to compare with).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import NDArray

from bimcap.features.matching import PairMatches
from bimcap.geometry.camera import Camera

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class PairChainOptions:
    """Settings of :func:`chain_inconsistent_pairs`.

    Attributes
    ----------
    max_median_px: a pair is dropped when the chain's pose puts its matches (median) more than
        this many pixels from where they were matched.
    min_matches: a pair needs this many matches with depth in both frames, and as many PnP
        inliers, to get a pose.
    reprojection_px: PnP RANSAC inlier threshold (pixels).
    """

    max_median_px: float = 100.0
    min_matches: int = 8
    reprojection_px: float = 3.0

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass
class PairChainCheck:
    """What :func:`chain_inconsistent_pairs` found.

    Attributes
    ----------
    dropped: the pairs ``(frame_a, frame_b)`` to drop.
    median_px: per dropped pair, the median pixel error of its matches under the chain's pose.
    posed: how many pairs got a PnP pose.
    """

    dropped: list[tuple[int, int]] = field(default_factory=list)
    median_px: list[float] = field(default_factory=list)
    posed: int = 0

    def to_dict(self) -> dict[str, object]:
        return {"dropped": [list(p) for p in self.dropped],
                "median_px": list(self.median_px), "posed": self.posed}


def pair_pose(uv_a: F64, depth_a: F64, uv_b: F64, camera: Camera,
              options: PairChainOptions | None = None) -> F64 | None:
    """``cam_b_from_cam_a`` (4, 4) of one pair by PnP RANSAC, then refined on its inliers.

    Parameters
    ----------
    uv_a, uv_b: (M, 2) undistorted pixels of the matches in frames a and b.
    depth_a: (M,) z-depth of the matches in frame a (metres; <= 0 none).
    camera: the pinhole camera of both frames.

    Returns None when fewer than ``options.min_matches`` matches have depth or are inliers.
    """
    import cv2

    opts = options or PairChainOptions()
    ok = np.asarray(depth_a) > 0
    if int(ok.sum()) < max(opts.min_matches, 6):
        return None
    p_in_a = camera.backproject(np.asarray(uv_a, np.float64)[ok],
                                np.asarray(depth_a, np.float64)[ok], distorted=False)
    px_b = np.ascontiguousarray(np.asarray(uv_b, np.float64)[ok])
    k = np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        np.ascontiguousarray(p_in_a), px_b, k, None, iterationsCount=200,
        reprojectionError=opts.reprojection_px, flags=cv2.SOLVEPNP_EPNP)
    if not found or inliers is None or len(inliers) < opts.min_matches:
        return None
    sel = inliers.ravel()
    found, rvec, tvec = cv2.solvePnP(p_in_a[sel], px_b[sel], k, None, rvec, tvec, True,
                                     cv2.SOLVEPNP_ITERATIVE)
    if not found:
        return None
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvec)[0]
    out[:3, 3] = np.asarray(tvec).ravel()
    return out


def reprojection_px(b_from_a: F64, uv_a: F64, depth_a: F64, uv_b: F64, camera: Camera) -> F64:
    """(M,) pixel distance in b between ``uv_b`` and the matches' points (``uv_a`` at
    ``depth_a`` in a, metres) moved by ``b_from_a`` (4, 4); inf where a point has no depth or
    lands behind b."""
    ok = np.asarray(depth_a) > 0
    out = np.full(len(ok), np.inf)
    p_in_a = camera.backproject(np.asarray(uv_a, np.float64)[ok],
                                np.asarray(depth_a, np.float64)[ok], distorted=False)
    p_in_b = p_in_a @ b_from_a[:3, :3].T + b_from_a[:3, 3]
    z = p_in_b[:, 2]
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    px = np.column_stack([camera.fx * p_in_b[:, 0] / zs + camera.cx,
                          camera.fy * p_in_b[:, 1] / zs + camera.cy])
    err = np.linalg.norm(px - np.asarray(uv_b, np.float64)[ok], axis=1)
    out[ok] = np.where(front, err, np.inf)
    return out


def chain_inconsistent_pairs(pairs: Sequence[PairMatches], keypoints_uv: Sequence[F64],
                             keypoints_depth: Sequence[F64], camera: Camera,
                             options: PairChainOptions | None = None) -> PairChainCheck:
    """The pairs whose relative pose contradicts the chain of consecutive pairs (module doc).

    Parameters
    ----------
    pairs: verified matches (``frame_a < frame_b``).
    keypoints_uv: per frame (Ni, 2) undistorted pixels.
    keypoints_depth: per frame (Ni,) metres, 0 = none.
    camera: the pinhole camera.
    """
    opts = options or PairChainOptions()
    poses: dict[tuple[int, int], F64] = {}
    by_frames = {(p.frame_a, p.frame_b): p for p in pairs}
    for p in pairs:
        if len(p.idx) < opts.min_matches:
            continue
        ia, ib = p.idx[:, 0], p.idx[:, 1]
        pose = pair_pose(keypoints_uv[p.frame_a][ia], keypoints_depth[p.frame_a][ia],
                         keypoints_uv[p.frame_b][ib], camera, opts)
        if pose is not None:
            poses[(p.frame_a, p.frame_b)] = pose
    check = PairChainCheck(posed=len(poses))
    for a, b in sorted(poses):
        if b - a < 2 or not all((k, k + 1) in poses for k in range(a, b)):
            continue
        chain = np.eye(4)
        for k in range(a, b):
            chain = poses[(k, k + 1)] @ chain
        p = by_frames[(a, b)]
        ia, ib = p.idx[:, 0], p.idx[:, 1]
        err = reprojection_px(chain, keypoints_uv[a][ia], keypoints_depth[a][ia],
                              keypoints_uv[b][ib], camera)
        median = float(np.median(err[np.isfinite(err)])) if np.isfinite(err).any() else 0.0
        if median > opts.max_median_px:
            check.dropped.append((a, b))
            check.median_px.append(round(median, 1))
    return check
