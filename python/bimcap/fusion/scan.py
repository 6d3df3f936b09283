"""Samples from the LiDAR scan outside the camera's view: the BIM terms' 360° observations.

The camera sees 60–70° of the scene; a spinning LiDAR sees all around. A frame whose camera looks
at a single wall from 0.8 m (no floor, no match) is placed by nothing but noise, while its scan
still sees the walls behind and beside it. This module turns each scan into oriented surface
points in the camera frame, and then into wall / floor / ceiling samples the solver's W / F / Ce
terms take like any labelled pixel.

Two steps, so that the front end stays independent of the poses:

1. :func:`scan_surface_points` (per frame, pose-free): drop returns closer than ``min_range_m``
   or further than ``max_range_m``, average them per ``voxel_m`` voxel (even density near and
   far), estimate each voxel's normal from its ``neighbours`` nearest voxels (PCA; kept when the
   neighbourhood is a plane, ``λ₀ ≤ max_flatness · λ₁``, and not a single scan line,
   ``λ₁ ≥ min_spread · λ₂``) for the points the camera does not see (those are already the
   pixels' samples), thin the rest evenly to ``max_candidates``, and return ``p_in_cam`` and
   ``n_in_cam``.
2. :func:`classify_scan_points` (at the initial poses, which give the up direction): a point
   whose normal is within ``max_tilt_deg`` of horizontal is a wall sample; one whose normal is
   within ``max_tilt_deg`` of vertical is a floor sample ``min_height_m`` below the camera or a
   ceiling sample above it; at most ``max_per_frame[class]`` per frame, drawn at random (seeded
   by the frame index).

Columns are not told apart from walls: their faces come out as wall samples, which the solver's
association sends to the nearest wall face within its gate, or drops.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.errors import BimcapError
from bimcap.geometry import Camera, quat_to_rotmat
from bimcap.geometry.noise import noise_factor
from bimcap.labels import Label

F64 = NDArray[np.float64]


class ScanSamplingError(BimcapError):
    """Bad settings of the scan sampling."""


@dataclass(frozen=True)
class ScanSamplingOptions:
    """Settings of :func:`scan_surface_points` and :func:`classify_scan_points` (module doc).

    Distances in metres, angles in degrees; ``max_wall`` / ``max_floor`` / ``max_ceiling`` are
    per-frame caps of each class (0 switches the class off).
    """

    min_range_m: float = 0.5
    max_range_m: float = 15.0
    voxel_m: float = 0.10
    neighbours: int = 10
    max_flatness: float = 0.10
    min_spread: float = 0.05
    exclude_camera_view: bool = True
    max_candidates: int = 2000
    max_tilt_deg: float = 20.0
    min_height_m: float = 0.3
    max_wall: int = 400
    max_floor: int = 150
    max_ceiling: int = 150
    seed: int = 0
    noise_reference_m: float = 0.03
    noise_adapt_above: float = 1.5
    max_voxel_scale: float = 2.0

    def for_noise(self, range_noise_m: float | None) -> ScanSamplingOptions:
        """These options for a scan with range noise σ = ``range_noise_m`` (metres; None or not
        finite: unknown, unchanged). Unchanged up to ``noise_adapt_above`` ×
        ``noise_reference_m``; above, the voxel grows with the noise, ``voxel_m`` ×
        σ / ``noise_reference_m``, at most ``max_voxel_scale`` times: a voxel mean's noise
        falls with the number of returns it averages (its area), so that its normal and its
        position stay about as certain as at the reference noise. At 8 cm of noise and 10 cm
        voxels the neighbourhoods' PCA no longer looked planar and the scan gave a few samples a
        frame (gen-small-s3 hard frames 55-57: 30, 3 and 3 walls) where it is meant to give the
        walls all around a frame that sees one wall."""
        k = noise_factor(range_noise_m, self.noise_reference_m, self.noise_adapt_above)
        if k is None:
            return self
        scale = min(self.max_voxel_scale, k)
        return replace(self, voxel_m=self.voxel_m * scale)

    def __post_init__(self) -> None:
        if not 0 <= self.min_range_m < self.max_range_m:
            raise ScanSamplingError("need 0 <= min_range_m < max_range_m")
        if not self.voxel_m > 0:
            raise ScanSamplingError("voxel_m must be > 0")
        if self.neighbours < 3:
            raise ScanSamplingError("neighbours must be >= 3")
        if not 0 < self.max_tilt_deg < 45:
            raise ScanSamplingError("max_tilt_deg must be in (0, 45)")
        if min(self.max_wall, self.max_floor, self.max_ceiling) < 0:
            raise ScanSamplingError("the per-frame caps must be >= 0")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def cap(self, label: Label) -> int:
        return {Label.WALL: self.max_wall, Label.FLOOR: self.max_floor,
                Label.CEILING: self.max_ceiling}.get(label, 0)


def scan_surface_points(points_in_lidar: ArrayLike, cam_from_lidar: ArrayLike, camera: Camera,
                        options: ScanSamplingOptions | None = None) -> tuple[F64, F64]:
    """Oriented surface points of one scan, in the camera frame (module doc, step 1).

    Parameters
    ----------
    points_in_lidar: (M, 3+) scan points in the LiDAR frame, metres (extra columns ignored,
        non-finite rows dropped).
    cam_from_lidar: (7,) TUM-order extrinsic.
    camera: the undistorted pinhole camera whose view is excluded.

    Returns
    -------
    p_in_cam (n, 3) metres and n_in_cam (n, 3) unit normals, pointing towards the LiDAR.
    """
    from bimcap import _core

    opts = options or ScanSamplingOptions()
    raw = np.asarray(points_in_lidar)
    if raw.ndim != 2 or raw.shape[1] < 3:
        raise ScanSamplingError(f"a scan must be (M, 3+), got {raw.shape}")
    # the xyz columns alone, as contiguous float64 (the intensity column is never read); the
    # returns in range (a row with a non-finite coordinate has a non-finite range), averaged
    # per voxel in compiled code (bimcap/raster/voxel_normals.h: numpy's arithmetic bit for bit)
    pts = np.ascontiguousarray(raw[:, :3], dtype=np.float64)
    try:
        vox, num_kept = _core.voxel_means(pts, opts.min_range_m, opts.max_range_m, opts.voxel_m)
    except _core.InputError as exc:
        raise ScanSamplingError(f"cannot average the scan per voxel: {exc}") from None
    empty = np.zeros((0, 3))
    if num_kept < opts.neighbours:
        return empty, empty
    if len(vox) < opts.neighbours:
        return empty, empty
    pose = np.asarray(cam_from_lidar, np.float64)
    rot = quat_to_rotmat(pose[3:])
    p_cam = vox @ rot.T + pose[:3]
    keep = np.ones(len(vox), bool)
    if opts.exclude_camera_view:
        z = p_cam[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            u = camera.fx * p_cam[:, 0] / z + camera.cx
            v = camera.fy * p_cam[:, 1] / z + camera.cy
        keep = ~((z > 0.05) & (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5)
                 & (v < camera.height - 0.5))
    cand = np.flatnonzero(keep)
    if len(cand) > opts.max_candidates:  # an even thinning, the same on every run
        cand = cand[np.linspace(0, len(cand) - 1, opts.max_candidates).astype(np.int64)]
    # PCA normals of each candidate's k nearest voxel means (scipy's cKDTree's neighbours, found
    # in a grid of cubes of three voxels: bimcap/raster/point_neighbours.h), in compiled code
    # (numpy's algorithm to rounding: bimcap/raster/voxel_normals.h)
    nearest = _core.nearest_points(vox, np.ascontiguousarray(vox[cand]), opts.neighbours,
                                   3.0 * opts.voxel_m)
    normal, planar = _core.pca_normals(vox, nearest, opts.max_flatness, opts.min_spread)
    cand, normal = cand[planar], normal[planar]
    flip = (normal * vox[cand]).sum(axis=1) > 0  # face the sensor
    normal[flip] *= -1.0
    p_cam, n_cam = p_cam[cand], normal @ rot.T
    return p_cam, n_cam


def classify_scan_points(p_in_cam: F64, n_in_cam: F64, world_from_cam: ArrayLike,
                         frame_index: int, options: ScanSamplingOptions | None = None
                         ) -> dict[Label, F64]:
    """Wall, floor and ceiling samples of one frame's surface points (module doc, step 2).

    ``world_from_cam`` (7,) gives the up direction (its translation and yaw do not matter).
    Returns, per class, (n, 3) points in the camera frame.
    """
    opts = options or ScanSamplingOptions()
    rot = quat_to_rotmat(np.asarray(world_from_cam, np.float64)[3:])
    up_in_cam = rot[2, :]  # world z in camera coordinates
    nz = np.asarray(n_in_cam, np.float64) @ up_in_cam
    height = np.asarray(p_in_cam, np.float64) @ up_in_cam
    sin_t = np.sin(np.deg2rad(opts.max_tilt_deg))
    cos_t = np.cos(np.deg2rad(opts.max_tilt_deg))
    masks = {
        Label.WALL: np.abs(nz) <= sin_t,
        Label.FLOOR: (np.abs(nz) >= cos_t) & (height <= -opts.min_height_m),
        Label.CEILING: (np.abs(nz) >= cos_t) & (height >= opts.min_height_m),
    }
    gen = np.random.default_rng([opts.seed, frame_index])
    out: dict[Label, F64] = {}
    for label, mask in masks.items():
        idx = np.flatnonzero(mask)
        cap = opts.cap(label)
        if len(idx) > cap:
            idx = np.sort(gen.choice(idx, size=cap, replace=False))
        out[label] = np.asarray(p_in_cam, np.float64)[idx]
    return out
