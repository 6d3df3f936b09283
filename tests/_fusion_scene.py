"""Shared synthetic frames for the fusion/segmentation tests (rendered once per session)."""

from __future__ import annotations

from functools import lru_cache

from bimcap.fusion.synthetic import SyntheticFrame, default_camera, render_default_frames


@lru_cache(maxsize=4)
def frames(n: int = 3, width: int = 516, height: int = 386,
           seed: int = 0) -> tuple[SyntheticFrame, ...]:
    """``n`` box-room frames at ``width × height`` (half the bench resolution for speed)."""
    return tuple(render_default_frames(n, camera=default_camera(width, height), seed=seed))
