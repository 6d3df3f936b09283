"""Exact mesh–plane slicing and the coverage / precision of a floor plan against it.

The exact slice of the wall and column meshes with the horizontal plane ``z = h`` is the "second
opinion" on the raster vectorizer (:mod:`bimcap.bim.floorplan`):

* **coverage** = fraction of the exact outline length (the slice at the cut height) that lies
  within ``tol`` (one raster cell) of a detected segment of the same class;
* **precision** = fraction of the detected length that lies within ``tol`` of the exact outline
  of the same class, where the exact outline is the union of the slices at every height of the
  band (the raster sees the whole band, so a wall below a window sill in the band is right).

Lengths are measured by sampling both sets of segments every ``step`` metres (default 1 cm).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray


def slice_mesh(
    vertices: NDArray[np.float64], faces: NDArray[np.int32], z: float
) -> NDArray[np.float64]:
    """Intersect a triangle mesh with the horizontal plane ``z``.

    Parameters
    ----------
    vertices: (V, 3) float64 metres. faces: (F, 3) int32.
    z: height of the cutting plane in metres.

    Returns
    -------
    (K, 4) float64 segments ``x1 y1 x2 y2`` in metres, one per triangle that crosses the plane.
    Triangles lying in the plane give nothing; a vertex exactly on the plane is nudged up by
    1e-9 m, so that a crossing is counted once.
    """
    if len(faces) == 0:
        return np.zeros((0, 4))
    tri = vertices[faces]  # (F, 3, 3)
    dz = tri[:, :, 2] - z
    dz = np.where(dz == 0.0, 1e-9, dz)
    above = dz > 0
    n_above = above.sum(axis=1)
    cross = (n_above == 1) | (n_above == 2)
    tri = tri[cross]
    dz = dz[cross]
    above = above[cross]
    if len(tri) == 0:
        return np.zeros((0, 4))
    # The lone vertex (the one on the other side from the other two).
    lone_is_above = above.sum(axis=1) == 1
    lone = np.where(lone_is_above, np.argmax(above, axis=1), np.argmin(above, axis=1))
    i1 = (lone + 1) % 3
    i2 = (lone + 2) % 3
    r = np.arange(len(tri))
    p0, p1, p2 = tri[r, lone], tri[r, i1], tri[r, i2]
    d0, d1, d2 = dz[r, lone], dz[r, i1], dz[r, i2]
    t1 = d0 / (d0 - d1)
    t2 = d0 / (d0 - d2)
    a = p0 + t1[:, None] * (p1 - p0)
    b = p0 + t2[:, None] * (p2 - p0)
    seg = np.concatenate([a[:, :2], b[:, :2]], axis=1)
    keep = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) > 1e-9
    return seg[keep]


def slice_band(
    vertices: NDArray[np.float64], faces: NDArray[np.int32], z_lo: float, z_hi: float, n: int
) -> list[NDArray[np.float64]]:
    """Slices at ``n`` evenly spaced heights from ``z_lo`` to ``z_hi`` (inclusive).

    Returns a list of ``n`` (K_i, 4) segment arrays (see :func:`slice_mesh`).
    """
    if len(faces):
        zt = vertices[faces][:, :, 2]
        sel = (zt.max(axis=1) >= z_lo) & (zt.min(axis=1) <= z_hi)
        faces = faces[sel]
    heights = np.linspace(z_lo, z_hi, n) if n > 1 else np.array([(z_lo + z_hi) / 2])
    return [slice_mesh(vertices, faces, float(h)) for h in heights]


def sample_segments(
    segments: NDArray[np.float64], step: float, endpoints: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points every ``step`` metres along segments, each carrying the length it stands for.

    Parameters
    ----------
    segments: (S, 4) ``x1 y1 x2 y2`` metres. step: sampling step in metres.
    endpoints: also emit both endpoints of every segment (weight 0), so that the samples reach
        the segment ends exactly.

    Returns
    -------
    points: (P, 2) float64 metres (sub-segment midpoints, then the endpoints if asked);
    weights: (P,) float64 metres, summing to the total length.
    """
    if len(segments) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    seg = np.asarray(segments, dtype=np.float64)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    n = np.maximum(1, np.ceil(length / step).astype(np.int64))
    idx = np.repeat(np.arange(len(seg)), n)
    start = np.cumsum(n) - n
    k = np.arange(idx.size) - np.repeat(start, n)
    t = (k + 0.5) / n[idx]
    pts = seg[idx, :2] + t[:, None] * (seg[idx, 2:] - seg[idx, :2])
    w = (length / n)[idx]
    if endpoints:
        pts = np.concatenate([pts, seg[:, :2], seg[:, 2:]])
        w = np.concatenate([w, np.zeros(2 * len(seg))])
    return pts, w


def thin_points(pts: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """Keep one point (the first) per ``cell``-sized grid square of (P, 2) points; (P', 2)."""
    if len(pts) == 0:
        return pts
    ij = np.floor(pts / cell).astype(np.int64)
    ij -= ij.min(axis=0)
    key = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    _, idx = np.unique(key, return_index=True)
    return pts[np.sort(idx)]


@dataclass
class Agreement:
    """Coverage and precision of a detected floor plan against the exact slice (one class or all).

    Attributes
    ----------
    coverage: fraction of exact outline length within ``tol`` of a detected segment (0..1).
    precision: fraction of detected length within ``tol`` of the exact outline (0..1).
    exact_length_m, detected_length_m: total lengths in metres.
    tol_m: the distance tolerance in metres (one raster cell).
    """

    coverage: float
    precision: float
    exact_length_m: float
    detected_length_m: float
    tol_m: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "coverage": self.coverage,
            "precision": self.precision,
            "exact_length_m": self.exact_length_m,
            "detected_length_m": self.detected_length_m,
            "tol_m": self.tol_m,
        }


def _fraction_near(
    pts: NDArray[np.float64], w: NDArray[np.float64], ref_pts: NDArray[np.float64], tol: float
) -> float:
    from scipy.spatial import cKDTree

    if len(pts) == 0:
        return 1.0
    if len(ref_pts) == 0:
        return 0.0
    dist, _ = cKDTree(ref_pts).query(pts, k=1, distance_upper_bound=tol * 2)
    return float(w[dist <= tol].sum() / w.sum())


def agreement(
    exact_mid: NDArray[np.float64],
    exact_band: NDArray[np.float64],
    detected: NDArray[np.float64],
    tol: float,
    step: float = 0.01,
) -> Agreement:
    """Coverage / precision of ``detected`` segments against the exact slice.

    Parameters
    ----------
    exact_mid: (K, 4) exact outline at the cut height (reference for coverage).
    exact_band: (K', 4) union of exact outlines over the band (reference for precision).
    detected: (S, 4) detected segments. All ``x1 y1 x2 y2`` metres, one class.
    tol: distance tolerance in metres. step: sampling step in metres (up to half of it adds to
        ``tol``'s slack, so keep it well below ``tol``).
    """
    e_pts, e_w = sample_segments(exact_mid, step)
    b_pts = thin_points(sample_segments(exact_band, step)[0], step / 2)
    d_pts, d_w = sample_segments(detected, step)
    return Agreement(
        coverage=_fraction_near(e_pts, e_w, d_pts, tol),
        precision=_fraction_near(d_pts, d_w, b_pts, tol),
        exact_length_m=float(e_w.sum()),
        detected_length_m=float(d_w.sum()),
        tol_m=tol,
    )
