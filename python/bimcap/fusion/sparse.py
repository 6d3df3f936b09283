"""Sparse depth on pixel grids: scattering LiDAR returns to the nearest pixel and moving them
to another resolution without losing any to interpolation (shared by the classical completion
and the ONNX model's input)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


def scatter_nearest(uv: F64, z: F64, shape: tuple[int, int]) -> tuple[F32, NDArray[np.int64]]:
    """Depth map (h, w) with each return at its nearest pixel, the nearest return kept per pixel.

    Returns (depth (h, w) float32, indices (K',) of the kept returns)."""
    h, w = shape
    col = np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, h - 1)
    lin = row * w + col
    order = np.lexsort((z, lin))
    ls = lin[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = ls[1:] != ls[:-1]
    keep = order[first]
    out = np.zeros(h * w, dtype=np.float32)
    out[lin[keep]] = z[keep]
    return out.reshape(h, w), keep


def resize_sparse(uv: F64, z: F64, shape: tuple[int, int],
                  new_shape: tuple[int, int]) -> tuple[F32, F64, F64]:
    """Move sparse returns (pixel-centre convention) from ``shape`` to a grid of ``new_shape``
    without losing any to interpolation: (depth (h, w) float32, uv (K', 2), z (K',))."""
    sy, sx = new_shape[0] / shape[0], new_shape[1] / shape[1]
    uv_s = np.stack([(uv[:, 0] + 0.5) * sx - 0.5, (uv[:, 1] + 0.5) * sy - 0.5], 1)
    depth, keep = scatter_nearest(uv_s, z, new_shape)
    return depth, uv_s[keep], z[keep]


def downsample_sparse(uv: F64, z: F64, shape: tuple[int, int],
                      scale: float) -> tuple[F32, F64, F64]:
    """:func:`resize_sparse` to ``round(scale × shape)``."""
    new_shape = (max(1, round(shape[0] * scale)), max(1, round(shape[1] * scale)))
    return resize_sparse(uv, z, shape, new_shape)
