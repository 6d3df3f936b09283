"""The camera model: pinhole intrinsics with OpenCV plumb_bob (radial-tangential) distortion.

Camera frame: OpenCV optical, x right, y down, z forward. Pixel ``(u, v) = (column, row)`` with
the origin at the **centre** of the top-left pixel (OpenCV's convention).

Distortion (plumb_bob, coefficients ``k1, k2, p1, p2, k3``) of a normalised point ``(x, y)``::

    r2 = x² + y²,  radial = 1 + k1 r2 + k2 r2² + k3 r2³
    x_d = x·radial + 2 p1 x y + p2 (r2 + 2 x²)
    y_d = y·radial + p1 (r2 + 2 y²) + 2 p2 x y
    u = fx x_d + cx,  v = fy y_d + cy
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bimcap.errors import InputError

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Camera:
    """A camera with image size, intrinsics and plumb_bob distortion.

    Attributes
    ----------
    width, height: image size in pixels.
    fx, fy, cx, cy: intrinsics in pixels.
    dist: (5,) plumb_bob coefficients ``k1, k2, p1, p2, k3``; zeros for a pinhole camera.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        vals = [self.fx, self.fy, self.cx, self.cy, *self.dist]
        if len(self.dist) != 5:
            raise InputError(f"expected 5 plumb_bob coefficients, got {len(self.dist)}",
                             field="dist")
        if not np.isfinite(vals).all():
            raise InputError("camera parameters must be finite", field="camera")
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"bad image size {self.width}x{self.height}", field="camera.size")
        if self.fx <= 0 or self.fy <= 0:
            raise InputError("focal lengths must be positive", field="camera.K")

    # ------------------------------------------------------------------ basics
    @property
    def K(self) -> F64:  # noqa: N802  (the usual name)
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def is_distorted(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    @property
    def intrinsics(self) -> F64:
        """(4,) ``[fx, fy, cx, cy]``, the layout the solver takes."""
        return np.array([self.fx, self.fy, self.cx, self.cy])

    def scaled(self, factor: float) -> Camera:
        """The same camera at ``factor`` × the resolution (pixel-centre convention kept)."""
        w = round(self.width * factor)
        h = round(self.height * factor)
        sx, sy = w / self.width, h / self.height
        return Camera(
            w, h, self.fx * sx, self.fy * sy,
            (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, self.dist,
        )

    def pinhole(self) -> Camera:
        """The undistorted camera with the same size and K (what undistorted images use)."""
        return Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy)

    def to_dict(self) -> dict[str, object]:
        return {
            "model": "plumb_bob",
            "width": self.width,
            "height": self.height,
            "K": [self.fx, self.fy, self.cx, self.cy],
            "dist": list(self.dist),
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> Camera:
        try:
            k = d["K"]
            dist_in = d.get("dist", [0.0] * 5)
            if not isinstance(k, list | tuple) or not isinstance(dist_in, list | tuple):
                raise TypeError("K and dist must be lists of numbers")
            fx, fy, cx, cy = (float(x) for x in k)
            if len(dist_in) != 5:
                raise ValueError(f"dist needs 5 coefficients, got {len(dist_in)}")
            k1, k2, p1, p2, k3 = (float(x) for x in dist_in)
            dist = (k1, k2, p1, p2, k3)
            width, height = d["width"], d["height"]
            if (not isinstance(width, int | float | str)
                    or not isinstance(height, int | float | str)):
                raise TypeError("width and height must be numbers")
            return cls(int(width), int(height), fx, fy, cx, cy, dist)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"malformed camera: {exc}", field="camera") from None

    # ------------------------------------------------------------- distortion
    def distort_normalized(self, xy: ArrayLike) -> F64:
        """Apply plumb_bob to normalised points (M, 2) → distorted normalised points (M, 2)."""
        k1, k2, p1, p2, k3 = self.dist
        p = np.asarray(xy, dtype=np.float64)
        x, y = p[..., 0], p[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort_normalized(self, xy_d: ArrayLike, iterations: int = 20) -> F64:
        """Invert plumb_bob by fixed-point iteration (as OpenCV's undistortPoints does).

        Converges to < 1e-10 for the moderate distortion of real lenses within the image.
        """
        k1, k2, p1, p2, k3 = self.dist
        pd = np.asarray(xy_d, dtype=np.float64)
        x, y = pd[..., 0].copy(), pd[..., 1].copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x = (pd[..., 0] - dx) / radial
            y = (pd[..., 1] - dy) / radial
        return np.stack([x, y], axis=-1)

    # ------------------------------------------------------ project / unproject
    def project(self, p_in_cam: ArrayLike, distort: bool = True) -> tuple[F64, NDArray[np.bool_]]:
        """Project camera-frame points (M, 3) to pixels.

        Returns
        -------
        uv: (M, 2) pixel coordinates (NaN where z <= 0).
        in_front: (M,) bool, z > 0.
        """
        p = np.asarray(p_in_cam, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        in_front = z > 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[:, :2] / np.where(in_front, z, np.nan)[:, None]
        if distort and self.is_distorted:
            xy = self.distort_normalized(xy)
        uv = np.empty_like(xy)
        uv[:, 0] = self.fx * xy[:, 0] + self.cx
        uv[:, 1] = self.fy * xy[:, 1] + self.cy
        return uv, in_front

    def in_image(self, uv: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
        """(M,) bool: pixel inside ``[-0.5, W-0.5) × [-0.5, H-0.5)`` shrunk by ``margin``."""
        q = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        with np.errstate(invalid="ignore"):
            return (
                (q[:, 0] >= -0.5 + margin)
                & (q[:, 0] < self.width - 0.5 - margin)
                & (q[:, 1] >= -0.5 + margin)
                & (q[:, 1] < self.height - 0.5 - margin)
            )

    def rays(self, uv: ArrayLike, distorted: bool = True) -> F64:
        """Camera-frame ray directions (M, 3) with z = 1 through pixels ``uv`` (M, 2)."""
        q = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        xy = np.stack([(q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy], axis=-1)
        if distorted and self.is_distorted:
            xy = self.undistort_normalized(xy)
        return np.concatenate([xy, np.ones((len(xy), 1))], axis=1)

    def backproject(self, uv: ArrayLike, depth: ArrayLike, distorted: bool = True) -> F64:
        """Camera-frame points (M, 3) at z-depth ``depth`` (M,) metres through pixels ``uv``."""
        return self.rays(uv, distorted) * np.asarray(depth, dtype=np.float64).reshape(-1, 1)

    def pixel_grid(self) -> F64:
        """(H·W, 2) pixel centres in row-major order, ``(u, v) = (column, row)``."""
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        return np.stack([u.ravel(), v.ravel()], axis=-1).astype(np.float64)
