"""The one rule by which thresholds made for one LiDAR range noise follow another.

Thresholds of the segmenter, the planar depth refiner, the scan sampling and G's pixel scale were
set for the standard worlds' range noise (about 3 cm). Each adapts to a noisier scan the same
way: unchanged up to ``adapt_above`` × that reference, so that the standard worlds are
untouched to the digit; above it, scaled by σ / reference (each caller says what it scales and
caps the factor).
"""

from __future__ import annotations

import math


def noise_factor(range_noise_m: float | None, reference_m: float,
                 adapt_above: float) -> float | None:
    """σ / ``reference_m`` for a measured range noise σ = ``range_noise_m`` (metres) above
    ``adapt_above`` × ``reference_m``; None where the thresholds stay as they are (σ unknown,
    not finite, or not above the limit)."""
    if range_noise_m is None or not math.isfinite(range_noise_m):
        return None
    if range_noise_m <= adapt_above * reference_m:
        return None
    return float(range_noise_m) / reference_m
