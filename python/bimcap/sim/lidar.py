"""A spinning multi-beam LiDAR like the Velodyne VLP-16, ray-cast in the simulated world.

LiDAR frame (Velodyne's): x forward, y left, z up. Beam ``b`` has elevation
``fov[0] + b·(fov[1] − fov[0])/(channels − 1)`` (VLP-16: −15°…+15° in 2° steps); a sweep has
``360 / azimuth_step`` columns. One scan is taken instantaneously at the frame's timestamp (no
motion distortion within the 0.1 s sweep; the camera frames are synchronised to scans as in
ConSLAM's ``synced2rgb`` topics).

Measurement model: range along the unit beam direction plus N(0, σ²) noise; no return beyond
``max_range_m`` or below ``min_range_m``; random dropouts with probability ``dropout``; more
dropouts at grazing incidence and on dark surfaces (glass). Intensity = 255 · reflectivity ·
|cos(incidence)| (+ noise), like a calibrated reflectivity channel.

Output: float32 (M, 4) ``x y z intensity`` in the LiDAR frame, ordered by azimuth then beam.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.poses import quat_to_rotmat
from bimcap.sim.render import World, rotate_rows
from bimcap.sim.texture import REFLECTIVITY

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class LidarConfig:
    """Spinning LiDAR model (defaults: VLP-16).

    Attributes
    ----------
    model: name written into the manifest.
    channels: number of beams.
    vertical_fov_deg: (lowest, highest) beam elevation in degrees.
    azimuth_step_deg: horizontal resolution in degrees.
    rate_hz: rotation rate (metadata; one scan per camera frame is simulated).
    max_range_m, min_range_m: valid range interval in metres.
    range_noise_m: range noise std in metres.
    dropout: probability that a return is lost at random.
    """

    model: str = "VLP-16"
    channels: int = 16
    vertical_fov_deg: tuple[float, float] = (-15.0, 15.0)
    azimuth_step_deg: float = 0.2
    rate_hz: float = 10.0
    max_range_m: float = 100.0
    min_range_m: float = 0.4
    range_noise_m: float = 0.03
    dropout: float = 0.02

    @property
    def columns(self) -> int:
        return int(round(360.0 / self.azimuth_step_deg))

    def to_dict(self) -> dict[str, object]:
        """The manifest's ``lidar`` block."""
        d = asdict(self)
        d["vertical_fov_deg"] = list(self.vertical_fov_deg)
        return d

    def directions(self) -> NDArray[np.float32]:
        """(columns·channels, 3) unit beam directions in the LiDAR frame, azimuth-major."""
        elev = np.deg2rad(np.linspace(*self.vertical_fov_deg, self.channels))
        azim = np.deg2rad(np.arange(self.columns) * self.azimuth_step_deg)
        az, el = np.meshgrid(azim, elev, indexing="ij")
        d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
        return d.reshape(-1, 3).astype(np.float32)


class LidarSimulator:
    """Casts one sweep of a :class:`LidarConfig` in a :class:`World`."""

    def __init__(self, world: World, config: LidarConfig | None = None) -> None:
        self.world = world
        self.config = config or LidarConfig()
        self.dirs_in_lidar = self.config.directions()

    def scan(
        self, world_from_lidar: F64, rng: np.random.Generator, nthreads: int = 0
    ) -> NDArray[np.float32]:
        """One sweep from pose ``world_from_lidar`` (7,) TUM order.

        Returns
        -------
        (M, 4) float32 ``x y z intensity``, points in the LiDAR frame (metres).
        """
        cfg = self.config
        pose = np.asarray(world_from_lidar, np.float64)
        r_wl = quat_to_rotmat(pose[3:7]).astype(np.float32)
        dirs_w = rotate_rows(self.dirs_in_lidar, r_wl)
        hit = self.world.cast(np.broadcast_to(pose[:3], dirs_w.shape), dirs_w, nthreads)
        rng_true = hit["t_hit"]
        n = len(rng_true)
        ok = np.isfinite(rng_true)
        prim = np.where(ok, hit["primitive_ids"], 0).astype(np.int64)
        cos_inc = np.abs(np.einsum("ij,ij->i", dirs_w, hit["primitive_normals"]))
        refl = REFLECTIVITY[self.world.tri_material[prim]]
        # the noise and dropout draws are made for every beam so that the stream is fixed-size
        noise = rng.standard_normal(n, dtype=np.float32) * np.float32(cfg.range_noise_m)
        u = rng.random(n, dtype=np.float32)
        inten_noise = rng.standard_normal(n, dtype=np.float32)
        p_keep = (1.0 - cfg.dropout) * np.clip(cos_inc / 0.1, 0.0, 1.0) * np.clip(refl / 0.1, 0.0, 1.0)
        measured = rng_true + noise
        ok &= u < p_keep
        ok &= (measured >= cfg.min_range_m) & (measured <= cfg.max_range_m)
        pts = self.dirs_in_lidar[ok] * measured[ok, None]
        inten = np.clip(255.0 * refl[ok] * cos_inc[ok] + 3.0 * inten_noise[ok], 0.0, 255.0)
        out = np.empty((int(ok.sum()), 4), np.float32)
        out[:, :3] = pts
        out[:, 3] = inten
        return out
