"""The LiDAR scan's samples outside the camera's view, added to a front-end result.

The front end keeps each scan's oriented surface points outside the camera's view
(``scan_*`` arrays of :class:`~bimcap.frontend.runner.FrontendResult`, pose-free, cached).
:func:`with_scan_samples` classifies them at given poses (their up direction;
:func:`bimcap.fusion.scan.classify_scan_points`) and appends them to the result's wall, floor and
ceiling samples, so that every later stage (coarse registration, global alignment, the solver's
W / F / Ce terms, observability) takes them like labelled pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.frontend.semantic_map import SEMANTIC_CLASSES
from bimcap.fusion.scan import ScanSamplingOptions, classify_scan_points
from bimcap.labels import Label

F64 = NDArray[np.float64]

#: The classes the scan gives samples of.
SCAN_CLASSES = (Label.WALL, Label.FLOOR, Label.CEILING)


@dataclass
class ScanSampleStats:
    """How many samples the scans added per class (over every frame)."""

    wall: int = 0
    floor: int = 0
    ceiling: int = 0

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def frames_without_matches(frontend: Any) -> NDArray[np.int64]:
    """The frames no feature match or track observation links to another frame (sorted)."""
    linked = np.zeros(frontend.num_frames, bool)
    linked[np.asarray(frontend.match_frames, np.int64).ravel()] = True
    linked[np.asarray(frontend.track_obs_frame, np.int64).ravel()] = True
    return np.flatnonzero(~linked)


def with_scan_samples(frontend: Any, world_from_cam: F64,
                      options: ScanSamplingOptions | None = None,
                      frames: NDArray[np.integer] | None = None) -> tuple[Any, ScanSampleStats]:
    """``frontend`` with each frame's classified scan points appended after its pixel samples.

    Parameters
    ----------
    frontend: a :class:`~bimcap.frontend.runner.FrontendResult` (its ``scan_*`` arrays).
    world_from_cam: (N, 7) poses; only their up direction matters.
    options: the classification's settings (tilt, height, per-frame caps).
    frames: only these frames' scans (None: every frame's).
    """
    opts = options or ScanSamplingOptions()
    poses = np.asarray(world_from_cam, np.float64)
    frame = np.asarray(frontend.scan_frame)
    bounds = np.searchsorted(frame, np.arange(frontend.num_frames + 1))
    added: dict[Label, list[tuple[int, F64]]] = {lab: [] for lab in SCAN_CLASSES}
    chosen = np.unique(frame) if frames is None else np.intersect1d(np.unique(frame), frames)
    for i in chosen:
        sl = slice(bounds[i], bounds[i + 1])
        per_class = classify_scan_points(frontend.scan_p_in_cam[sl], frontend.scan_n_in_cam[sl],
                                         poses[i], int(i), opts)
        for lab in SCAN_CLASSES:
            added[lab].append((int(i), per_class[lab]))
    changes: dict[str, Any] = {}
    stats = ScanSampleStats()
    for lab, per_frame in added.items():
        prefix = SEMANTIC_CLASSES[lab]
        frames = [np.asarray(getattr(frontend, f"{prefix}_frame"))]
        points = [np.asarray(getattr(frontend, f"{prefix}_p_in_cam"))]
        frames += [np.full(len(p), i, np.int32) for i, p in per_frame]
        points += [p for _, p in per_frame]
        f = np.concatenate(frames)
        order = np.argsort(f, kind="stable")  # frame by frame: its pixels, then its scan
        changes[f"{prefix}_frame"] = f[order]
        changes[f"{prefix}_p_in_cam"] = np.concatenate(points)[order]
        setattr(stats, prefix, int(sum(len(p) for _, p in per_frame)))
    return replace(frontend, **changes), stats
