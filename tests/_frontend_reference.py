"""The front end's previous implementations of the stages made faster (issue 14), kept as oracles.

Each ``*_reference`` function is the code as it was before the speed-up, verbatim; the tests
check that the new code gives the same arrays bit for bit on real frames, and
``bench/bench_frontend.py --world`` times both in one process (``REFERENCES``: stage name →
a callable with the stage's own arguments that runs the stage with the old code swapped in).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.geometry.camera import Camera

F64 = NDArray[np.float64]


def pixel_surface_area_reference(depth: NDArray[np.floating], camera: Camera,
                                 min_cos: float = 0.1) -> F64:
    """``bimcap.frontend.semantic_map.pixel_surface_area`` before issue 14 (stacked points)."""
    z = np.asarray(depth, dtype=np.float64)
    h, w = z.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (u - camera.cx) / camera.fx * z
    y = (v - camera.cy) / camera.fy * z
    p = np.stack([x, y, z], axis=-1)
    du = np.gradient(p, axis=1)
    dv = np.gradient(p, axis=0)
    n = np.cross(du, dv)
    nn = np.linalg.norm(n, axis=-1)
    pn = np.linalg.norm(p, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs((n * p).sum(axis=-1)) / (nn * pn)
    cos = np.where(np.isfinite(cos), cos, 1.0)
    cos = np.clip(cos, min_cos, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_alpha = np.where(pn > 0, z / pn, 1.0)
    return np.where(z > 0, z * z * cos_alpha / (camera.fx * camera.fy) / cos, 0.0)


@contextmanager
def swapped(module: Any, **functions: Callable[..., Any]) -> Iterator[None]:
    """Replace ``module``'s attributes by ``functions`` for the duration of the block."""
    saved = {name: getattr(module, name) for name in functions}
    try:
        for name, fn in functions.items():
            setattr(module, name, fn)
        yield
    finally:
        for name, fn in saved.items():
            setattr(module, name, fn)


def _semantic_sampling(*args: Any, **kwargs: Any) -> Any:
    from bimcap.frontend import semantic_map

    with swapped(semantic_map, pixel_surface_area=pixel_surface_area_reference):
        return semantic_map.sample_semantic_points(*args, **kwargs)


#: Stage name (as ``bench_frontend.py --world`` prints it) → the stage run with the old code.
REFERENCES: dict[str, Callable[..., Any]] = {
    "semantic sampling": _semantic_sampling,
}
