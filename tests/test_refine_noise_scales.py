"""G's pixel noise scale follows the sequence's measured LiDAR range noise
(``refine.pixel_sigma_for_noise``, ``refine.sequence_range_noise``)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import bimcap.pipeline.refine as refine
from bimcap.pipeline.config import RefineConfig


class _Rings:
    """A stand-in sequence: ``n`` frames, each a 16-ring scan of a 4 m cylinder every 0.2° with
    ``noise_m`` of range noise (what ``scan_range_noise`` measures); frame 1 has no scan."""

    def __init__(self, noise_m: float, n: int = 5) -> None:
        rng = np.random.default_rng(1)
        az = np.radians(np.arange(0.0, 360.0, 0.2))
        el = np.radians(np.linspace(-15.0, 15.0, 16))
        a, e = (g.ravel() for g in np.meshgrid(az, el))
        self.scans = []
        for _ in range(n):
            r = 4.0 / np.cos(e) + rng.normal(0.0, noise_m, a.shape)
            self.scans.append(np.stack([r * np.cos(e) * np.cos(a), r * np.cos(e) * np.sin(a),
                                        r * np.sin(e)], 1))
        self.frames = [SimpleNamespace(lidar=None if i == 1 else f"{i}.bin") for i in range(n)]

    def load_lidar(self, i: int) -> np.ndarray:
        assert self.frames[i].lidar is not None, "a frame without a scan was loaded"
        return self.scans[i]


def test_the_sequence_noise_is_measured_on_its_scans() -> None:
    assert refine.sequence_range_noise(_Rings(0.08)) == pytest.approx(0.08, rel=0.1)
    assert refine.sequence_range_noise(_Rings(0.03)) == pytest.approx(0.03, rel=0.1)
    assert refine.sequence_range_noise(SimpleNamespace(frames=[])) is None
    assert refine.sequence_range_noise(object()) is None


def test_pixel_sigma_grows_with_the_range_noise_above_the_reference() -> None:
    config = RefineConfig()
    base = refine.solver_options(config)
    assert base.pixel_sigma == pytest.approx(2.0)
    wide = refine.pixel_sigma_for_noise(base, config, 0.08)
    assert wide.pixel_sigma == pytest.approx(2.0 * 0.08 / 0.03)
    assert base.pixel_sigma == pytest.approx(2.0)  # a copy
    assert refine.pixel_sigma_for_noise(base, config, 0.5).pixel_sigma == pytest.approx(8.0)
    # the standard worlds' 3 cm, unknown noise, and a scale the user set: unchanged
    for noise in (0.03, 0.045, None, float("nan")):
        assert refine.pixel_sigma_for_noise(base, config, noise) is base
    mine = RefineConfig(solver={"pixel_sigma": 3.0})
    opts = refine.solver_options(mine)
    assert refine.pixel_sigma_for_noise(opts, mine, 0.08) is opts


def test_noise_factor_is_the_one_rule_of_every_noise_adaptation() -> None:
    """Unknown, non-finite or not above the limit: None (thresholds unchanged); above: σ / ref.
    Each option's ``for_noise`` follows it (the segmenter's, the refiner's, the scan's)."""
    import math

    from bimcap.fusion import PlanarSmoothingOptions
    from bimcap.fusion.scan import ScanSamplingOptions
    from bimcap.geometry.noise import noise_factor
    from bimcap.segmentation.geometric import GeometricOptions

    assert noise_factor(None, 0.03, 1.5) is None
    assert noise_factor(math.nan, 0.03, 1.5) is None
    assert noise_factor(0.045, 0.03, 1.5) is None  # at the limit: unchanged
    assert noise_factor(0.08, 0.03, 1.5) == 0.08 / 0.03
    for opts in (PlanarSmoothingOptions(), ScanSamplingOptions(), GeometricOptions()):
        assert opts.for_noise(0.045) is opts and opts.for_noise(None) is opts
        assert opts.for_noise(0.08) != opts
