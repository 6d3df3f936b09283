"""A spinning multi-beam LiDAR like the Velodyne VLP-16, ray-cast in the simulated world.

LiDAR frame (Velodyne's): x forward, y left, z up. Beam ``b`` has elevation
``fov[0] + b·(fov[1] − fov[0])/(channels − 1)`` (VLP-16: −15°…+15° in 2° steps); a sweep
has ``360 / azimuth_step`` columns. One scan is taken instantaneously at the frame's timestamp (no
motion distortion within the 0.1 s sweep; the camera frames are synchronised to scans as in
ConSLAM's ``synced2rgb`` topics).

Measurement model (``r`` the true range, ``θ`` the angle between the beam and the surface
normal, ``ρ`` the surface reflectivity):

* **Range noise** grows with range and with the incidence angle: the measured range is
  ``r + ε``, ``ε ~ N(0, σ²)`` with
  ``σ(r, θ) = sqrt(σ₀² + (k·r)² + (β·r·tan θ)² / 12)``:
  ``σ₀ = range_noise_m`` (the noise at short range, facing the surface), ``k =
  range_noise_per_m`` (the slow growth with range of a time-of-flight measurement), and the
  last term the spread of ranges inside the beam's footprint: a beam of divergence ``β =
  beam_divergence_rad`` lights a spot ``β·r`` wide, which on a surface seen at incidence θ spans
  ``β·r·tan θ`` in range; the return comes from anywhere in it (the standard deviation of a
  uniform spread, ``/ √12``; ``tan θ`` capped at cos θ = 0.1). At the defaults (3 cm, 1 mm/m,
  3 mrad) a wall 5 m away seen head-on gives 3.0 cm, seen at 70° 3.3 cm, at 84° 5.1 cm; the
  floor 20 m away at 86° 18 cm.
* **Dropouts**: a fraction ``dropout`` of the returns is lost, part at random and part where the
  beam grazes the surface: return ``i`` is lost with probability
  ``dropout · ((1 − s) + s · g_i / mean(g))``, ``g = 1 − cos θ``, ``s = grazing_share``
  (the mean over the scan's hits, so that the expected lost fraction stays ``dropout``).
  Independently of ``dropout``, the physics loses what returns too little light: the return
  probability falls linearly to 0 below cos θ = 0.1 and below ρ = 0.1 (glass).
* No return beyond ``max_range_m`` or below ``min_range_m``.

Intensity = 255 · ρ · |cos θ| (+ noise), like a calibrated reflectivity channel.

Output: float32 (M, 4) ``x y z intensity`` in the LiDAR frame, ordered by azimuth then beam.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.geometry.poses import quat_to_rotmat
from bimcap.sim.render import SimConfigError, World, rotate_rows
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
    range_noise_m: range noise std σ₀ in metres at short range and normal incidence.
    range_noise_per_m: growth of the noise std with range, metres per metre.
    beam_divergence_rad: full beam divergence (VLP-16: 3 mrad); sets the grazing-angle noise.
    dropout: fraction of the returns lost (besides the physical losses of glass and grazing
        beams), in [0, 1).
    grazing_share: share of the lost returns placed preferentially at grazing incidence (0 = all
        at random).

    See the module docstring for the model.
    """

    model: str = "VLP-16"
    channels: int = 16
    vertical_fov_deg: tuple[float, float] = (-15.0, 15.0)
    azimuth_step_deg: float = 0.2
    rate_hz: float = 10.0
    max_range_m: float = 100.0
    min_range_m: float = 0.4
    range_noise_m: float = 0.03
    range_noise_per_m: float = 0.001
    beam_divergence_rad: float = 0.003
    dropout: float = 0.02
    grazing_share: float = 0.5

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> SimConfigError:
            return SimConfigError(f"{why} (got {getattr(self, name)!r})", None, f"lidar.{name}")

        for name in ("range_noise_m", "range_noise_per_m", "beam_divergence_rad"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise bad(name, "must be finite and >= 0")
        if not 0.0 <= self.dropout < 1.0:
            raise bad("dropout", "must be in [0, 1)")
        if not 0.0 <= self.grazing_share <= 1.0:
            raise bad("grazing_share", "must be in [0, 1]")
        if self.channels < 1 or not self.azimuth_step_deg > 0:
            raise bad("channels" if self.channels < 1 else "azimuth_step_deg", "must be positive")
        if not 0 <= self.min_range_m < self.max_range_m:
            raise bad("max_range_m", "need 0 <= min_range_m < max_range_m")

    @property
    def columns(self) -> int:
        return round(360.0 / self.azimuth_step_deg)

    def to_dict(self) -> dict[str, object]:
        """The manifest's ``lidar`` block."""
        d = asdict(self)
        d["vertical_fov_deg"] = list(self.vertical_fov_deg)
        return d

    def range_sigma(self, range_m: ArrayLike, cos_incidence: ArrayLike) -> F64:
        """Range noise std σ(r, θ) in metres (module docstring) for ranges ``range_m`` (metres)
        and ``cos_incidence`` = |cos θ| (same shapes)."""
        r = np.asarray(range_m, np.float64)
        c = np.clip(np.abs(np.asarray(cos_incidence, np.float64)), 0.1, 1.0)
        tan = np.sqrt(1.0 - c * c) / c
        footprint = self.beam_divergence_rad * r * tan / np.sqrt(12.0)
        return np.sqrt(self.range_noise_m**2 + (self.range_noise_per_m * r) ** 2 + footprint**2)

    def drop_probability(self, cos_incidence: ArrayLike) -> F64:
        """Probability that each of a scan's hits (|cos θ| given) is lost to ``dropout`` (the
        random and grazing part of the model; the physical losses come on top)."""
        c = np.abs(np.asarray(cos_incidence, np.float64))
        if self.dropout == 0 or c.size == 0:
            return np.zeros(c.shape)
        g = 1.0 - c
        mean_g = float(g.mean())
        rel = g / mean_g if mean_g > 1e-9 else np.ones_like(g)
        return np.clip(self.dropout * ((1.0 - self.grazing_share) + self.grazing_share * rel),
                       0.0, 1.0)

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
        noise = rng.standard_normal(n, dtype=np.float32)
        u = rng.random(n, dtype=np.float32)
        inten_noise = rng.standard_normal(n, dtype=np.float32)
        r_ok = np.where(ok, rng_true, 0.0)
        sigma = cfg.range_sigma(r_ok, cos_inc).astype(np.float32)
        p_drop = np.zeros(n)
        p_drop[ok] = cfg.drop_probability(cos_inc[ok])
        p_keep = (1.0 - p_drop) * np.clip(cos_inc / 0.1, 0.0, 1.0)
        p_keep *= np.clip(refl / 0.1, 0.0, 1.0)
        measured = rng_true + noise * sigma
        ok &= u < p_keep
        ok &= (measured >= cfg.min_range_m) & (measured <= cfg.max_range_m)
        pts = self.dirs_in_lidar[ok] * measured[ok, None]
        inten = np.clip(255.0 * refl[ok] * cos_inc[ok] + 3.0 * inten_noise[ok], 0.0, 255.0)
        out = np.empty((int(ok.sum()), 4), np.float32)
        out[:, :3] = pts
        out[:, 3] = inten
        return out
