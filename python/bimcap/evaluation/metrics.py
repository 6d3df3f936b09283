"""Trajectory metrics: ATE (position, rotation) and yaw/pitch/roll RMSE.

Conventions
-----------
- Poses are ``world_from_cam`` in TUM order ``[tx, ty, tz, qx, qy, qz, qw]``, shape (N, 7).
- ATE_pos: per-frame error ``||t_est - t_gt||`` in metres (evo ``APE`` ``trans_part``).
- ATE_rot: per-frame angle of ``R_gtᵀ R_est`` (the same angle as ``R_estᵀ R_gt``) in degrees, as
  the norm of scipy's rotation vector (evo ``APE`` ``angle_deg``).
- Yaw/pitch/roll: the error rotation ``E = R_est R_gtᵀ`` split with scipy
  ``as_euler('ZYX')`` (intrinsic z-y'-x''), RMSE per angle in degrees; see :data:`YPR_CONVENTION`.
- Alignment: none by default (the BIM frame is shared); SE(3)/Sim(3) Umeyama of the estimate onto
  the ground truth as evo ``-a`` / ``-as`` does it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from bimcap.evaluation.alignment import Similarity, umeyama_alignment
from bimcap.evaluation.errors import EvaluationError
from bimcap.geometry.trajectory import Trajectory, validate_poses

F64 = NDArray[np.float64]

YPR_CONVENTION = "E = R_est R_gt^T, scipy as_euler('ZYX') (intrinsic z-y'-x''): yaw, pitch, roll"

#: Default timestamp tolerance of the association, seconds (evo's ``--t_max_diff`` default).
DEFAULT_MAX_DT = 0.01


class AlignMode(str, enum.Enum):
    """How the estimate is aligned to the ground truth before measuring."""

    NONE = "none"
    SE3 = "se3"
    SIM3 = "sim3"


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of one per-frame error, as evo prints them (same unit as the errors)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float

    @classmethod
    def of(cls, errors: ArrayLike) -> ErrorStats:
        """Statistics of a non-empty (N,) array of errors."""
        e = np.asarray(errors, dtype=np.float64).reshape(-1)
        if e.size == 0:
            raise EvaluationError("no errors to summarise")
        return cls(
            rmse=float(np.sqrt(np.mean(e**2))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
        )

    def to_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ("rmse", "mean", "median", "std", "min", "max")}


@dataclass(frozen=True)
class FrameErrors:
    """Per-frame errors (what Fig. 5 plots).

    Attributes
    ----------
    timestamps: (N,) seconds of the matched frames (ground-truth clock).
    trans_m: (N,) ``||t_est - t_gt||`` metres.
    rot_deg: (N,) rotation angle of ``R_estᵀ R_gt``, degrees.
    ypr_deg: (N, 3) yaw, pitch, roll of ``E = R_est R_gtᵀ`` (``as_euler('ZYX')``), degrees.
    """

    timestamps: F64
    trans_m: F64
    rot_deg: F64
    ypr_deg: F64


@dataclass(frozen=True)
class TrajectoryMetrics:
    """ATE and yaw/pitch/roll RMSE of one estimate against the ground truth."""

    ate_pos_m: ErrorStats
    ate_rot_deg: ErrorStats
    yaw_rmse_deg: float
    pitch_rmse_deg: float
    roll_rmse_deg: float
    align: AlignMode
    n_matched: int
    n_est: int
    n_gt: int
    max_dt_s: float
    alignment: Similarity | None = None
    ypr_convention: str = YPR_CONVENTION
    frame_errors: FrameErrors | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, object]:
        """JSON-ready dictionary (per-frame errors left out)."""
        return {
            "ate_pos_m": self.ate_pos_m.to_dict(),
            "ate_rot_deg": self.ate_rot_deg.to_dict(),
            "yaw_rmse_deg": self.yaw_rmse_deg,
            "pitch_rmse_deg": self.pitch_rmse_deg,
            "roll_rmse_deg": self.roll_rmse_deg,
            "ypr_convention": self.ypr_convention,
            "align": self.align.value,
            "alignment": None if self.alignment is None else self.alignment.to_dict(),
            "n_matched": self.n_matched,
            "n_est": self.n_est,
            "n_gt": self.n_gt,
            "max_dt_s": self.max_dt_s,
        }

    def format_table(self) -> str:
        """A plain-text table for the terminal."""
        p, r = self.ate_pos_m, self.ate_rot_deg
        lines = [
            (
                f"trajectory: {self.n_matched} matched poses (est {self.n_est}, gt {self.n_gt}, "
                f"|dt| <= {self.max_dt_s:g} s), alignment: {self.align.value}"
            ),
            f"{'metric':<18}{'rmse':>12}{'mean':>12}{'median':>12}{'max':>12}",
            f"{'ATE_pos [m]':<18}{p.rmse:>12.4f}{p.mean:>12.4f}{p.median:>12.4f}{p.max:>12.4f}",
            f"{'ATE_rot [deg]':<18}{r.rmse:>12.4f}{r.mean:>12.4f}{r.median:>12.4f}{r.max:>12.4f}",
            f"{'yaw RMSE [deg]':<18}{self.yaw_rmse_deg:>12.4f}",
            f"{'pitch RMSE [deg]':<18}{self.pitch_rmse_deg:>12.4f}",
            f"{'roll RMSE [deg]':<18}{self.roll_rmse_deg:>12.4f}",
            f"yaw/pitch/roll convention: {self.ypr_convention}",
        ]
        if self.alignment is not None:
            lines.append(f"alignment scale: {self.alignment.scale:.6f}")
        return "\n".join(lines)


def associate(
    est_timestamps: ArrayLike,
    gt_timestamps: ArrayLike,
    max_dt: float = DEFAULT_MAX_DT,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Match poses by timestamp like evo's ``sync.associate_trajectories``.

    Each stamp of the shorter trajectory (the estimate on a tie) is matched to the nearest stamp
    of the other one if ``|dt| <= max_dt``; exact matches therefore always pair up.

    Parameters
    ----------
    est_timestamps: (N,) seconds, increasing.
    gt_timestamps: (M,) seconds, increasing.
    max_dt: tolerance in seconds (>= 0).

    Returns
    -------
    (K,) indices into the estimate and (K,) indices into the ground truth.

    Raises
    ------
    EvaluationError
        If nothing matches within ``max_dt``.
    """
    t_est = np.asarray(est_timestamps, dtype=np.float64).reshape(-1)
    t_gt = np.asarray(gt_timestamps, dtype=np.float64).reshape(-1)
    if max_dt < 0 or not np.isfinite(max_dt):
        raise EvaluationError(f"max_dt must be a finite non-negative number, got {max_dt}")
    swap = len(t_est) > len(t_gt)
    first, second = (t_gt, t_est) if swap else (t_est, t_gt)
    if len(first) == 0 or len(second) == 0:
        raise EvaluationError("cannot associate an empty trajectory")
    hi = np.clip(np.searchsorted(second, first), 1, len(second) - 1) if len(second) > 1 else None
    if hi is None:
        nearest = np.zeros(len(first), dtype=np.int64)
    else:
        lo = hi - 1
        nearest = np.where(np.abs(second[lo] - first) <= np.abs(second[hi] - first), lo, hi)
    ok = np.abs(second[nearest] - first) <= max_dt
    idx_first = np.flatnonzero(ok).astype(np.int64)
    idx_second = nearest[ok].astype(np.int64)
    if idx_first.size == 0:
        raise EvaluationError(
            f"no timestamps match within {max_dt:g} s (estimate {t_est[0]:.6f}..{t_est[-1]:.6f}, "
            f"ground truth {t_gt[0]:.6f}..{t_gt[-1]:.6f}); check the clocks or raise the tolerance"
        )
    return (idx_second, idx_first) if swap else (idx_first, idx_second)


def frame_errors(
    est_world_from_cam: ArrayLike, gt_world_from_cam: ArrayLike
) -> tuple[F64, F64, F64]:
    """Per-frame errors of matched poses (no alignment).

    Parameters
    ----------
    est_world_from_cam, gt_world_from_cam: (N, 7) TUM-order poses, metres.

    Returns
    -------
    trans_m (N,) metres, rot_deg (N,) degrees (angle of ``R_gtᵀ R_est``), ypr_deg (N, 3) degrees
    (yaw, pitch, roll of ``E = R_est R_gtᵀ`` with ``as_euler('ZYX')``).
    """
    est = np.atleast_2d(np.asarray(est_world_from_cam, dtype=np.float64))
    gt = np.atleast_2d(np.asarray(gt_world_from_cam, dtype=np.float64))
    if est.shape != gt.shape:
        raise EvaluationError(f"pose arrays differ in shape: {est.shape} vs {gt.shape}")
    validate_poses(est, field="estimate")
    validate_poses(gt, field="ground truth")
    trans = np.linalg.norm(est[:, :3] - gt[:, :3], axis=1)
    r_est = Rotation.from_quat(est[:, 3:7]).as_matrix()
    r_gt = Rotation.from_quat(gt[:, 3:7]).as_matrix()
    rel = np.transpose(r_gt, (0, 2, 1)) @ r_est  # evo: inv(ref) @ est
    rot = np.rad2deg(np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1))
    e = r_est @ np.transpose(r_gt, (0, 2, 1))
    ypr = Rotation.from_matrix(e).as_euler("ZYX", degrees=True)
    return trans, rot, ypr


def trajectory_metrics(
    est_world_from_cam: ArrayLike,
    gt_world_from_cam: ArrayLike,
    align: AlignMode | str = AlignMode.NONE,
    timestamps: ArrayLike | None = None,
) -> TrajectoryMetrics:
    """ATE and yaw/pitch/roll RMSE of already-matched poses.

    Parameters
    ----------
    est_world_from_cam, gt_world_from_cam: (N, 7) TUM-order poses, row i of one matches row i of
        the other; metres.
    align: :class:`AlignMode`; the estimate is aligned onto the ground truth with evo's Umeyama.
    timestamps: optional (N,) seconds kept with the per-frame errors.
    """
    mode = AlignMode(align)
    est = np.atleast_2d(np.asarray(est_world_from_cam, dtype=np.float64))
    gt = np.atleast_2d(np.asarray(gt_world_from_cam, dtype=np.float64))
    if est.shape != gt.shape or est.ndim != 2 or est.shape[1] != 7 or len(est) == 0:
        raise EvaluationError(f"need two matching (N, 7) pose arrays, got {est.shape}, {gt.shape}")
    sim = None
    if mode is not AlignMode.NONE:
        sim = umeyama_alignment(est[:, :3], gt[:, :3], with_scale=mode is AlignMode.SIM3)
        est = sim.apply_poses(est)
    trans, rot, ypr = frame_errors(est, gt)
    ts = (
        np.arange(len(est), dtype=np.float64)
        if timestamps is None
        else np.asarray(timestamps, dtype=np.float64)
    )
    ypr_rmse = np.sqrt(np.mean(ypr**2, axis=0))
    return TrajectoryMetrics(
        ate_pos_m=ErrorStats.of(trans),
        ate_rot_deg=ErrorStats.of(rot),
        yaw_rmse_deg=float(ypr_rmse[0]),
        pitch_rmse_deg=float(ypr_rmse[1]),
        roll_rmse_deg=float(ypr_rmse[2]),
        align=mode,
        n_matched=len(est),
        n_est=len(est),
        n_gt=len(gt),
        max_dt_s=0.0,
        alignment=sim,
        frame_errors=FrameErrors(ts, trans, rot, ypr),
    )


def evaluate_trajectory(
    est: Trajectory,
    gt: Trajectory,
    align: AlignMode | str = AlignMode.NONE,
    max_dt: float = DEFAULT_MAX_DT,
) -> TrajectoryMetrics:
    """Associate ``est`` and ``gt`` by timestamp (within ``max_dt`` seconds) and measure.

    Raises
    ------
    EvaluationError
        If no timestamps match, or alignment is impossible (fewer than 3 non-collinear poses).
    """
    i_est, i_gt = associate(est.timestamps, gt.timestamps, max_dt)
    m = trajectory_metrics(est.poses[i_est], gt.poses[i_gt], align, gt.timestamps[i_gt])
    return TrajectoryMetrics(
        ate_pos_m=m.ate_pos_m,
        ate_rot_deg=m.ate_rot_deg,
        yaw_rmse_deg=m.yaw_rmse_deg,
        pitch_rmse_deg=m.pitch_rmse_deg,
        roll_rmse_deg=m.roll_rmse_deg,
        align=m.align,
        n_matched=len(i_est),
        n_est=len(est),
        n_gt=len(gt),
        max_dt_s=float(max_dt),
        alignment=m.alignment,
        frame_errors=m.frame_errors,
    )
