"""SIFT features, sequential matching with geometric verification, tracks, keypoint depths.

Everything is in undistorted pinhole pixels (origin at the first pixel centre); pycolmap and
OpenCV are imported inside the functions that need them.
"""

from __future__ import annotations

from bimcap.features.matching import (
    DescriptorProduct,
    MatcherBackend,
    MatchOptions,
    PairMatches,
    Verification,
    match_descriptors,
    match_pair,
    sequential_pairs,
    verify_matches,
)
from bimcap.features.sift import FeatureError, Features, SiftBackend, SiftOptions, extract_sift
from bimcap.features.tracks import (
    DepthEdgePolicy,
    DepthLookupOptions,
    MatchFilterOptions,
    MatchObservations,
    RequireDepth,
    Tracks,
    assemble_match_observations,
    build_tracks,
    consistent_track_observations,
    frame_gap_ok,
    lookup_depth,
    triangulate_tracks,
    unsupported_depths,
)

__all__ = [
    "DepthEdgePolicy",
    "DepthLookupOptions",
    "DescriptorProduct",
    "FeatureError",
    "Features",
    "MatchFilterOptions",
    "MatchObservations",
    "MatchOptions",
    "MatcherBackend",
    "PairMatches",
    "RequireDepth",
    "SiftBackend",
    "SiftOptions",
    "Tracks",
    "Verification",
    "assemble_match_observations",
    "build_tracks",
    "consistent_track_observations",
    "extract_sift",
    "frame_gap_ok",
    "lookup_depth",
    "match_descriptors",
    "match_pair",
    "sequential_pairs",
    "triangulate_tracks",
    "unsupported_depths",
    "verify_matches",
]
