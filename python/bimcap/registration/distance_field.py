"""A raster distance field of floor-plan segments and the robust score maps built from it.

Pixel ``(u, v)`` (column, row) of a field covers the world point
``(x, y) = origin_xy + resolution_m * (u, v)`` (pixel centres). Distances are metres to the
nearest rasterised segment (``cv2.distanceTransform``, exact Euclidean mask), so they are exact
to about ``resolution_m / sqrt(2)``; the final alignment uses exact point-to-segment distances
(:mod:`bimcap.registration.icp`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bimcap.registration.errors import RegistrationInputError

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

#: Distance reported for pixels of a field with no segment at all (metres).
FAR_M = 1.0e3


@dataclass(frozen=True)
class DistanceField:
    """Distance (metres) from every pixel to the nearest segment of a floor plan.

    Attributes
    ----------
    origin_xy: (2,) world xy of the centre of pixel (0, 0), metres.
    resolution_m: pixel size, metres.
    distance_m: (H, W) float32 distances; row v is y, column u is x.
    nearest_segment: (H, W) int32 index (into the segments it was built from) of the segment
        nearest to each pixel (approximate Voronoi of the rasterised segments), or None.
    """

    origin_xy: F64
    resolution_m: float
    distance_m: F32
    nearest_segment: NDArray[np.int32] | None = None

    @classmethod
    def from_segments(
        cls,
        segments: NDArray[np.float64],
        resolution_m: float,
        bounds_xy: tuple[float, float, float, float] | None = None,
        margin_m: float = 3.0,
        with_nearest: bool = False,
    ) -> DistanceField:
        """Rasterise ``segments`` and take the Euclidean distance transform.

        Parameters
        ----------
        segments: (S, 4) ``x1 y1 x2 y2`` metres; S may be 0 (every distance is :data:`FAR_M`).
        resolution_m: pixel size, metres (> 0).
        bounds_xy: ``x_min y_min x_max y_max`` of the field; default the segments' box.
        margin_m: added around ``bounds_xy`` on every side.
        with_nearest: also label every pixel with its nearest segment (``nearest_segment``).
        """
        import cv2

        seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
        if not resolution_m > 0:
            raise RegistrationInputError(f"must be > 0, got {resolution_m}", None, "resolution_m")
        if bounds_xy is None:
            if len(seg) == 0:
                raise RegistrationInputError("no segments and no bounds", None, "segments")
            xy = seg.reshape(-1, 2)
            bounds_xy = (xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max())
        x0, y0 = bounds_xy[0] - margin_m, bounds_xy[1] - margin_m
        width = int(np.ceil((bounds_xy[2] + margin_m - x0) / resolution_m)) + 1
        height = int(np.ceil((bounds_xy[3] + margin_m - y0) / resolution_m)) + 1
        origin = np.array([x0, y0])
        if len(seg) == 0:
            near = np.full((height, width), -1, np.int32) if with_nearest else None
            return cls(origin, float(resolution_m), np.full((height, width), FAR_M, np.float32),
                       near)
        ids = np.full((height, width), -1, dtype=np.int32)
        shift = 4  # sub-pixel bits of cv2.line
        px = np.round((seg.reshape(-1, 2) - origin) / resolution_m * (1 << shift)).astype(np.int64)
        px = px.reshape(-1, 4)
        for k, (a0, b0, a1, b1) in enumerate(px):
            cv2.line(ids, (int(a0), int(b0)), (int(a1), int(b1)), k, 1, cv2.LINE_8, shift)
        canvas = np.where(ids >= 0, 0, 255).astype(np.uint8)
        dist = cv2.distanceTransform(canvas, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        near = None
        if with_nearest:
            # DIST_LABEL_PIXEL numbers the zero pixels 1..Z in row-major order.
            _, lab = cv2.distanceTransformWithLabels(canvas, cv2.DIST_L2, cv2.DIST_MASK_5,
                                                      labelType=cv2.DIST_LABEL_PIXEL)
            zero_ids = ids[canvas == 0]
            near = zero_ids[np.clip(lab, 1, len(zero_ids)) - 1].astype(np.int32)
        return cls(origin, float(resolution_m), (dist * resolution_m).astype(np.float32), near)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.distance_m.shape[0]), int(self.distance_m.shape[1]))

    def to_pixel(self, p_xy: NDArray[np.float64]) -> F64:
        """(M, 2) world xy → (M, 2) continuous pixel coordinates ``(u, v)``."""
        return (np.asarray(p_xy, dtype=np.float64) - self.origin_xy) / self.resolution_m

    def lookup(self, p_xy: NDArray[np.float64], image: F32 | None = None) -> F64:
        """Bilinear lookup of ``image`` (default the distance) at (M, 2) world points.

        Points outside the field get the value of the nearest border pixel plus, for the
        distance itself, their distance to the field's box.
        """
        img = self.distance_m if image is None else image
        uv = self.to_pixel(p_xy).reshape(-1, 2)
        h, w = img.shape
        u = np.clip(uv[:, 0], 0.0, w - 1.000001)
        v = np.clip(uv[:, 1], 0.0, h - 1.000001)
        u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        fu, fv = u - u0, v - v0
        val = ((img[v0, u0] * (1 - fu) + img[v0, u0 + 1] * fu) * (1 - fv)
               + (img[v0 + 1, u0] * (1 - fu) + img[v0 + 1, u0 + 1] * fu) * fv).astype(np.float64)
        if image is None:
            out = np.hypot(uv[:, 0] - u, uv[:, 1] - v) * self.resolution_m
            val = val + out
        return val

    def nearest_at(self, p_xy: NDArray[np.float64]) -> NDArray[np.int64]:
        """(M,) index of the segment nearest to the pixel under each point (clamped to the
        field); needs ``with_nearest``."""
        if self.nearest_segment is None:
            raise ValueError("field built without with_nearest=True")
        uv = np.rint(self.to_pixel(p_xy).reshape(-1, 2)).astype(np.int64)
        h, w = self.nearest_segment.shape
        return self.nearest_segment[np.clip(uv[:, 1], 0, h - 1), np.clip(uv[:, 0], 0, w - 1)]

    def score_map(self, sigma_m: float, truncate: float = 3.0) -> F32:
        """(H, W) robust score ``exp(-d² / 2σ²)``, exactly 0 beyond ``truncate · σ``.

        A point far from every segment (clutter, a wall missing from the BIM) adds nothing, so
        it cannot pull the alignment; a missing as-built wall only removes points.
        """
        d = self.distance_m.astype(np.float64)
        # The exponential only where it is kept (a fine map is mostly far from every wall):
        # the same values, elementwise, as computing it everywhere and zeroing the rest.
        near = ~(d > truncate * sigma_m)
        s = np.zeros(d.shape)
        s[near] = np.exp(-0.5 * (d[near] / sigma_m) ** 2)
        return s.astype(np.float32)


def distance_to_segments(p_xy: NDArray[np.float64], segments: NDArray[np.float64],
                         index: NDArray[np.int64]) -> tuple[F64, F64]:
    """Exact distance of each point to one given segment each.

    Parameters
    ----------
    p_xy: (M, 2) metres; segments: (S, 4); index: (M,) a segment per point.

    Returns
    -------
    (dist (M,), closest (M, 2)).
    """
    # Coordinate by coordinate: the same products and two-term sums as the row-wise
    # ``((p - a) * ab).sum(1)``, ``(ab ** 2).sum(1)`` and ``np.linalg.norm(p - c, axis=1)``
    # (a sum of two is their one addition), with one gather of the segments' rows.
    s = np.take(np.asarray(segments, dtype=np.float64).reshape(-1, 4), index, axis=0)
    p = np.asarray(p_xy, dtype=np.float64).reshape(-1, 2)
    ax, ay = s[:, 0], s[:, 1]
    abx, aby = s[:, 2] - ax, s[:, 3] - ay
    px, py = p[:, 0], p[:, 1]
    u = np.clip(((px - ax) * abx + (py - ay) * aby)
                / np.maximum(abx * abx + aby * aby, 1e-18), 0.0, 1.0)
    c = np.empty((len(s), 2))
    c[:, 0] = ax + u * abx
    c[:, 1] = ay + u * aby
    dx, dy = px - c[:, 0], py - c[:, 1]
    return np.sqrt(dx * dx + dy * dy), c
