"""Map-quality metrics: MME, MPV (no ground truth needed) and NND (needs a reference).

MME and MPV reproduce the ``map-metrics`` 0.0.5 package (Skoltech) to 1e-9:

- the map is the concatenation, in scan order, of every scan mapped into the world by its pose;
- for each map point the neighbours within ``radius`` are gathered (the point itself included,
  distance ``<= radius``); the point is used if the count is **strictly greater** than
  ``min_neighbours``;
- Σ is the unbiased (N − 1) covariance of those neighbours (``np.cov``);
- MME = mean over used points with ``det(2πeΣ) > 0`` of ``½ ln det(2πeΣ)`` (nats; lower is
  sharper);
- MPV = mean over used points of the smallest eigenvalue of Σ (m²).

Covariances are computed in batches relative to each query point (better conditioned than raw
sums of squares), with a scipy ``cKDTree`` for the radius search; memory is bounded by batching
about two million neighbour pairs at a time.

NND follows ConSLAM's ``tools/constrained_RMSE``: distances from each map point to its nearest
neighbour in the reference cloud; by default (:attr:`CutoffMode.EXCLUDE`, ConSLAM's rule) points at
a distance >= the cut-off are left out (counted as ``n_beyond_cutoff``). NND is the mean of the
kept distances; their RMS (ConSLAM's number) is reported beside it. :attr:`CutoffMode.CLAMP`
counts far points as the cut-off instead.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from bimcap.evaluation.errors import EvaluationError

F64 = NDArray[np.float64]

#: Neighbourhood radii (metres) used by the shared oracle / map-metrics examples.
DEFAULT_RADIUS = 0.2
#: A point is used when its neighbour count (itself included) is > this number.
DEFAULT_MIN_NEIGHBOURS = 5
#: NND cut-off in metres.
DEFAULT_NND_CUTOFF = 0.3

_CHUNK_PAIRS = 2_000_000  # neighbour pairs per batch: bounds memory (~150 MB of work arrays)


class CutoffMode(str, enum.Enum):
    """What NND does with points farther than the cut-off from the reference."""

    EXCLUDE = "exclude"
    CLAMP = "clamp"


@dataclass(frozen=True)
class MapMetrics:
    """MME/MPV of one map, optionally NND against a named reference.

    Attributes
    ----------
    mme: mean map entropy, nats (``nan`` if no point had a usable neighbourhood).
    mpv: mean plane variance, m².
    radius_m, min_neighbours: the neighbourhood parameters (count must be > min_neighbours).
    n_points: points in the map; n_used_mpv / n_used_mme: points that entered each mean.
    nnd_m, nnd_rmse_m, nnd_reference, nnd_cutoff_m, nnd_cutoff_mode, n_beyond_cutoff: NND (mean and
    RMS distance) and how it was taken (``None`` when no reference was given).
    """

    mme: float
    mpv: float
    radius_m: float
    min_neighbours: int
    n_points: int
    n_used_mpv: int
    n_used_mme: int
    nnd_m: float | None = None
    nnd_rmse_m: float | None = None
    nnd_reference: str | None = None
    nnd_cutoff_m: float | None = None
    nnd_cutoff_mode: CutoffMode | None = None
    n_beyond_cutoff: int | None = None

    def to_dict(self) -> dict[str, object]:
        def num(x: float | None) -> float | None:
            return None if x is None or not np.isfinite(x) else float(x)

        return {
            "mme": num(self.mme),
            "mpv": num(self.mpv),
            "radius_m": self.radius_m,
            "min_neighbours_exclusive": self.min_neighbours,
            "n_points": self.n_points,
            "n_used_mpv": self.n_used_mpv,
            "n_used_mme": self.n_used_mme,
            "nnd_m": num(self.nnd_m),
            "nnd_rmse_m": num(self.nnd_rmse_m),
            "nnd_reference": self.nnd_reference,
            "nnd_cutoff_m": self.nnd_cutoff_m,
            "nnd_cutoff_mode": None if self.nnd_cutoff_mode is None else self.nnd_cutoff_mode.value,
            "n_beyond_cutoff": self.n_beyond_cutoff,
        }

    def format_table(self) -> str:
        """A plain-text table for the terminal."""
        lines = [
            (
                f"map: {self.n_points} points, radius {self.radius_m:g} m, "
                f"more than {self.min_neighbours} neighbours (unbiased covariance)"
            ),
            f"{'MME [nats]':<18}{self.mme:>12.4f}   ({self.n_used_mme} points)",
            f"{'MPV [m^2]':<18}{self.mpv:>12.6f}   ({self.n_used_mpv} points)",
        ]
        if self.nnd_m is not None:
            mode = self.nnd_cutoff_mode.value if self.nnd_cutoff_mode else "?"
            lines.append(
                f"{'NND [m]':<18}{self.nnd_m:>12.4f}   (RMS {self.nnd_rmse_m:.4f}; reference "
                f"{self.nnd_reference}, cut-off {self.nnd_cutoff_m:g} m, {mode}, "
                f"{self.n_beyond_cutoff} points at or beyond it)"
            )
        return "\n".join(lines)


def _as_points(p: ArrayLike, name: str) -> F64:
    arr = np.asarray(p, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise EvaluationError(f"expected an (N, 3) point array, got shape {arr.shape}", field=name)
    if not np.isfinite(arr).all():
        raise EvaluationError("points must be finite", field=name)
    return arr


def aggregate_map(scans_in_sensor: Sequence[ArrayLike], world_from_sensor: ArrayLike) -> F64:
    """Concatenate scans mapped into the world, in scan order (map-metrics' ``aggregate_map``).

    Parameters
    ----------
    scans_in_sensor: S arrays of shape (N_i, 3), metres, each in its sensor frame.
    world_from_sensor: (S, 4, 4) homogeneous poses.

    Returns
    -------
    (sum N_i, 3) points in the world, metres.
    """
    poses = np.asarray(world_from_sensor, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) != len(scans_in_sensor):
        raise EvaluationError(
            f"need one (4, 4) pose per scan: {len(scans_in_sensor)} scans, poses {poses.shape}"
        )
    parts = []
    for i, (scan, pose) in enumerate(zip(scans_in_sensor, poses, strict=True)):
        p = _as_points(scan, f"scan {i}")
        parts.append(p @ pose[:3, :3].T + pose[:3, 3])
    return np.concatenate(parts, axis=0) if parts else np.zeros((0, 3))


def neighbourhood_covariances(
    points: ArrayLike, radius: float, min_neighbours: int = DEFAULT_MIN_NEIGHBOURS
) -> tuple[NDArray[np.int64], F64]:
    """Unbiased covariance of each point's radius neighbourhood (itself included).

    Parameters
    ----------
    points: (P, 3) metres.
    radius: metres (> 0); neighbours have distance <= radius.
    min_neighbours: keep points whose neighbour count is > min_neighbours (and >= 2).

    Returns
    -------
    (K,) indices of the kept points and their (K, 3, 3) covariances in m².
    """
    pts = _as_points(points, "points")
    if not radius > 0:
        raise EvaluationError(f"radius must be positive, got {radius}")
    tree = cKDTree(pts)
    kept: list[NDArray[np.int64]] = []
    cov_parts: list[F64] = []
    start, batch = 0, 4096
    while start < len(pts):
        q = np.arange(start, min(len(pts), start + batch))
        # all (query, neighbour) pairs of this batch, self pairs included, computed in C
        pairs = cKDTree(pts[q]).sparse_distance_matrix(tree, radius, output_type="ndarray")
        owner = np.ascontiguousarray(pairs["i"])
        d = pts[pairs["j"]] - pts[q][owner]  # offsets from the query point: small numbers
        n = np.bincount(owner, minlength=len(q))
        s1 = np.stack([np.bincount(owner, d[:, a], len(q)) for a in range(3)], axis=1)
        s2 = np.empty((len(q), 3, 3))
        for a in range(3):
            for b in range(a, 3):
                s2[:, a, b] = s2[:, b, a] = np.bincount(owner, d[:, a] * d[:, b], len(q))
        use = (n > min_neighbours) & (n >= 2)
        nf = n[use].astype(np.float64)[:, None, None]
        mean = s1[use] / nf[:, :, 0]
        cov_parts.append((s2[use] - nf * mean[:, :, None] * mean[:, None, :]) / (nf - 1.0))
        kept.append(q[use])
        start += len(q)
        # size the next batch to about _CHUNK_PAIRS neighbour pairs
        batch = max(1, int(_CHUNK_PAIRS * len(q) / max(len(pairs), 1)))
    keep = np.concatenate(kept) if kept else np.zeros(0, dtype=np.int64)
    covs = np.concatenate(cov_parts) if cov_parts else np.zeros((0, 3, 3))
    return keep.astype(np.int64), covs


def map_metrics(
    points: ArrayLike,
    radius: float = DEFAULT_RADIUS,
    min_neighbours: int = DEFAULT_MIN_NEIGHBOURS,
) -> MapMetrics:
    """MME and MPV of a point map (see the module docstring for the exact definitions).

    Parameters
    ----------
    points: (P, 3) map points in the world, metres.
    radius: neighbourhood radius, metres.
    min_neighbours: a point is used when its neighbour count (itself included) is greater.
    """
    pts = _as_points(points, "points")
    _, covs = neighbourhood_covariances(pts, radius, min_neighbours)
    if len(covs) == 0:
        return MapMetrics(float("nan"), float("nan"), radius, min_neighbours, len(pts), 0, 0)
    covs = 0.5 * (covs + np.transpose(covs, (0, 2, 1)))
    smallest = np.linalg.eigvalsh(covs)[:, 0]
    det = np.linalg.det(2.0 * np.pi * np.e * covs)
    ok = det > 0
    mme = float(np.mean(0.5 * np.log(det[ok]))) if ok.any() else float("nan")
    return MapMetrics(
        mme=mme,
        mpv=float(np.mean(smallest)),
        radius_m=float(radius),
        min_neighbours=int(min_neighbours),
        n_points=len(pts),
        n_used_mpv=len(covs),
        n_used_mme=int(ok.sum()),
    )


@dataclass(frozen=True)
class NearestNeighbourDistance:
    """NND of a map against a reference cloud.

    Attributes
    ----------
    mean_m: mean nearest-neighbour distance over the counted points, metres (``nan`` if none).
    rmse_m: root mean square of the same distances, metres: ConSLAM's ``constrained_RMSE`` when
        the mode is EXCLUDE.
    n_beyond_cutoff: points whose distance is >= the cut-off.
    n_points: points of the map.
    """

    mean_m: float
    rmse_m: float
    n_beyond_cutoff: int
    n_points: int


def nearest_neighbour_distance(
    points: ArrayLike,
    reference: ArrayLike,
    cutoff: float = DEFAULT_NND_CUTOFF,
    mode: CutoffMode | str = CutoffMode.EXCLUDE,
) -> NearestNeighbourDistance:
    """NND: distance from each map point to its nearest reference point, with a cut-off.

    ConSLAM's ``tools/constrained_RMSE`` ignores nearest neighbours at a distance >= the threshold
    (0.3 m) and reports ``sqrt(mean d²)`` over the rest; EXCLUDE mode does the same selection and
    reports both the mean (the NND of the paper) and that RMSE.

    Parameters
    ----------
    points: (P, 3) map points, metres.
    reference: (R, 3) reference cloud (the map built with ground-truth poses, or the BIM cloud).
    cutoff: metres (> 0).
    mode: :class:`CutoffMode`: EXCLUDE drops points with ``d >= cutoff``; CLAMP counts them as
        ``cutoff``.
    """
    pts = _as_points(points, "points")
    ref = _as_points(reference, "reference")
    if len(pts) == 0 or len(ref) == 0:
        raise EvaluationError("NND needs non-empty map and reference clouds")
    if not cutoff > 0:
        raise EvaluationError(f"cutoff must be positive, got {cutoff}")
    dist, _ = cKDTree(ref).query(pts, k=1)
    beyond = dist >= cutoff
    used = np.minimum(dist, cutoff) if CutoffMode(mode) is CutoffMode.CLAMP else dist[~beyond]
    if used.size == 0:
        return NearestNeighbourDistance(float("nan"), float("nan"), int(beyond.sum()), len(pts))
    return NearestNeighbourDistance(
        mean_m=float(np.mean(used)),
        rmse_m=float(np.sqrt(np.mean(used**2))),
        n_beyond_cutoff=int(beyond.sum()),
        n_points=len(pts),
    )


def map_metrics_with_reference(
    points: ArrayLike,
    reference: ArrayLike,
    reference_name: str,
    radius: float = DEFAULT_RADIUS,
    min_neighbours: int = DEFAULT_MIN_NEIGHBOURS,
    cutoff: float = DEFAULT_NND_CUTOFF,
    mode: CutoffMode | str = CutoffMode.EXCLUDE,
) -> MapMetrics:
    """MME, MPV and NND (against ``reference``, named ``reference_name`` in the output)."""
    m = map_metrics(points, radius, min_neighbours)
    nnd = nearest_neighbour_distance(points, reference, cutoff, mode)
    return MapMetrics(
        mme=m.mme,
        mpv=m.mpv,
        radius_m=m.radius_m,
        min_neighbours=m.min_neighbours,
        n_points=m.n_points,
        n_used_mpv=m.n_used_mpv,
        n_used_mme=m.n_used_mme,
        nnd_m=nnd.mean_m,
        nnd_rmse_m=nnd.rmse_m,
        nnd_reference=reference_name,
        nnd_cutoff_m=float(cutoff),
        nnd_cutoff_mode=CutoffMode(mode),
        n_beyond_cutoff=nnd.n_beyond_cutoff,
    )


def read_ply_points(path: str | PathLike[str]) -> F64:
    """Read the x, y, z of a PLY point cloud (ASCII or binary) as (P, 3) float64 metres.

    Raises
    ------
    EvaluationError
        If the file is missing, unreadable or holds no points.
    """
    p = Path(path)
    if not p.is_file():
        raise EvaluationError("no such file", p)
    with open(p, "rb") as fh:
        if fh.read(3) != b"ply":
            raise EvaluationError("not a PLY file (no 'ply' magic)", p)
    import open3d as o3d  # heavy; only here

    cloud = o3d.io.read_point_cloud(p, format="ply")
    pts = np.asarray(cloud.points, dtype=np.float64)
    if pts.size == 0:
        raise EvaluationError("no points could be read", p)
    if not np.isfinite(pts).all():
        raise EvaluationError("points must be finite", p, "vertex")
    return pts.reshape(-1, 3)
