"""The front end as one run: per-frame fusion → segmentation → features → semantic map, cached.

``run_frontend(sequence, config, init_traj, depth_provider, label_provider, cache_dir, workers)``
returns a :class:`FrontendResult` whose ``to_problem_arrays()`` are the solver's observations.
"""

from __future__ import annotations

from bimcap.frontend.cache import ResultCache, file_fingerprint, frame_cache_key, stable_hash
from bimcap.frontend.errors import FrontendError, FrontendInputError
from bimcap.frontend.executor import ExecutorOptions, SchedulerUnreachableError
from bimcap.frontend.providers import (
    LidarDepthProvider,
    PlanarDepthRefiner,
    SegmenterLabelProvider,
)
from bimcap.frontend.runner import (
    DepthProvider,
    DepthRefiner,
    FrameContext,
    FrameStats,
    FrontendConfig,
    FrontendResult,
    GroundTruthDepthProvider,
    GroundTruthLabelProvider,
    LabelProvider,
    PairStats,
    RunStats,
    SequenceLike,
    Undistorter,
    run_frontend,
)
from bimcap.frontend.semantic_map import (
    SEMANTIC_CLASSES,
    SamplingMode,
    SemanticMap,
    SemanticMapError,
    SemanticSamplingOptions,
    build_semantic_map,
    read_semantic_ply,
    sample_semantic_points,
    write_semantic_ply,
)

__all__ = [
    "SEMANTIC_CLASSES",
    "DepthProvider",
    "DepthRefiner",
    "ExecutorOptions",
    "FrameContext",
    "FrameStats",
    "FrontendConfig",
    "FrontendError",
    "FrontendInputError",
    "FrontendResult",
    "GroundTruthDepthProvider",
    "GroundTruthLabelProvider",
    "LabelProvider",
    "LidarDepthProvider",
    "PairStats",
    "PlanarDepthRefiner",
    "ResultCache",
    "RunStats",
    "SamplingMode",
    "SchedulerUnreachableError",
    "SegmenterLabelProvider",
    "SemanticMap",
    "SemanticMapError",
    "SemanticSamplingOptions",
    "SequenceLike",
    "Undistorter",
    "build_semantic_map",
    "file_fingerprint",
    "frame_cache_key",
    "read_semantic_ply",
    "run_frontend",
    "sample_semantic_points",
    "stable_hash",
    "write_semantic_ply",
]
