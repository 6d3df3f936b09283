"""Stage methods that run settings name, in a module that imports nothing heavy (the CLI builds
its parser from them without importing the stages)."""

from __future__ import annotations

from enum import Enum


class CompletionMethod(str, Enum):
    """Where a frame's dense depth comes from (``bimcap.fusion.complete_depth`` computes the first
    four; ``bimcap refine --completion`` takes any)."""

    LINEAR = "linear"  #: LiDAR projection + Delaunay interpolation
    CLASSICAL = "classical"  #: LiDAR projection + Ku et al. 2018 style completion
    ONNX = "onnx"  #: LiDAR projection + a CompletionFormer-like ONNX model
    HYBRID = "hybrid"  #: interpolation refined by the ONNX model (the paper's choice)
    GROUND_TRUTH = "ground_truth"  #: the sequence's depth/ (simulated sequences only)

    @property
    def needs_model(self) -> bool:
        """Whether the method runs an ONNX model (``completion_model``)."""
        return self in (CompletionMethod.ONNX, CompletionMethod.HYBRID)


class ExecutorKind(str, Enum):
    """Where the front end's per-frame and per-pair jobs run (``bimcap.frontend.executor``;
    ``bimcap refine --dask`` picks DASK). The solve always runs in the calling process."""

    LOCAL = "local"  #: a pool of processes on this machine (``workers``; 1: this process)
    DASK = "dask"  #: a Dask cluster: a LocalCluster started for the run, or a running scheduler
