"""The drift generator: synthetic "SLAM output" made from ground-truth poses.

Two models (:class:`DriftModel`), both seeded:

``PAPER`` — the BIMCaP paper's model (Sec. "Synthetic pose calculation"). For frames
i = 1 … N::

    ΔT_1 ~ N(0, σ_t² I),   ΔT_{i+1} ~ N(ΔT_i, σ_t² I)          (3-D random walk, metres)
    Δφ_i ~ N(0, σ_p²),     Δψ_i ~ N(0, σ_y²)                   (independent per frame, degrees)
    t_init,i = t_gt,i + ΔT_i
    R_init,i = Rz(Δψ_i) · R_gt,i · Rx(Δφ_i)

``Rz`` turns about the world's vertical axis (gravity-aligned yaw, applied on the world side);
``Rx`` turns about the camera's x axis (OpenCV optical frame: x right, so this is pitch, applied
on the camera side). The camera centre is not moved by the rotation offsets. The walk is 3-D by
default — z drifts too, as the paper's ΔT is an unrestricted translation and the floor/ceiling
terms exist to correct height — set ``drift_z=False`` for a planar walk.

``SLAM_LIKE`` — smooth odometry-like drift. Increments are correlated (AR(1) with coefficient
``smoothing``, marginal standard deviations σ_t, σ_p, σ_y) and *accumulated* into yaw, pitch and
position offsets, and the yaw offset bends the path as odometry does::

    ψ_i = Σ_{k<=i} δψ_k,   φ_i = Σ_{k<=i} δφ_k,   e_i = Σ_{k<=i} δt_k
    t_init,1 = t_gt,1 + e_1
    t_init,i = t_init,i-1 + Rz(ψ_i)(t_gt,i − t_gt,i-1) + δt_i
    R_init,i = Rz(ψ_i) · R_gt,i · Rx(φ_i)

Calibration (presets). A preset fixes the *shape* (nominal σs) and a *target* ATE. After
sampling with the nominal σs, the rotation offsets (angles) are multiplied by a factor
``scale_rot`` found by a 1-D root search so that ATE_rot equals the target exactly, then the
translation increments by ``scale_t`` so that ATE_pos equals its target (in PAPER mode ATE_pos
is linear in ``scale_t``; in SLAM_LIKE mode it also depends on the yaw bending, hence the root
search). The effective σs are the nominal ones times the scales; both are reported. Because a
random walk's magnitude grows with the number of frames, the scales absorb the sequence length:
any sequence gets the paper's magnitudes. Without targets the scales are 1 and the σs are exact.

ATE here is the plain RMSE without alignment: ATE_pos = sqrt(mean ‖t_init − t_gt‖²)
in metres, ATE_rot = sqrt(mean θ²) in degrees with θ the angle of R_initᵀ R_gt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from bimcap.errors import InputError
from bimcap.geometry.trajectory import Trajectory

F64 = NDArray[np.float64]


class DriftError(InputError):
    """Drift parameters that cannot be used, or targets that cannot be reached."""


class DriftModel(str, Enum):
    """How offsets evolve along the trajectory (see the module docstring)."""

    PAPER = "paper"
    SLAM_LIKE = "slam_like"


@dataclass(frozen=True)
class DriftParams:
    """Parameters of one drift draw.

    Attributes
    ----------
    sigma_t: standard deviation of one translation random-walk step, metres (per axis).
    sigma_pitch_deg: standard deviation of the pitch offset (PAPER) or step (SLAM_LIKE), degrees.
    sigma_yaw_deg: likewise for yaw, degrees.
    seed: seed of the random generator.
    mode: the drift model.
    drift_z: whether the translation walk includes the vertical axis.
    smoothing: AR(1) correlation of consecutive increments in SLAM_LIKE mode, in [0, 1).
    target_ate_pos_m: if set, rescale the translation offsets so that ATE_pos equals this.
    target_ate_rot_deg: if set, rescale the rotation offsets so that ATE_rot equals this.
    preset: name of the preset these came from, if any (informational).
    """

    sigma_t: float = 0.0
    sigma_pitch_deg: float = 0.0
    sigma_yaw_deg: float = 0.0
    seed: int = 0
    mode: DriftModel = DriftModel.PAPER
    drift_z: bool = True
    smoothing: float = 0.9
    target_ate_pos_m: float | None = None
    target_ate_rot_deg: float | None = None
    preset: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", DriftModel(self.mode))
        for name in ("sigma_t", "sigma_pitch_deg", "sigma_yaw_deg"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0:
                raise DriftError(f"must be finite and >= 0, got {v!r}", field=name)
        if not 0.0 <= self.smoothing < 1.0:
            raise DriftError(f"must be in [0, 1), got {self.smoothing!r}", field="smoothing")
        for name in ("target_ate_pos_m", "target_ate_rot_deg"):
            v = getattr(self, name)
            if v is not None and (not math.isfinite(v) or v < 0):
                raise DriftError(f"must be finite and >= 0, got {v!r}", field=name)
        if self.target_ate_pos_m and self.sigma_t == 0:
            raise DriftError("a positive translation target needs sigma_t > 0", field="sigma_t")
        if self.target_ate_rot_deg and self.sigma_pitch_deg == 0 and self.sigma_yaw_deg == 0:
            raise DriftError(
                "a positive rotation target needs sigma_pitch_deg or sigma_yaw_deg > 0",
                field="sigma_pitch_deg",
            )
        if self.target_ate_rot_deg is not None and self.target_ate_rot_deg >= 90.0:
            raise DriftError(
                "rotation targets must be below 90 degrees", field="target_ate_rot_deg"
            )

    @classmethod
    def from_preset(cls, name: str, seed: int = 0, **overrides: Any) -> DriftParams:
        """The parameters of preset ``name`` (``exp1``, ``exp2``, ``exp3``) with ``seed``."""
        if name not in PRESETS:
            raise DriftError(
                f"unknown preset {name!r}; choose one of {sorted(PRESETS)}", field="preset"
            )
        p = PRESETS[name]
        kwargs: dict[str, Any] = {
            "sigma_t": p.sigma_t,
            "sigma_pitch_deg": p.sigma_pitch_deg,
            "sigma_yaw_deg": p.sigma_yaw_deg,
            "seed": seed,
            "mode": DriftModel.PAPER,
            "target_ate_pos_m": p.target_ate_pos_m,
            "target_ate_rot_deg": p.target_ate_rot_deg,
            "preset": name,
        }
        kwargs.update(overrides)
        return cls(**kwargs)

    def to_dict(self) -> dict[str, Any]:
        return {
            "sigma_t": self.sigma_t,
            "sigma_pitch_deg": self.sigma_pitch_deg,
            "sigma_yaw_deg": self.sigma_yaw_deg,
            "seed": self.seed,
            "mode": self.mode.value,
            "drift_z": self.drift_z,
            "smoothing": self.smoothing,
            "target_ate_pos_m": self.target_ate_pos_m,
            "target_ate_rot_deg": self.target_ate_rot_deg,
            "preset": self.preset,
        }


@dataclass(frozen=True)
class DriftPreset:
    """Nominal σs (the shape of the drift) and the ATE targets the paper reports."""

    sigma_t: float
    sigma_pitch_deg: float
    sigma_yaw_deg: float
    target_ate_pos_m: float
    target_ate_rot_deg: float
    description: str


#: The paper's three experiments. Nominal σs are those that give the targets in expectation on
#: ~150 frames (a 3-D walk has E ATE_pos² = 1.5 (N + 1) σ_t²; two independent angles give
#: ATE_rot ≈ √2 σ); the targets are then hit exactly by the scale fit. Pitch and yaw get equal
#: σs, as the paper's per-axis RMSEs (yaw 4.31°, pitch 4.31°) show.
PRESETS: dict[str, DriftPreset] = {
    "exp1": DriftPreset(0.092, 7.06, 7.06, 1.391, 9.99, "Exp. 1: large drift, 1.391 m / 9.99 deg"),
    "exp2": DriftPreset(0.020, 6.24, 6.24, 0.303, 8.82, "Exp. 2: small drift, 0.303 m / 8.82 deg"),
    "exp3": DriftPreset(0.0, 6.79, 6.79, 0.0, 9.60, "Exp. 3: rotation only, 0 m / 9.60 deg"),
}


@dataclass(frozen=True)
class DriftOffsets:
    """The sampled offsets after calibration, one row per frame.

    Attributes
    ----------
    translation: (N, 3) metres; PAPER: ``t_init − t_gt``; SLAM_LIKE: the accumulated increments
        e_i (the actual position error also contains the yaw bending).
    pitch_deg: (N,) pitch offset about the camera x axis, degrees.
    yaw_deg: (N,) yaw offset about the world z axis, degrees.
    """

    translation: F64
    pitch_deg: F64
    yaw_deg: F64


@dataclass
class DriftResult:
    """The drifted trajectory and how it was made.

    Attributes
    ----------
    init: the drifted ``world_from_cam`` trajectory (same timestamps as the ground truth).
    offsets: the offsets actually applied.
    params: the parameters of the draw.
    ate_pos: ATE_pos of ``init`` against the ground truth, metres.
    ate_rot: ATE_rot, degrees.
    scale_t: factor applied to the nominal translation increments by the calibration.
    scale_rot: factor applied to the nominal rotation offsets.
    """

    init: Trajectory
    offsets: DriftOffsets
    params: DriftParams
    ate_pos: float
    ate_rot: float
    scale_t: float = 1.0
    scale_rot: float = 1.0
    n_frames: int = field(init=False)

    def __post_init__(self) -> None:
        self.n_frames = len(self.init)

    def to_dict(self) -> dict[str, Any]:
        """JSON summary (written next to ``init.tum`` as ``init.drift.json``)."""
        p = self.params
        return {
            "preset": p.preset,
            "seed": p.seed,
            "mode": p.mode.value,
            "params": p.to_dict(),
            "scale_t": self.scale_t,
            "scale_rot": self.scale_rot,
            "effective_sigma_t": p.sigma_t * self.scale_t,
            "effective_sigma_pitch_deg": p.sigma_pitch_deg * self.scale_rot,
            "effective_sigma_yaw_deg": p.sigma_yaw_deg * self.scale_rot,
            "ate_pos_m": self.ate_pos,
            "ate_rot_deg": self.ate_rot,
            "n_frames": self.n_frames,
            "rotation_composition": "R_init = Rz_world(yaw) * R_gt * Rx_cam(pitch)",
            "ate_definition": "no alignment; pos = sqrt(mean |t_init - t_gt|^2) m, "
            "rot = sqrt(mean angle(R_init^T R_gt)^2) deg",
        }


# --------------------------------------------------------------------------- sampling
def _ar1(rng: np.random.Generator, shape: tuple[int, ...], rho: float) -> F64:
    """Unit-variance AR(1) sequences along axis 0 (rho = 0 gives white noise)."""
    eps = rng.standard_normal(shape)
    if rho == 0.0:
        return eps
    out = np.empty(shape)
    out[0] = eps[0]
    c = math.sqrt(1.0 - rho * rho)
    for i in range(1, shape[0]):
        out[i] = rho * out[i - 1] + c * eps[i]
    return out


@dataclass(frozen=True)
class _Unit:
    """Nominal (scale 1) per-frame draws; the trajectory is built from these and two scales."""

    steps_t: F64  # (N, 3) metres: translation increments
    pitch_deg: F64  # (N,) PAPER: offsets; SLAM_LIKE: accumulated offsets
    yaw_deg: F64  # (N,)


def _sample(n: int, params: DriftParams) -> _Unit:
    rng = np.random.default_rng(params.seed)
    rho = params.smoothing if params.mode is DriftModel.SLAM_LIKE else 0.0
    steps = _ar1(rng, (n, 3), rho) * params.sigma_t
    if not params.drift_z:
        steps[:, 2] = 0.0
    rot = _ar1(rng, (n, 2), rho) * np.array([params.sigma_pitch_deg, params.sigma_yaw_deg])
    if params.mode is DriftModel.SLAM_LIKE:
        rot = np.cumsum(rot, axis=0)
    return _Unit(steps, rot[:, 0].copy(), rot[:, 1].copy())


def _rotations(gt: Trajectory, pitch_deg: F64, yaw_deg: F64) -> Rotation:
    r_gt = Rotation.from_quat(gt.poses[:, 3:7])
    rz = Rotation.from_euler("z", yaw_deg[:, None], degrees=True)
    rx = Rotation.from_euler("x", pitch_deg[:, None], degrees=True)
    return rz * r_gt * rx


def _positions(
    gt: Trajectory, unit: _Unit, mode: DriftModel, scale_t: float, yaw_deg: F64
) -> tuple[F64, F64]:
    """Drifted camera centres (N, 3) and the accumulated translation offsets (N, 3)."""
    walk = np.cumsum(unit.steps_t * scale_t, axis=0)
    t_gt = gt.poses[:, :3]
    if mode is DriftModel.PAPER:
        return t_gt + walk, walk
    rz = Rotation.from_euler("z", yaw_deg[:, None], degrees=True)
    moves = np.diff(t_gt, axis=0)
    bent = rz[1:].apply(moves) if len(moves) else np.zeros((0, 3))
    steps = unit.steps_t * scale_t
    out = np.empty_like(t_gt)
    out[0] = t_gt[0] + steps[0]
    out[1:] = out[0] + np.cumsum(bent + steps[1:], axis=0)
    return out, walk


def _ate(t_est: F64, r_est: Rotation, gt: Trajectory) -> tuple[float, float]:
    """Unaligned ATE_pos (m) and ATE_rot (deg); the evaluation stage owns the full metrics."""
    pos = float(np.sqrt(np.mean(np.sum((t_est - gt.poses[:, :3]) ** 2, axis=1))))
    theta = (r_est.inv() * Rotation.from_quat(gt.poses[:, 3:7])).magnitude()
    return pos, float(np.degrees(np.sqrt(np.mean(theta**2))))


def _solve_scale(f: Any, target: float, what: str) -> float:
    """Smallest s >= 0 with f(s) == target, for f continuous, f(s) → ∞; f(0) <= target."""
    f0 = f(0.0)
    if target < f0 - 1e-12:
        raise DriftError(
            f"target {target} cannot be reached: even without {what} drift the error is {f0:.6g}",
            field=f"target_ate_{what}",
        )
    if target <= f0 + 1e-12:
        return 0.0
    hi = 1.0
    while f(hi) < target:
        hi *= 2.0
        if hi > 1e6:
            raise DriftError(f"target {target} cannot be reached", field=f"target_ate_{what}")
    return float(brentq(lambda s: f(s) - target, 0.0, hi, xtol=1e-14, rtol=1e-13, maxiter=200))


def apply_drift(gt: Trajectory, params: DriftParams) -> DriftResult:
    """Make a drifted copy of ``gt`` (``world_from_cam``) with the model and seed of ``params``.

    Parameters
    ----------
    gt: the ground-truth trajectory, N >= 1 poses.
    params: σs, seed, model and optional ATE targets.

    Returns
    -------
    DriftResult with the drifted trajectory (same timestamps), the offsets, the calibration
    scales and the resulting ATEs.

    Raises
    ------
    DriftError
        If a target cannot be reached (e.g. a zero translation target in SLAM_LIKE mode with
        yaw drift, which bends the path).
    """
    n = len(gt)
    if n == 0:
        raise DriftError("the trajectory is empty", field="gt")
    unit = _sample(n, params)

    def rot_error(s: float) -> float:
        r = _rotations(gt, unit.pitch_deg * s, unit.yaw_deg * s)
        return _ate(gt.poses[:, :3], r, gt)[1]

    scale_rot = 1.0
    if params.target_ate_rot_deg is not None:
        scale_rot = _solve_scale(rot_error, params.target_ate_rot_deg, "rot")
    pitch, yaw = unit.pitch_deg * scale_rot, unit.yaw_deg * scale_rot
    r_init = _rotations(gt, pitch, yaw)

    def pos_error(s: float) -> float:
        return _ate(_positions(gt, unit, params.mode, s, yaw)[0], r_init, gt)[0]

    scale_t = 1.0
    if params.target_ate_pos_m is not None:
        if params.sigma_t == 0.0:
            scale_t = 1.0
            if pos_error(0.0) > params.target_ate_pos_m + 1e-9:
                _solve_scale(pos_error, params.target_ate_pos_m, "pos")  # raises
        else:
            scale_t = _solve_scale(pos_error, params.target_ate_pos_m, "pos")
    t_init, walk = _positions(gt, unit, params.mode, scale_t, yaw)

    q = r_init.as_quat()
    q[q[:, 3] < 0] *= -1.0
    init = Trajectory(gt.timestamps.copy(), np.concatenate([t_init, q], axis=1))
    ate_pos, ate_rot = _ate(t_init, r_init, gt)
    return DriftResult(
        init=init,
        offsets=DriftOffsets(walk, pitch, yaw),
        params=params,
        ate_pos=ate_pos,
        ate_rot=ate_rot,
        scale_t=scale_t,
        scale_rot=scale_rot,
    )


# --------------------------------------------------------------------------- SLAM frame
#: Default ranges of the random rigid motion of :func:`to_slam_frame`.
SLAM_FRAME_XY_RANGE_M = 50.0
SLAM_FRAME_Z_RANGE_M = 5.0


@dataclass(frozen=True)
class SlamFrame:
    """A trajectory expressed in a SLAM system's own frame, and the true transform.

    Attributes
    ----------
    trajectory: ``slam_from_cam`` poses (the drifted ``world_from_cam`` moved into the SLAM
        frame), same timestamps.
    slam_from_world: (7,) TUM-order pose of the BIM/world frame in the SLAM frame: a yaw about
        the vertical and a translation; ``slam_from_cam = slam_from_world ∘ world_from_cam``.
    yaw_deg: the yaw of ``slam_from_world``, degrees in [0, 360).
    translation_m: (3,) its translation, metres.
    seed: the seed of the draw.
    """

    trajectory: Trajectory
    slam_from_world: F64
    yaw_deg: float
    translation_m: F64
    seed: int

    def to_dict(self) -> dict[str, Any]:
        """JSON provenance (``slam_frame`` of ``init.drift.json``)."""
        return {
            "slam_from_world": [float(v) for v in self.slam_from_world],
            "world_from_slam": [float(v) for v in _invert_pose(self.slam_from_world)],
            "yaw_deg": self.yaw_deg,
            "translation_m": [float(v) for v in self.translation_m],
            "seed": self.seed,
            "convention": "TUM order [tx ty tz qx qy qz qw]; "
            "slam_from_cam = slam_from_world * world_from_cam",
        }


def _invert_pose(pose: F64) -> F64:
    rot = Rotation.from_quat(pose[3:7]).inv()
    q = rot.as_quat()
    if q[3] < 0:
        q = -q
    return np.concatenate([-rot.apply(pose[:3]), q])


def to_slam_frame(
    traj: Trajectory,
    seed: int,
    xy_range_m: float = SLAM_FRAME_XY_RANGE_M,
    z_range_m: float = SLAM_FRAME_Z_RANGE_M,
) -> SlamFrame:
    """Move ``traj`` (``world_from_cam``) into a random SLAM frame, as a SLAM system writes it.

    The frame is a seeded random rigid motion: yaw uniform in [0°, 360°), x and y uniform in
    ``±xy_range_m``, z uniform in ``±z_range_m`` (gravity stays vertical, as an IMU keeps it).

    Parameters
    ----------
    traj: the (drifted) trajectory in the world frame.
    seed: seed of the draw (its own random stream: ``[seed, 515]``, independent of the drift's).
    xy_range_m, z_range_m: half-widths of the translation, metres (>= 0).

    Returns
    -------
    SlamFrame with ``slam_from_cam`` poses and the true ``slam_from_world``.
    """
    for name, v in (("slam_xy_range_m", xy_range_m), ("slam_z_range_m", z_range_m)):
        if not math.isfinite(v) or v < 0:
            raise DriftError(f"must be finite and >= 0, got {v!r}", field=name)
    rng = np.random.default_rng([seed, 515])
    yaw = float(rng.uniform(0.0, 2.0 * np.pi))
    t = np.array([rng.uniform(-xy_range_m, xy_range_m), rng.uniform(-xy_range_m, xy_range_m),
                  rng.uniform(-z_range_m, z_range_m)])
    rz = Rotation.from_euler("z", yaw)
    q = rz.as_quat()
    slam_from_world = np.concatenate([t, q if q[3] >= 0 else -q])
    moved_t = rz.apply(traj.poses[:, :3]) + t
    moved_q = (rz * Rotation.from_quat(traj.poses[:, 3:7])).as_quat()
    moved_q[moved_q[:, 3] < 0] *= -1.0
    moved = Trajectory(traj.timestamps.copy(), np.concatenate([moved_t, moved_q], axis=1))
    return SlamFrame(moved, slam_from_world, float(np.degrees(yaw)), t, seed)
