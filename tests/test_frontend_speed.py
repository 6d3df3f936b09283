"""The front end's speed-ups (issue 14) give the same arrays, bit for bit, as the code before them
(``tests/_frontend_reference.py``), on the box-room frames run through the whole chain: LiDAR
projection, linear completion, geometric segmentation, planar smoothing, semantic sampling."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

import _frontend_reference as ref
from _fusion_scene import frames
from bimcap.frontend.semantic_map import (
    SamplingMode,
    SemanticSamplingOptions,
    pixel_surface_area,
    sample_semantic_points,
)
from bimcap.fusion import CompletionMethod, CompletionOptions, complete_depth, project_lidar
from bimcap.fusion.completion import smooth_planar_regions
from bimcap.geometry.camera import Camera
from bimcap.segmentation.geometric import segment_geometric


@dataclass
class _Frame:
    camera: Camera  # the pinhole camera of every map
    world_from_cam: np.ndarray  # (7,)
    sparse: object  # bimcap.fusion.SparseDepth
    dense: np.ndarray  # (H, W) float32 linear completion
    labels: np.ndarray  # (H, W) uint8 geometric labels
    smoothed: np.ndarray  # (H, W) float32 after planar smoothing


@pytest.fixture(scope="module")
def chain() -> list[_Frame]:
    out = []
    for f in frames(3) + frames(2, 516, 386, 7):
        cam = f.camera.pinhole()
        sparse = project_lidar(f.points_in_lidar, f.cam_from_lidar, cam)
        dense = np.asarray(complete_depth(sparse, CompletionOptions(CompletionMethod.LINEAR)),
                           np.float32)
        labels = segment_geometric(dense, cam, f.world_from_cam)
        smoothed = smooth_planar_regions(dense, labels, cam)
        out.append(_Frame(cam, f.world_from_cam, sparse, dense, labels, smoothed))
    return out


def test_chain_has_content(chain: list[_Frame]) -> None:
    """The frames exercise every stage (a check that cannot pass on empty maps)."""
    for f in chain:
        assert (f.dense > 0).mean() > 0.5
        assert len(np.unique(f.labels)) >= 3
        assert not np.array_equal(f.smoothed, f.dense)


def test_pixel_surface_area_same_as_before(chain: list[_Frame]) -> None:
    for f in chain:
        for depth in (f.dense, f.smoothed):
            new = pixel_surface_area(depth, f.camera)
            assert np.array_equal(new, ref.pixel_surface_area_reference(depth, f.camera))
    # zeros, edges and a tilted plane, where the gradient's one-sided ends matter
    cam = chain[0].camera
    d = np.zeros((cam.height, cam.width), np.float32)
    d[50:200, 30:300] = 2.0 + np.linspace(0, 1, 270, dtype=np.float32)
    assert np.array_equal(pixel_surface_area(d, cam), ref.pixel_surface_area_reference(d, cam))


def test_semantic_sampling_same_as_before(chain: list[_Frame]) -> None:
    opts = SemanticSamplingOptions(mode=SamplingMode.DENSITY)
    for i, f in enumerate(chain):
        new = sample_semantic_points(f.labels, f.smoothed, f.camera, i, opts)
        old = ref.REFERENCES["semantic sampling"](f.labels, f.smoothed, f.camera, i, opts)
        assert new.keys() == old.keys()
        assert sum(len(v) for v in new.values()) > 100
        for k in new:
            assert np.array_equal(new[k], old[k])
