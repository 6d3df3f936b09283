"""The front end over a whole sequence: per-frame work in parallel, cached, then assembly.

Per frame (in worker processes): load the raw image, undistort it to ``camera.pinhole()`` (same
K, no distortion; the undistortion map is computed with :class:`bimcap.geometry.Camera` itself,
the reference for the distortion model), get dense depth and labels from the pluggable providers
(in the undistorted image), extract SIFT, look up each keypoint's depth, subsample the labelled
pixels. Per pair of frames within the window: match descriptors and verify geometrically.
In the main process: tracks, the peers' filters, initial landmarks and the solver's arrays
(:class:`FrontendResult`).

Providers are callables ``provider(ctx: FrameContext) -> (H, W) array`` in undistorted pinhole
pixels: depth float32 metres (0 = unknown), labels uint8 :class:`bimcap.labels.Label` ids. The
depth provider runs first; the label provider sees its result in ``ctx.depth``; an optional
``depth_refiner(ctx, labels) -> depth`` runs last (the paper's floor/ceiling smoothing). They must
be picklable (module-level classes or dataclasses) to run in worker processes.

Cache: three kinds of entries, so that a change redoes only what depends on it.
``features`` (SIFT) depend on the image file, the camera and the SIFT settings; ``pair`` entries
on the two frames' feature keys and the matching settings; ``frame`` entries (depth, labels →
keypoint depths, semantic samples) on all of the frame's files, the providers, the look-up and
sampling settings, and the frame's initial pose if a provider declares ``uses_pose = True`` (the
no-weights segmenter takes gravity from it) or the sampling checks the labels against the depth
(``SemanticSamplingOptions.orientation_check_deg``, gravity again). A provider may define
``cache_token`` (a string that changes whenever its output would); otherwise its class name and
``repr`` are used, which for a dataclass includes its settings. The match filters, tracks and
landmarks are recomputed on every run (they are cheap and depend on the initial poses).
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, Protocol, TypeVar, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.features.matching import MatchOptions, PairMatches, match_pair, sequential_pairs
from bimcap.features.pair_chain import PairChainOptions, chain_inconsistent_pairs
from bimcap.features.sift import Features, SiftOptions, extract_sift
from bimcap.features.tracks import (
    DepthLookupOptions,
    MatchFilterOptions,
    assemble_match_observations,
    build_tracks,
    consistent_track_observations,
    lookup_depth,
    triangulate_tracks,
    unsupported_depths,
)
from bimcap.frontend.cache import ResultCache, frame_cache_key, stable_hash
from bimcap.frontend.errors import FrontendError as FrontendError
from bimcap.frontend.errors import FrontendInputError as FrontendInputError
from bimcap.frontend.executor import (
    ExecutorOptions,
    check_scheduler,
    cluster_threads,
    dask_client,
    require_distributed,
)
from bimcap.frontend.heap import callers_heap, keep_freed_heap
from bimcap.frontend.semantic_map import (
    SEMANTIC_CLASSES,
    SampleSource,
    SemanticMap,
    SemanticSamplingOptions,
    build_semantic_map,
    check_label_orientation,
    sample_semantic_points,
    write_semantic_ply,
)
from bimcap.fusion.scan import ScanSamplingOptions, scan_surface_points
from bimcap.geometry.camera import Camera
from bimcap.geometry.trajectory import Trajectory, validate_poses
from bimcap.io.atomic import atomic_write_bytes
from bimcap.labels import Label
from bimcap.methods import ExecutorKind
from bimcap.progress import progress as progress_bar

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]
T = TypeVar("T")
_log = logging.getLogger(__name__)

#: Version of the .npz layout written by :meth:`FrontendResult.save`.
RESULT_FORMAT_VERSION = 1


# --------------------------------------------------------------------------- sequence & context
@runtime_checkable
class SequenceLike(Protocol):
    """What the front end needs of a sequence (``bimcap.dataset.Sequence`` provides it).

    ``camera`` is the raw (distorted) camera; ``load_image(i)`` returns (H, W, 3) uint8 RGB of the
    raw image; ``frames[i]`` names frame i's files (attributes ``image``, ``lidar``, ``labels``,
    ``depth``, relative to the sequence directory ``root``/``path``); these files key the cache.
    The ground-truth providers also use ``load_depth(i)`` / ``load_labels(i)``, the LiDAR one
    ``load_lidar(i)`` and ``cam_from_lidar``.
    """

    camera: Camera

    @property
    def frames(self) -> Sequence[Any]: ...

    def load_image(self, index: int) -> NDArray[np.uint8]: ...


class Undistorter:
    """Resamples raw images and maps into the undistorted pinhole image of the same K.

    The map sends each pinhole pixel to the raw pixel that sees the same ray, computed with
    :meth:`Camera.project` (the project's reference distortion model), and is applied with
    ``cv2.remap`` (bilinear for images, nearest for depth and labels, which must not be blended
    across edges).
    """

    def __init__(self, camera: Camera) -> None:
        self.camera = camera
        self.pinhole = camera.pinhole()
        self._map: tuple[NDArray[np.float32], NDArray[np.float32]] | None = None
        if camera.is_distorted:
            rays = self.pinhole.rays(self.pinhole.pixel_grid(), distorted=False)
            uv_raw, _ = camera.project(rays, distort=True)
            shape = (camera.height, camera.width)
            self._map = (
                uv_raw[:, 0].reshape(shape).astype(np.float32),
                uv_raw[:, 1].reshape(shape).astype(np.float32),
            )

    def _remap(self, arr: NDArray[Any], nearest: bool) -> NDArray[Any]:
        if self._map is None:
            return np.array(arr, copy=True)
        import cv2

        interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        return cv2.remap(
            arr, self._map[0], self._map[1], interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        )

    def image(self, image: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """(H, W, 3) or (H, W) uint8 raw image → undistorted (bilinear; black outside)."""
        return self._remap(np.ascontiguousarray(image), nearest=False)

    def nearest(self, arr: NDArray[Any]) -> NDArray[Any]:
        """(H, W) depth or label map of the raw image → undistorted (nearest; 0 outside)."""
        a = np.ascontiguousarray(arr)
        if a.dtype == np.float64:
            a = a.astype(np.float32)
        return self._remap(a, nearest=True)


_UNDISTORTERS: dict[Camera, Undistorter] = {}


def get_undistorter(camera: Camera) -> Undistorter:
    """A per-process cached :class:`Undistorter` for ``camera``."""
    und = _UNDISTORTERS.get(camera)
    if und is None:
        und = _UNDISTORTERS[camera] = Undistorter(camera)
    return und


@dataclass
class FrameContext:
    """What a depth or label provider gets for one frame.

    Attributes
    ----------
    sequence: the sequence (load the frame's LiDAR, labels, depth ... from it).
    index: frame index.
    camera: the raw (distorted) camera.
    pinhole: the undistorted camera every output is in.
    image: (H, W, 3) uint8 undistorted RGB image.
    undistorter: resamples raw-image maps into the pinhole image.
    world_from_cam: (7,) TUM-order initial pose of the frame.
    depth: (H, W) float32 dense depth once the depth provider has run (None before).
    measured_depth: (H, W) float32 depth of the sensor's own returns at their pixels (0
        elsewhere), set by depth providers that have them (the LiDAR's z-buffer); None when the
        provider has no such thing (ground truth, a learned model alone).

    The frame's LiDAR scan and its range noise are read and measured once, on first use
    (:meth:`lidar`, :meth:`range_noise_m`), for every stage that needs them.
    """

    sequence: Any
    index: int
    camera: Camera
    pinhole: Camera
    image: NDArray[np.uint8]
    undistorter: Undistorter
    world_from_cam: NDArray[np.float64]
    depth: NDArray[np.float32] | None = None
    measured_depth: NDArray[np.float32] | None = None
    _lidar: NDArray[np.floating] | None = field(default=None, repr=False, compare=False)
    _range_noise: tuple[float | None] | None = field(default=None, repr=False, compare=False)

    def lidar(self) -> NDArray[np.floating]:
        """The frame's scan ``sequence.load_lidar(index)`` (M, ≥3) sensor-frame metres, read
        on the first call; the same array afterwards (do not modify it)."""
        if self._lidar is None:
            self._lidar = self.sequence.load_lidar(self.index)
        return self._lidar

    def range_noise_m(self) -> float | None:
        """The scan's range noise σ in metres
        (:func:`bimcap.segmentation.geometric.scan_range_noise` of :meth:`lidar`; None when it
        cannot be measured), computed on the first call."""
        if self._range_noise is None:
            from bimcap.segmentation.geometric import scan_range_noise

            self._range_noise = (scan_range_noise(self.lidar()),)
        return self._range_noise[0]


class DepthProvider(Protocol):
    """``provider(ctx) -> (H, W) float32`` z-depth in metres (0 = unknown), pinhole pixels."""

    def __call__(self, ctx: FrameContext) -> NDArray[np.floating]: ...


class LabelProvider(Protocol):
    """``provider(ctx) -> (H, W) uint8`` :class:`bimcap.labels.Label` ids, pinhole pixels."""

    def __call__(self, ctx: FrameContext) -> NDArray[np.integer]: ...


class DepthRefiner(Protocol):
    """``refiner(ctx, labels) -> (H, W) float32`` depth refined with the labels (``ctx.depth``)."""

    def __call__(self, ctx: FrameContext, labels: NDArray[np.integer]) -> NDArray[np.floating]: ...


@dataclass(frozen=True)
class GroundTruthDepthProvider:
    """Depth from the sequence's ``depth/`` files (simulator ground truth), undistorted."""

    def __call__(self, ctx: FrameContext) -> NDArray[np.float32]:
        loaded = ctx.sequence.load_depth(ctx.index)
        if loaded is None:
            raise FrontendInputError(
                f"frame {ctx.index} has no ground-truth depth file", None,
                f"frames[{ctx.index}].depth",
            )
        raw = np.asarray(loaded, dtype=np.float32)
        _check_map(raw, ctx.camera, ctx.index, "depth")
        return ctx.undistorter.nearest(raw)


@dataclass(frozen=True)
class GroundTruthLabelProvider:
    """Labels from the sequence's ``labels/`` files (simulator ground truth), undistorted."""

    def __call__(self, ctx: FrameContext) -> NDArray[np.uint8]:
        loaded = ctx.sequence.load_labels(ctx.index)
        if loaded is None:
            raise FrontendInputError(
                f"frame {ctx.index} has no label image", None, f"frames[{ctx.index}].labels"
            )
        raw = np.asarray(loaded)
        _check_map(raw, ctx.camera, ctx.index, "labels")
        return ctx.undistorter.nearest(raw.astype(np.uint8))


def _check_map(arr: NDArray[Any], camera: Camera, index: int, what: str,
               path: object = None) -> None:
    if arr.shape[:2] != (camera.height, camera.width) or arr.ndim != 2:
        raise FrontendInputError(
            f"frame {index}: {what} has shape {arr.shape}, the camera is "
            f"{camera.width}x{camera.height} (expected ({camera.height}, {camera.width}))",
            path,  # type: ignore[arg-type]
            f"frames[{index}].{what}",
        )


def provider_token(provider: object) -> str:
    """The cache token of a provider: its ``cache_token`` or class name + ``repr``."""
    tok = getattr(provider, "cache_token", None)
    if tok is not None:
        return str(tok() if callable(tok) else tok)
    cls = type(provider)
    return f"{cls.__module__}.{cls.__qualname__}:{provider!r}"


def uses_pose(provider: object) -> bool:
    """True if the provider's output depends on the frame's initial pose (``uses_pose``)."""
    return bool(getattr(provider, "uses_pose", False))


def frame_input_files(sequence: Any, index: int) -> dict[str, Path]:
    """The files frame ``index`` is computed from, by role (they key the cache).

    The ``image``, ``lidar``, ``labels`` and ``depth`` entries of ``sequence.frames[index]``
    (attributes or dict keys) that are not None, resolved against the sequence directory
    (``sequence.root`` or ``sequence.path``) when relative.
    """
    frame = sequence.frames[index]
    root = None
    for name in ("root", "path", "directory"):
        val = getattr(sequence, name, None)
        if isinstance(val, (str, PathLike)):
            root = Path(val)
            break
    out: dict[str, Path] = {}
    for attr in ("image", "lidar", "labels", "depth"):
        val = frame.get(attr) if isinstance(frame, dict) else getattr(frame, attr, None)
        if val is None:
            continue
        p = Path(val)
        if not p.is_absolute() and root is not None:
            p = root / p
        out[attr] = p
    if "image" not in out:
        raise FrontendError(
            f"cannot tell which image file frame {index} comes from (frames[{index}].image); "
            "run without a cache directory"
        )
    return out


# --------------------------------------------------------------------------- config & result
@dataclass(frozen=True)
class FrontendConfig:
    """Settings of the whole front end.

    Attributes
    ----------
    sift: feature extraction.
    match: descriptor matching and geometric verification of one pair.
    window: match each frame with the next ``window`` frames.
    filters: the peers' filters on pairwise matches (gap, initial 3-D distance, depth).
    depth_lookup: validity check of keypoint depths.
    sampling: subsampling of labelled pixels into semantic samples.
    scan: the oriented surface points of each LiDAR scan outside the camera's view
        (:func:`bimcap.fusion.scan.scan_surface_points`); None: none. Sequences without a
        LiDAR give none either way.
    min_track_length: observations per track (>= 2).
    pair_chain: drop the pairs whose relative pose contradicts the chain of consecutive pairs
        between their frames (a repeated texture matched on another wall,
        :mod:`bimcap.features.pair_chain`); None keeps every pair (the peers' front end).
    """

    sift: SiftOptions = field(default_factory=SiftOptions)
    match: MatchOptions = field(default_factory=MatchOptions)
    window: int = 5
    filters: MatchFilterOptions = field(default_factory=MatchFilterOptions)
    depth_lookup: DepthLookupOptions = field(default_factory=DepthLookupOptions)
    sampling: SemanticSamplingOptions = field(default_factory=SemanticSamplingOptions)
    scan: ScanSamplingOptions | None = field(default_factory=ScanSamplingOptions)
    min_track_length: int = 2
    pair_chain: PairChainOptions | None = field(default_factory=PairChainOptions)

    def __post_init__(self) -> None:
        if self.window < 1:
            raise FrontendError(f"window must be >= 1, got {self.window}")
        if self.min_track_length < 2:
            raise FrontendError(f"min_track_length must be >= 2, got {self.min_track_length}")

    def to_dict(self) -> dict[str, object]:
        return {
            "sift": self.sift.to_dict(),
            "match": self.match.to_dict(),
            "window": self.window,
            "filters": self.filters.to_dict(),
            "depth_lookup": self.depth_lookup.to_dict(),
            "sampling": self.sampling.to_dict(),
            "scan": None if self.scan is None else self.scan.to_dict(),
            "min_track_length": self.min_track_length,
            "pair_chain": None if self.pair_chain is None else self.pair_chain.to_dict(),
        }


@dataclass
class FrameStats:
    """Per-frame numbers: keypoints, keypoints with depth, semantic samples, the frame's total
    time and its SIFT time (0 when the features came from the cache), cache hit."""

    index: int
    num_keypoints: int
    num_keypoints_with_depth: int
    num_floor: int
    num_ceiling: int
    num_wall: int
    num_column: int
    time_s: float
    sift_time_s: float
    cached: bool
    num_scan: int = 0


@dataclass
class PairStats:
    """Per-pair numbers: putative and verified matches, the verified model, cache hit."""

    frame_a: int
    frame_b: int
    num_putative: int
    num_verified: int
    model: str
    time_s: float
    cached: bool


@dataclass
class RunStats:
    """What one run did: what it computed rather than took from the cache.

    ``features_computed``: frames whose SIFT ran; ``frames_computed``: frames whose depth,
    labels, keypoint depths and samples were computed; ``pairs_computed``: pairs matched.
    ``workers``: jobs run at once (processes of the local pool, threads of the Dask cluster);
    ``executor``: where they ran (:class:`bimcap.methods.ExecutorKind` value).
    """

    features_computed: int = 0
    frames_computed: int = 0
    pairs_computed: int = 0
    wall_time_s: float = 0.0
    workers: int = 1
    executor: str = ExecutorKind.LOCAL.value


#: The solver's observation arrays the front end fills (docs/architecture.md), name → dtype.
OBSERVATION_ARRAYS: dict[str, type] = {
    "match_frames": np.int32,
    "match_uv": np.float64,
    "match_depth": np.float64,
    "track_obs_frame": np.int32,
    "track_obs_point": np.int32,
    "track_obs_uv": np.float64,
    "track_obs_depth": np.float64,
    "track_points": np.float64,
    **{f"{p}_frame": np.int32 for p in SEMANTIC_CLASSES.values()},
    **{f"{p}_p_in_cam": np.float64 for p in SEMANTIC_CLASSES.values()},
}

#: The scans' oriented surface points outside the camera's view (not solver arrays: they become
#: W / F / Ce samples once classified at some poses, :mod:`bimcap.frontend.scan_samples`).
SCAN_ARRAYS: dict[str, type] = {
    "scan_frame": np.int32,
    "scan_p_in_cam": np.float64,
    "scan_n_in_cam": np.float64,
}


@dataclass
class FrontendResult:
    """The front end's output for one sequence, in undistorted pinhole pixels of ``camera``.

    Attributes
    ----------
    camera: the pinhole camera (``raw_camera.pinhole()``) all pixels refer to.
    num_frames: N.
    match_frames (M, 2) int32, match_uv (M, 4) ``[ua, va, ub, vb]``, match_depth (M, 2) metres.
    track_obs_frame (K,) int32, track_obs_point (K,) int32, track_obs_uv (K, 2),
    track_obs_depth (K,) metres (0 = none), track_points (P, 3) world, from the initial poses.
    floor_frame (F,) int32, floor_p_in_cam (F, 3) metres; likewise ceiling_*, wall_*, column_*.
    scan_frame (R,) int32, scan_p_in_cam (R, 3) metres, scan_n_in_cam (R, 3) unit normals: the
    scans' surface points outside the camera's view (empty without a LiDAR).
    frame_stats, pair_stats, run: statistics; config: the settings as a dict.
    """

    camera: Camera
    num_frames: int
    match_frames: I32
    match_uv: F64
    match_depth: F64
    track_obs_frame: I32
    track_obs_point: I32
    track_obs_uv: F64
    track_obs_depth: F64
    track_points: F64
    floor_frame: I32
    floor_p_in_cam: F64
    ceiling_frame: I32
    ceiling_p_in_cam: F64
    wall_frame: I32
    wall_p_in_cam: F64
    column_frame: I32
    column_p_in_cam: F64
    scan_frame: I32 = field(default_factory=lambda: np.zeros(0, np.int32))
    scan_p_in_cam: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    scan_n_in_cam: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    frame_stats: list[FrameStats] = field(default_factory=list)
    pair_stats: list[PairStats] = field(default_factory=list)
    run: RunStats = field(default_factory=RunStats)
    config: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, dtype in {**OBSERVATION_ARRAYS, **SCAN_ARRAYS}.items():
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=dtype))
        for name in ("scan_p_in_cam", "scan_n_in_cam"):
            setattr(self, name, getattr(self, name).reshape(-1, 3))

    def to_problem_arrays(self) -> dict[str, NDArray[Any]]:
        """The solver's arrays by their names: the observations plus ``cameras (1, 4)`` and
        ``frame_camera (N,) int32`` (every frame uses the one pinhole camera)."""
        out: dict[str, NDArray[Any]] = {n: getattr(self, n) for n in OBSERVATION_ARRAYS}
        out["cameras"] = self.camera.intrinsics.reshape(1, 4).copy()
        out["frame_camera"] = np.zeros(self.num_frames, np.int32)
        return out

    def semantic_samples(self) -> dict[Label, tuple[I32, F64]]:
        """Per class ``(frame (n,), p_in_cam (n, 3))``."""
        return {
            lab: (getattr(self, f"{p}_frame"), getattr(self, f"{p}_p_in_cam"))
            for lab, p in SEMANTIC_CLASSES.items()
        }

    def semantic_map(self, world_from_cam: F64) -> SemanticMap:
        """The semantic samples moved into the world with ``world_from_cam`` (N, 7)."""
        return build_semantic_map(self.semantic_samples(), np.asarray(world_from_cam))

    def write_semantic_map(self, path: str | PathLike[str], world_from_cam: F64) -> SemanticMap:
        """Write the semantic map under ``world_from_cam`` as a labelled PLY (atomically)."""
        smap = self.semantic_map(world_from_cam)
        write_semantic_ply(path, smap.points, smap.labels)
        return smap

    def to_dict(self) -> dict[str, object]:
        """Summary for JSON: counts, per-frame and per-pair statistics, settings."""
        return {
            "camera": self.camera.to_dict(),
            "num_frames": self.num_frames,
            "num_matches": len(self.match_frames),
            "num_track_points": len(self.track_points),
            "num_track_observations": len(self.track_obs_frame),
            **{f"num_{p}": len(getattr(self, f"{p}_frame")) for p in SEMANTIC_CLASSES.values()},
            "num_scan": len(self.scan_frame),
            "run": asdict(self.run),
            "frame_stats": [asdict(s) for s in self.frame_stats],
            "pair_stats": [asdict(s) for s in self.pair_stats],
            "config": self.config,
        }

    def save(self, path: str | PathLike[str]) -> None:
        """Write all arrays and the statistics to one ``.npz`` file, atomically."""
        import io

        meta = {
            "format": "bimcap-frontend",
            "version": RESULT_FORMAT_VERSION,
            **self.to_dict(),
        }
        arrays = {n: getattr(self, n) for n in (*OBSERVATION_ARRAYS, *SCAN_ARRAYS)}
        buf = io.BytesIO()
        np.savez(buf, meta_json=np.array(json.dumps(meta)), **arrays)
        atomic_write_bytes(os.fspath(path), buf.getvalue())

    @classmethod
    def load(cls, path: str | PathLike[str]) -> FrontendResult:
        """Read a file written by :meth:`save`; raises :class:`FrontendInputError` if malformed."""
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError) as exc:
            raise FrontendInputError(f"cannot read front-end result: {exc}", path) from None
        if "meta_json" not in data:
            raise FrontendInputError("not a bimcap front-end result", path, "meta_json")
        meta = json.loads(str(data["meta_json"]))
        if meta.get("format") != "bimcap-frontend" or meta.get("version") != RESULT_FORMAT_VERSION:
            raise FrontendInputError(
                f"unsupported format {meta.get('format')!r} version {meta.get('version')!r}",
                path,
                "meta_json",
            )
        missing = [n for n in (*OBSERVATION_ARRAYS, *SCAN_ARRAYS) if n not in data]
        if missing:
            raise FrontendInputError(f"missing arrays {missing}", path)
        return cls(
            camera=Camera.from_dict(meta["camera"]),
            num_frames=int(meta["num_frames"]),
            **{n: data[n] for n in (*OBSERVATION_ARRAYS, *SCAN_ARRAYS)},
            frame_stats=[FrameStats(**s) for s in meta["frame_stats"]],
            pair_stats=[PairStats(**s) for s in meta["pair_stats"]],
            run=RunStats(**meta["run"]),
            config=meta["config"],
        )


# --------------------------------------------------------------------------- per-frame work
@dataclass
class _RunShared:
    """What every frame job of one run shares; sent once to each worker (pool initializer)."""

    sequence: Any
    config: FrontendConfig
    depth_provider: Any
    label_provider: Any
    depth_refiner: Any


@dataclass
class _WorkerSlot:
    """The run's shared state inside one worker process."""

    shared: _RunShared | None = None


#: Inside a worker process only: set once by the pool initializer (:func:`_init_worker`), so
#: that the sequence and providers travel once per worker, not once per job. ``run_frontend``
#: hands the shared state to the jobs it runs in its own process explicitly and never sets it.
_WORKER = _WorkerSlot()


def _init_worker(shared: _RunShared) -> None:
    _WORKER.shared = shared


@dataclass
class _FrameJob:
    index: int
    world_from_cam: F64
    features: dict[str, NDArray[Any]] | None  # cached SIFT of this frame, or None to extract
    maps_dir: Path | None = None  # write the frame's undistorted depth and labels here


def map_paths(maps_dir: str | PathLike[str], index: int) -> tuple[Path, Path]:
    """``(depth .npy, labels .png)`` written for frame ``index`` under ``maps_dir``."""
    root = Path(maps_dir)
    return root / "depth" / f"{index:06d}.npy", root / "labels" / f"{index:06d}.png"


def _write_maps(maps_dir: Path, index: int, depth: NDArray[np.float32],
                labels: NDArray[Any]) -> None:
    import io

    import cv2

    depth_path, label_path = map_paths(maps_dir, index)
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(depth, dtype=np.float32))
    atomic_write_bytes(depth_path, buf.getvalue())
    ok, png = cv2.imencode(".png", np.ascontiguousarray(labels, dtype=np.uint8))
    if not ok:  # pragma: no cover - cv2 encodes any uint8 image
        raise FrontendError(f"cannot encode the labels of frame {index}")
    atomic_write_bytes(label_path, png.tobytes())


def _load_raw_image(sequence: Any, index: int, camera: Camera) -> NDArray[np.uint8]:
    try:
        img = np.asarray(sequence.load_image(index))
    except InputError:
        raise
    except (OSError, IndexError, KeyError) as exc:
        raise FrontendInputError(
            f"cannot load image of frame {index}: {exc}", None, f"frames[{index}].image"
        ) from None
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise FrontendInputError(
            f"frame {index}: expected an 8-bit RGB image, got {img.dtype} {img.shape}",
            None,
            f"frames[{index}].image",
        )
    if img.shape[:2] != (camera.height, camera.width):
        raise FrontendInputError(
            f"frame {index}: image is {img.shape[1]}x{img.shape[0]}, the camera is "
            f"{camera.width}x{camera.height}",
            None,
            f"frames[{index}].image",
        )
    return img


FEATURE_ARRAYS = ("uv", "scale", "orientation", "descriptors")


@contextmanager
def one_thread() -> Iterator[None]:
    """BLAS (every OpenBLAS / MKL loaded, ``threadpoolctl``) and OpenCV on one thread for the
    block, as they were after it.

    The front end's parallelism is one job a core (processes, or Dask threads); BLAS and OpenCV
    threads inside a job only compete with the other jobs, and small products cost about 3× the
    CPU time with OpenBLAS's threads than on one (a 3000 × 150 RANSAC score table, when numpy
    formed it: 8 vs 2.5 ms on the 2-core box; docs/speed.md). The results are the same bit for
    bit: these libraries split a product's output, not its sums, across threads
    (``tests/test_frontend_speed.py`` compares a whole front end both ways).
    """
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with _threadpools().limit(limits=1):
            yield
    finally:
        cv2.setNumThreads(before)


@contextmanager
def job_settings() -> Iterator[None]:
    """This process as the front end's jobs run: its freed heap kept for the next job
    (:func:`bimcap.frontend.heap.keep_freed_heap`; not in the process that called
    :func:`run_frontend`), BLAS and OpenCV on one thread for the block (:func:`one_thread`)."""
    keep_freed_heap()
    with one_thread():
        yield


#: This process's ``threadpoolctl.ThreadpoolController`` and ``len(sys.modules)`` when it was made.
_THREADPOOLS: tuple[int, Any] | None = None


def _threadpools() -> Any:
    """The ``threadpoolctl.ThreadpoolController`` of this process's loaded libraries, made again
    only when modules were imported since the last one (a new native library comes with its
    module). Making one scans every loaded shared library (~1.2 ms; ``threadpool_limits`` made
    one on each call, 4–5 a frame); limiting through it is ~0.02 ms. It reads and restores the
    libraries' thread counts on each use, as ``threadpool_limits`` does."""
    global _THREADPOOLS
    from threadpoolctl import ThreadpoolController

    loaded = len(sys.modules)
    if _THREADPOOLS is None or _THREADPOOLS[0] != loaded:
        _THREADPOOLS = (loaded, ThreadpoolController())
    return _THREADPOOLS[1]


def compute_frame(job: _FrameJob, *, shared: _RunShared | None = None
                  ) -> dict[str, NDArray[Any]]:
    """All per-frame work for one frame.

    ``shared`` is the run's sequence, settings and providers; None takes this worker
    process's (set by the pool initializer).

    Returns the SIFT arrays (``uv, scale, orientation, descriptors``; extracted unless
    ``job.features`` holds them), the keypoint depths ``depth``, the semantic samples
    ``<class>_p_in_cam`` and the timings ``time_s`` / ``sift_time_s``.

    Runs in :func:`job_settings` (BLAS and OpenCV on one thread, the freed heap kept).
    """
    with job_settings():
        return _compute_frame(job, shared)


def _compute_frame(job: _FrameJob, shared: _RunShared | None) -> dict[str, NDArray[Any]]:
    """:func:`compute_frame`."""
    t0 = time.perf_counter()
    if shared is None:
        shared = _WORKER.shared
    if shared is None:  # pragma: no cover - passed by run_frontend / set by the pool initializer
        raise FrontendError("compute_frame called outside run_frontend")
    seq, i, cfg = shared.sequence, job.index, shared.config
    camera: Camera = seq.camera
    und = get_undistorter(camera)
    image = und.image(_load_raw_image(seq, i, camera))
    ctx = FrameContext(seq, i, camera, und.pinhole, image, und, np.asarray(job.world_from_cam))
    depth = np.asarray(shared.depth_provider(ctx), dtype=np.float32)
    _check_map(depth, und.pinhole, i, "depth (from the depth provider)")
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    ctx.depth = depth
    labels = np.asarray(shared.label_provider(ctx))
    _check_map(labels, und.pinhole, i, "labels (from the label provider)")
    if shared.depth_refiner is not None:
        depth = np.asarray(shared.depth_refiner(ctx, labels), dtype=np.float32)
        _check_map(depth, und.pinhole, i, "depth (from the depth refiner)")
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
        ctx.depth = depth
    if job.maps_dir is not None:
        _write_maps(job.maps_dir, i, depth, labels)
    t1 = time.perf_counter()
    if job.features is None:
        f = extract_sift(image, cfg.sift)
        feats = {"uv": f.uv, "scale": f.scale, "orientation": f.orientation,
                 "descriptors": f.descriptors}
        sift_time = time.perf_counter() - t1
    else:
        feats = {k: job.features[k] for k in FEATURE_ARRAYS}
        sift_time = 0.0
    kp_depth = lookup_depth(depth, np.asarray(feats["uv"]), cfg.depth_lookup)
    measured = ctx.measured_depth
    noise = ctx.range_noise_m() if measured is not None else None
    if measured is not None and noise is not None:
        # a depth the returns around the keypoint contradict (a plane fitted off the wall) is
        # none: G keeps the match's other direction
        kp_depth[unsupported_depths(depth, measured, np.asarray(feats["uv"]), noise,
                                    cfg.depth_lookup)] = 0.0
    # The BIM terms' samples come from the completed depth, or from the returns themselves
    # (SampleSource.RETURNS) when the provider has them: no interpolation across edges.
    sample_depth = depth
    if cfg.sampling.source is SampleSource.RETURNS and ctx.measured_depth is not None:
        sample_depth = np.asarray(ctx.measured_depth, np.float32)
        _check_map(sample_depth, und.pinhole, i, "measured depth (from the depth provider)")
    checked, _ = check_label_orientation(labels, depth, und.pinhole, ctx.world_from_cam,
                                         cfg.sampling)
    samples = sample_semantic_points(checked, sample_depth, und.pinhole, i, cfg.sampling)
    out: dict[str, NDArray[Any]] = {**feats, "depth": kp_depth}
    for lab, prefix in SEMANTIC_CLASSES.items():
        out[f"{prefix}_p_in_cam"] = samples[lab]
    out["scan_p_in_cam"], out["scan_n_in_cam"] = _scan_points(ctx, cfg.scan)
    out["sift_time_s"] = np.array(sift_time)
    out["time_s"] = np.array(time.perf_counter() - t0)
    return out


def _scan_points(ctx: FrameContext, options: ScanSamplingOptions | None) -> tuple[F64, F64]:
    """The frame's scan surface points outside the view (empty without options or LiDAR)."""
    seq, i = ctx.sequence, ctx.index
    has_scan = getattr(seq.frames[i], "lidar", None) is not None
    if options is None or not has_scan or not hasattr(seq, "cam_from_lidar"):
        return np.zeros((0, 3)), np.zeros((0, 3))
    scan = np.asarray(ctx.lidar())
    if scan.ndim != 2 or scan.shape[1] < 3 or len(scan) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    # the voxel grows with the scan's own range noise (ScanSamplingOptions.for_noise)
    options = options.for_noise(ctx.range_noise_m())
    return scan_surface_points(scan, seq.cam_from_lidar, ctx.pinhole, options)


@dataclass
class _PairJob:
    feats_a: Features
    feats_b: Features
    camera: Camera
    frame_a: int
    frame_b: int
    options: MatchOptions


def compute_pair(job: _PairJob) -> dict[str, NDArray[Any]]:
    """Match and verify one pair (in :func:`job_settings`); returns the arrays that the cache
    stores."""
    t0 = time.perf_counter()
    with job_settings():
        pm = match_pair(job.feats_a, job.feats_b, job.camera, job.frame_a, job.frame_b,
                        job.options)
    return {
        "idx": pm.idx,
        "num_putative": np.array(pm.num_putative),
        "model": np.array(pm.model),
        "time_s": np.array(time.perf_counter() - t0),
    }


def _features_of(arrays: dict[str, NDArray[Any]]) -> Features:
    return Features(arrays["uv"], arrays["scale"], arrays["orientation"], arrays["descriptors"])


# --------------------------------------------------------------------------- pool
def _submit(pool: Executor | None, fn: Callable[..., T], job: Any, **kwargs: Any) -> Future[T]:
    """``fn(job, **kwargs)`` in the pool, or run now in this process as a finished future."""
    if pool is not None:
        return pool.submit(fn, job, **kwargs)
    fut: Future[T] = Future()
    try:
        fut.set_result(fn(job, **kwargs))
    except BaseException as exc:  # re-raised by fut.result() in the caller, like the pool does
        fut.set_exception(exc)
    return fut


# --------------------------------------------------------------------------- the runner
def run_frontend(
    sequence: SequenceLike,
    config: FrontendConfig | None,
    init_traj: Trajectory | F64,
    depth_provider: DepthProvider,
    label_provider: LabelProvider,
    cache_dir: str | PathLike[str] | None = None,
    workers: int | None = None,
    progress: bool = True,
    depth_refiner: DepthRefiner | None = None,
    maps_dir: str | PathLike[str] | None = None,
    executor: ExecutorOptions | Any | None = None,
) -> FrontendResult:
    """Run the front end over a whole sequence.

    Parameters
    ----------
    sequence: the sequence (raw camera, frames, images).
    config: settings; None for the defaults.
    init_traj: initial ``world_from_cam`` poses, a Trajectory or (N, 7) TUM-order array, one per
        frame (for the distance filter, the initial landmarks, and providers that use the pose).
    depth_provider, label_provider: dense depth and labels per frame (see the module doc).
    cache_dir: folder of the cache; None disables caching.
    workers: processes (default ``os.cpu_count()``); 1 runs everything in this process. Workers
        are started with ``spawn``: a script that calls this must do so under
        ``if __name__ == "__main__":``.
    progress: False: no progress bar; True: one on a terminal while bimcap logs at INFO
        (:mod:`bimcap.progress`).
    depth_refiner: optional ``refiner(ctx, labels) -> depth`` run after the labels.
    maps_dir: if given, each frame's final undistorted depth (``depth/NNNNNN.npy``, float32
        metres) and labels (``labels/NNNNNN.png``) are written there (atomically; see
        :func:`map_paths`); a cached frame whose maps are missing is recomputed. On a Dask
        cluster of several machines it must be the same path on a shared filesystem.
    executor: where the frame and pair jobs run (:mod:`bimcap.frontend.executor`): None or
        ``ExecutorOptions()`` for the local pool of ``workers`` processes; an
        ``ExecutorOptions(kind=ExecutorKind.DASK)`` for a Dask cluster that this call starts
        (a LocalCluster, closed before it returns or raises) or connects to (``scheduler``);
        or a ``distributed.Client`` of the caller's (left open). The same jobs run either way
        and give the same result bit for bit; the cache, the assembly stay in this process.

    Returns
    -------
    FrontendResult in the pinhole camera ``sequence.camera.pinhole()``.

    Raises
    ------
    FrontendInputError
        A missing or unreadable frame, an image or map whose size does not match the camera,
        initial poses that do not match the frames.
    SchedulerUnreachableError
        The Dask scheduler of ``executor`` does not answer (checked before any work).
    """
    t_start = time.perf_counter()
    cfg = config or FrontendConfig()
    pinhole = sequence.camera.pinhole()
    init = _initial_poses(sequence, init_traj)
    nworkers = _worker_count(workers)
    if isinstance(executor, ExecutorOptions) and executor.is_dask:
        require_distributed()
        if executor.scheduler is not None:
            check_scheduler(executor.scheduler, executor.connect_timeout_s)
    ctx = _RunContext(
        shared=_RunShared(sequence, cfg, depth_provider, label_provider, depth_refiner),
        init=init,
        pinhole=pinhole,
        cache=ResultCache(cache_dir),
        maps_dir=None if maps_dir is None else Path(maps_dir),
        stats=RunStats(workers=nworkers),
    )
    frames = _frames_from_cache(ctx)
    pairs = _pairs_from_cache(ctx, frames.feat_keys)
    num_jobs = len(frames.todo) + sum(not c for c in pairs.cached)
    with ExitStack() as stack:  # closes the pool / cluster however the run ends
        stack.enter_context(callers_heap())  # jobs run here leave this process's heap alone
        backend = _open_backend(stack, ctx.shared, executor, nworkers, num_jobs)
        ctx.stats.workers, ctx.stats.executor = backend.workers, backend.kind.value
        bar = stack.enter_context(progress_bar(total=num_jobs, desc="front end", unit="job",
                                               enabled=progress))
        _Scheduler(ctx, frames, pairs, backend).run(bar)
    frames_ok = [d for d in frames.data if d is not None]
    pair_list, pair_stats = _pair_matches(pairs)
    result = _assemble(cfg, pinhole, init, frames_ok, pair_list)
    result.frame_stats = _frame_stats(frames_ok, frames.cached)
    result.pair_stats = pair_stats
    ctx.stats.wall_time_s = time.perf_counter() - t_start
    result.run = ctx.stats
    _log.debug(f"front end: {len(frames.todo)} frame and {num_jobs - len(frames.todo)} pair jobs "
               f"run, the rest from the cache, on {backend.workers} {backend.kind.value} "
               f"worker(s), {ctx.stats.wall_time_s:.1f} s")
    return result


@dataclass
class _RunContext:
    """What the steps of one run share."""

    shared: _RunShared  # sequence, settings and providers (what the frame jobs need)
    init: F64  # (N, 7) initial world_from_cam, TUM order
    pinhole: Camera  # the undistorted camera of every output
    cache: ResultCache
    maps_dir: Path | None  # where the frames' final depth and labels go, if anywhere
    stats: RunStats  # what the run computed (filled in as it goes)


@dataclass
class _FrameSlots:
    """Per frame: its arrays once known, and what the cache gave."""

    data: list[dict[str, NDArray[Any]] | None]  # (N,) the frame's arrays (None until known)
    cached: list[bool]  # (N,) taken whole from the cache
    cached_feats: list[dict[str, NDArray[Any]] | None]  # (N,) cached SIFT of a frame to compute
    todo: list[int]  # frames to compute, in order
    feat_keys: list[str]  # (N,) cache keys of the features (empty without a cache)
    frame_keys: list[str]  # (N,) cache keys of the frame entries (empty without a cache)


@dataclass
class _PairSlots:
    """Per pair of frames within the window: its arrays once known, and what the cache gave."""

    pairs: list[tuple[int, int]]  # (P,) frame indices (a, b), a < b
    results: list[dict[str, NDArray[Any]] | None]  # (P,) the pair's arrays (None until known)
    cached: list[bool]  # (P,) taken from the cache
    keys: list[str]  # (P,) cache keys (empty without a cache)
    of_frame: list[list[int]]  # (N,) per frame, the pairs to match that use it


def _initial_poses(sequence: SequenceLike, init_traj: Trajectory | F64) -> F64:
    """(N, 7) initial poses, checked: finite, unit quaternions, one per frame."""
    num = len(sequence.frames)
    if num == 0:
        raise FrontendInputError("the sequence has no frames", None, "frames")
    init = np.asarray(
        init_traj.poses if isinstance(init_traj, Trajectory) else init_traj, dtype=np.float64
    )
    validate_poses(init, field="init_traj")
    if len(init) != num:
        raise FrontendInputError(f"{len(init)} initial poses for {num} frames", None, "init_traj")
    return init


def _worker_count(workers: int | None) -> int:
    """The number of processes: ``workers``, default ``os.cpu_count()``; at least 1."""
    nworkers = int(workers if workers is not None else (os.cpu_count() or 1))
    if nworkers < 1:
        raise FrontendError(f"workers must be >= 1, got {workers}")
    return nworkers


def _frame_cache_keys(ctx: _RunContext) -> tuple[list[str], list[str]]:
    """Per frame, the cache keys of its features and of its frame entry (module docstring)."""
    shared, cfg = ctx.shared, ctx.shared.config
    providers = (shared.depth_provider, shared.label_provider, shared.depth_refiner)
    pose_dependent = any(uses_pose(p) for p in providers if p is not None)
    # the label check takes gravity from the initial pose
    pose_dependent |= cfg.sampling.orientation_check_deg is not None
    feat_settings = {"camera": shared.sequence.camera.to_dict(), "sift": cfg.sift.to_dict()}
    frame_settings = {
        "depth_lookup": cfg.depth_lookup.to_dict(),
        "sampling": cfg.sampling.to_dict(),
        "scan": None if cfg.scan is None else cfg.scan.to_dict(),
        "depth_provider": provider_token(shared.depth_provider),
        "label_provider": provider_token(shared.label_provider),
        "depth_refiner": (None if shared.depth_refiner is None
                          else provider_token(shared.depth_refiner)),
    }
    feat_keys: list[str] = []
    frame_keys: list[str] = []
    for i in range(len(ctx.init)):
        files = frame_input_files(shared.sequence, i)
        fk = frame_cache_key([files["image"]], feat_settings)
        feat_keys.append(fk)
        extra: dict[str, object] = {"index": i, "features": fk}
        if pose_dependent:
            extra["world_from_cam"] = [float(x) for x in ctx.init[i]]
        frame_keys.append(frame_cache_key(list(files.values()), {**frame_settings, **extra}))
    return feat_keys, frame_keys


def _frames_from_cache(ctx: _RunContext) -> _FrameSlots:
    """The frames the cache holds whole (with their maps, if asked for), the cached features
    of the others, and the frames to compute."""
    num = len(ctx.init)
    cache = ctx.cache
    feat_keys, frame_keys = _frame_cache_keys(ctx) if cache.enabled else ([], [])
    frames = _FrameSlots(data=[None] * num, cached=[False] * num, cached_feats=[None] * num,
                         todo=[], feat_keys=feat_keys, frame_keys=frame_keys)
    for i in range(num):
        if cache.enabled:
            hit = cache.get("frame", frame_keys[i])
            feats_hit = cache.get("features", feat_keys[i])
            maps_there = (ctx.maps_dir is None
                          or all(p.is_file() for p in map_paths(ctx.maps_dir, i)))
            if hit is not None and feats_hit is not None and maps_there:
                frames.data[i] = {**hit, **feats_hit}
                frames.cached[i] = True
                continue
            frames.cached_feats[i] = feats_hit
        frames.todo.append(i)
    return frames


def _pairs_from_cache(ctx: _RunContext, feat_keys: list[str]) -> _PairSlots:
    """The pairs within the window, those the cache holds, and per frame the pairs to match."""
    num = len(ctx.init)
    cfg = ctx.shared.config
    pair_list = sequential_pairs(num, cfg.window)
    pair_settings = {"camera": ctx.shared.sequence.camera.to_dict(), "match": cfg.match.to_dict()}
    pairs = _PairSlots(pairs=pair_list, results=[None] * len(pair_list),
                       cached=[False] * len(pair_list), keys=[],
                       of_frame=[[] for _ in range(num)])
    for k, (a, b) in enumerate(pair_list):
        if ctx.cache.enabled:
            key = stable_hash({"a": feat_keys[a], "b": feat_keys[b], **pair_settings})
            pairs.keys.append(key)
            hit = ctx.cache.get("pair", key)
            if hit is not None:
                pairs.results[k], pairs.cached[k] = hit, True
                continue
        pairs.of_frame[a].append(k)
        pairs.of_frame[b].append(k)
    return pairs


@dataclass
class _Backend:
    """Where the jobs of one run execute.

    Attributes
    ----------
    pool: None runs each job at once in this process; else a ``concurrent.futures`` executor:
        the local process pool, or a Dask client's (``Client.get_executor``).
    frame_kwargs: :func:`compute_frame`'s keyword arguments: ``shared`` itself in this process,
        the Dask future of the state scattered to every worker once (Dask hands each job the
        worker's copy), nothing in the local pool (its initializer set it per process).
    workers: jobs that run at once (processes, or threads of the Dask cluster).
    kind: the executor.
    died: exceptions that mean a worker process died (not the job's own error).
    """

    pool: Executor | None
    frame_kwargs: dict[str, Any]
    workers: int
    kind: ExecutorKind
    died: tuple[type[BaseException], ...] = ()

    @property
    def limit(self) -> int:
        """Jobs in flight at most: 2 per worker (1 in this process)."""
        return 1 if self.pool is None else 2 * self.workers


def _open_backend(stack: ExitStack, shared: _RunShared, executor: ExecutorOptions | Any | None,
                  nworkers: int, num_jobs: int) -> _Backend:
    """The run's :class:`_Backend`; its pool, cluster and scattered state are released by
    ``stack``. Nothing is started (no pool, no LocalCluster) when there is nothing to compute."""
    is_client = executor is not None and not isinstance(executor, ExecutorOptions)
    if num_jobs == 0:
        dask = is_client or (isinstance(executor, ExecutorOptions) and executor.is_dask)
        return _Backend(None, {"shared": shared}, nworkers,
                        ExecutorKind.DASK if dask else ExecutorKind.LOCAL)
    if is_client:
        return _dask_backend(stack, shared, executor)  # the caller's distributed.Client
    if isinstance(executor, ExecutorOptions) and executor.is_dask:
        return _dask_backend(stack, shared, stack.enter_context(dask_client(executor, nworkers)))
    pool = _start_pool(shared, nworkers, num_jobs)
    if pool is None:
        return _Backend(None, {"shared": shared}, nworkers, ExecutorKind.LOCAL)
    stack.callback(pool.shutdown, wait=True, cancel_futures=True)
    return _Backend(pool, {}, nworkers, ExecutorKind.LOCAL, (BrokenProcessPool,))


def _dask_backend(stack: ExitStack, shared: _RunShared, client: Any) -> _Backend:
    """Jobs on ``client``'s cluster: the shared state goes to every worker once (scatter with
    broadcast; a job names it by its future), the jobs through ``Client.get_executor``."""
    from distributed import KilledWorker

    shared_future = client.scatter(shared, broadcast=True, hash=False)
    stack.callback(shared_future.release)
    pool = client.get_executor(pure=False)
    stack.callback(pool.shutdown, wait=False)  # cancels what is still queued after an error
    return _Backend(pool, {"shared": shared_future}, cluster_threads(client), ExecutorKind.DASK,
                    (KilledWorker,))


def _start_pool(shared: _RunShared, nworkers: int, num_jobs: int) -> ProcessPoolExecutor | None:
    """A pool of ``spawn`` workers for ``num_jobs`` jobs, or None to run them in this process."""
    if not (nworkers > 1 and num_jobs > 1):
        return None
    # spawn, not fork: forking a process whose BLAS / pycolmap threads are running can
    # deadlock. The sequence and providers travel once per worker, not once per job.
    return ProcessPoolExecutor(
        max_workers=min(nworkers, num_jobs),
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(shared,),
    )


class _Scheduler:
    """Runs the frame and pair jobs of one run and stores their results (and the cache's).

    Frames and pairs share one queue: a pair is submitted as soon as both of its frames have
    features (pairs first, so that descriptors can be released early: a frame keeps only
    keypoints, depths and samples once all of its pairs are matched). At most ``limit`` jobs
    (2 × workers) are in flight, so that finished frames do not wait behind the whole frame list.
    """

    def __init__(self, ctx: _RunContext, frames: _FrameSlots, pairs: _PairSlots,
                 backend: _Backend) -> None:
        self.ctx, self.frames, self.pairs, self.backend = ctx, frames, pairs, backend
        self.limit = backend.limit
        self.ready = [d is not None for d in frames.data]
        self.pairs_left = [len(p) for p in pairs.of_frame]
        self.frame_queue = deque(frames.todo)
        self.pair_queue: deque[int] = deque(
            k for k, (a, b) in enumerate(pairs.pairs)
            if not pairs.cached[k] and self.ready[a] and self.ready[b]
        )
        self.in_flight: dict[Future[dict[str, NDArray[Any]]], tuple[str, int]] = {}
        for i in range(len(frames.data)):
            self.release(i)

    def release(self, i: int) -> None:
        """Drop frame ``i``'s descriptors once it is ready and all of its pairs are matched."""
        d = self.frames.data[i]
        if d is not None and self.ready[i] and self.pairs_left[i] == 0:
            for name in ("descriptors", "scale", "orientation"):
                d.pop(name, None)

    def run(self, bar: Any) -> None:
        """Submit and collect jobs until every frame and pair is done."""
        while self.frame_queue or self.pair_queue or self.in_flight:
            self._submit_ready()
            done, _ = wait(list(self.in_flight), return_when=FIRST_COMPLETED)
            for fut in done:
                kind, n = self.in_flight.pop(fut)
                res = self._result(fut, kind, n)
                bar.update()
                if kind == "frame":
                    self._frame_done(n, res)
                else:
                    self._pair_done(n, res)

    def _submit_ready(self) -> None:
        """Fill the in-flight slots: ready pairs first, then frames."""
        while len(self.in_flight) < self.limit and (self.pair_queue or self.frame_queue):
            if self.pair_queue:
                k = self.pair_queue.popleft()
                a, b = self.pairs.pairs[k]
                fa, fb = self.frames.data[a], self.frames.data[b]
                assert fa is not None and fb is not None
                pjob = _PairJob(_features_of(fa), _features_of(fb), self.ctx.pinhole, a, b,
                                self.ctx.shared.config.match)
                self.in_flight[_submit(self.backend.pool, compute_pair, pjob)] = ("pair", k)
            else:
                i = self.frame_queue.popleft()
                fjob = _FrameJob(i, self.ctx.init[i], self.frames.cached_feats[i],
                                 self.ctx.maps_dir)
                fut = _submit(self.backend.pool, compute_frame, fjob, **self.backend.frame_kwargs)
                self.in_flight[fut] = ("frame", i)

    def _result(self, fut: Future[dict[str, NDArray[Any]]], kind: str, n: int
                ) -> dict[str, NDArray[Any]]:
        """The job's arrays; a dead worker process becomes a :class:`FrontendError`."""
        try:
            return fut.result()
        except self.backend.died as exc:
            what = self.pairs.pairs[n] if kind == "pair" else n
            if self.backend.kind is ExecutorKind.DASK:
                raise FrontendError(
                    f"Dask workers died while computing {kind} {what} ({exc}; out of memory? "
                    "the workers' logs say why)") from exc
            raise FrontendError(
                f"a worker process died while computing {kind} {what} "
                "(out of memory, or a script that calls run_frontend without an "
                "`if __name__ == '__main__':` guard, which the spawn start method needs); "
                "run with workers=1 to see the error"
            ) from exc

    def _frame_done(self, i: int, res: dict[str, NDArray[Any]]) -> None:
        """Store frame ``i`` (and cache it), queue its pairs whose frames are both ready."""
        frames, ctx = self.frames, self.ctx
        frames.data[i] = res
        self.ready[i] = True
        ctx.stats.frames_computed += 1
        if frames.cached_feats[i] is None:
            ctx.stats.features_computed += 1
        if ctx.cache.enabled:
            if frames.cached_feats[i] is None:
                ctx.cache.put("features", frames.feat_keys[i],
                              {k: res[k] for k in FEATURE_ARRAYS})
            ctx.cache.put("frame", frames.frame_keys[i],
                          {k: v for k, v in res.items() if k not in FEATURE_ARRAYS})
        frames.cached_feats[i] = None  # not needed any more
        for k in self.pairs.of_frame[i]:
            a, b = self.pairs.pairs[k]
            if self.ready[a] and self.ready[b]:
                self.pair_queue.append(k)
        self.release(i)

    def _pair_done(self, k: int, res: dict[str, NDArray[Any]]) -> None:
        """Store pair ``k`` (and cache it); release its frames' descriptors when done with."""
        self.pairs.results[k] = res
        self.ctx.stats.pairs_computed += 1
        if self.ctx.cache.enabled:
            self.ctx.cache.put("pair", self.pairs.keys[k], res)
        for f in self.pairs.pairs[k]:
            self.pairs_left[f] -= 1
            self.release(f)


def _pair_matches(pairs: _PairSlots) -> tuple[list[PairMatches], list[PairStats]]:
    """The verified matches and statistics of every pair, in pair order."""
    pair_list: list[PairMatches] = []
    pair_stats: list[PairStats] = []
    for k, ((a, b), r) in enumerate(zip(pairs.pairs, pairs.results, strict=True)):
        assert r is not None
        pm = PairMatches(
            a, b, np.asarray(r["idx"], np.int32).reshape(-1, 2), int(r["num_putative"]),
            str(r["model"]),
        )
        pair_list.append(pm)
        pair_stats.append(PairStats(a, b, pm.num_putative, len(pm.idx), pm.model,
                                    float(r["time_s"]), pairs.cached[k]))
    return pair_list, pair_stats


def _frame_stats(frames: list[dict[str, NDArray[Any]]], cached: list[bool]) -> list[FrameStats]:
    """Per-frame statistics of the frames' arrays."""
    return [
        FrameStats(
            index=i,
            num_keypoints=len(d["uv"]),
            num_keypoints_with_depth=int((d["depth"] > 0).sum()),
            **{f"num_{p}": len(d[f"{p}_p_in_cam"]) for p in SEMANTIC_CLASSES.values()},
            time_s=float(d["time_s"]),
            sift_time_s=float(d["sift_time_s"]),
            cached=cached[i],
            num_scan=len(d["scan_p_in_cam"]),
        )
        for i, d in enumerate(frames)
    ]


def _assemble(
    cfg: FrontendConfig,
    pinhole: Camera,
    init: F64,
    frames: list[dict[str, NDArray[Any]]],
    pairs: list[PairMatches],
) -> FrontendResult:
    """Flatten per-frame and per-pair results into the solver's arrays."""
    uvs = [np.asarray(d["uv"], np.float64).reshape(-1, 2) for d in frames]
    depths = [np.asarray(d["depth"], np.float64).reshape(-1) for d in frames]
    if cfg.pair_chain is not None:
        check = chain_inconsistent_pairs(pairs, uvs, depths, pinhole, cfg.pair_chain)
        if check.dropped:
            _log.info(f"{len(check.dropped)} pair(s) of frames contradict the chain of "
                      f"consecutive pairs between them (a repeated texture?) and are dropped: "
                      + ", ".join(f"{a}-{b} ({px:.0f} px)" for (a, b), px
                                  in zip(check.dropped, check.median_px, strict=True)))
            bad = set(check.dropped)
            pairs = [p for p in pairs if (p.frame_a, p.frame_b) not in bad]
    obs = assemble_match_observations(pairs, uvs, depths, pinhole, init, cfg.filters)
    tracks = build_tracks([len(u) for u in uvs], pairs, cfg.min_track_length)
    t_uv = np.zeros((len(tracks.obs_frame), 2))
    t_depth = np.zeros(len(tracks.obs_frame))
    for f in np.unique(tracks.obs_frame):
        sel = tracks.obs_frame == f
        t_uv[sel] = uvs[f][tracks.obs_keypoint[sel]]
        t_depth[sel] = depths[f][tracks.obs_keypoint[sel]]
    t_frame, t_point = tracks.obs_frame, tracks.obs_point
    if cfg.filters.max_initial_distance_m is not None and len(t_point):
        # The pairwise distance filter's analogue: drop observations far from their track.
        keep = consistent_track_observations(
            t_frame, t_point, t_uv, t_depth, pinhole, init, cfg.filters.max_initial_distance_m
        )
        keep &= (np.bincount(t_point[keep], minlength=tracks.num_points)[t_point]
                 >= cfg.min_track_length)
        _, t_point = np.unique(t_point[keep], return_inverse=True)
        t_point = t_point.astype(np.int32).reshape(-1)
        t_frame, t_uv, t_depth = t_frame[keep], t_uv[keep], t_depth[keep]
    points, valid = triangulate_tracks(t_frame, t_point, t_uv, t_depth, pinhole, init)
    # Drop landmarks without a usable initial position and renumber the rest.
    keep_obs = valid[t_point] if len(valid) else np.zeros(0, bool)
    new_id = np.cumsum(valid) - 1
    sem: dict[str, NDArray[Any]] = {}
    for prefix in SEMANTIC_CLASSES.values():
        pts = [np.asarray(d[f"{prefix}_p_in_cam"], np.float64).reshape(-1, 3) for d in frames]
        sem[f"{prefix}_frame"] = np.concatenate(
            [np.full(len(p), i, np.int32) for i, p in enumerate(pts)]
        ) if pts else np.zeros(0, np.int32)
        sem[f"{prefix}_p_in_cam"] = np.concatenate(pts) if pts else np.zeros((0, 3))
    scan = [np.asarray(d["scan_p_in_cam"], np.float64).reshape(-1, 3) for d in frames]
    sem["scan_frame"] = np.concatenate(
        [np.full(len(p), i, np.int32) for i, p in enumerate(scan)]) if scan else np.zeros(0)
    sem["scan_p_in_cam"] = np.concatenate(scan) if scan else np.zeros((0, 3))
    sem["scan_n_in_cam"] = (np.concatenate([np.asarray(d["scan_n_in_cam"], np.float64)
                                            .reshape(-1, 3) for d in frames])
                            if frames else np.zeros((0, 3)))
    return FrontendResult(
        camera=pinhole,
        num_frames=len(frames),
        match_frames=obs.match_frames,
        match_uv=obs.match_uv,
        match_depth=obs.match_depth,
        track_obs_frame=t_frame[keep_obs],
        track_obs_point=new_id[t_point[keep_obs]] if len(valid) else np.zeros(0, np.int32),
        track_obs_uv=t_uv[keep_obs],
        track_obs_depth=t_depth[keep_obs],
        track_points=points[valid],
        config=cfg.to_dict(),
        **sem,
    )

