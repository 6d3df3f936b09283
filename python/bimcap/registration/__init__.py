"""Coarse registration to the BIM (before bundle adjustment): bring frames or windows of frames
near the right pose using the floor plan and the floor/ceiling planes alone.

Public API: :func:`coarse_register` with :class:`CoarseOptions`, :class:`SemanticSamples`,
:class:`FloorPlan` → :class:`CoarseResult`; the refinement :class:`Schedule` that follows it;
:func:`global_align` (:class:`GlobalAlignOptions` → :class:`GlobalAlignResult`) for a trajectory
in a SLAM system's own frame, before the coarse stage.
OpenCV is imported only when a distance field is built.
"""

from __future__ import annotations

from bimcap.registration.coarse import (
    CoarseOptions,
    CoarseResult,
    FloorPlan,
    SemanticSamples,
    WindowResult,
    coarse_register,
)
from bimcap.registration.errors import (
    AmbiguousAlignmentError,
    GlobalAlignmentError,
    RegistrationError,
    RegistrationInputError,
)
from bimcap.registration.global_align import (
    AlignHypothesis,
    GlobalAlignOptions,
    GlobalAlignResult,
    global_align,
    initial_free_fraction,
)
from bimcap.registration.schedule import (
    BIM_TERMS,
    Schedule,
    ScheduleStage,
    StageKind,
)

__all__ = [
    "BIM_TERMS",
    "AlignHypothesis",
    "AmbiguousAlignmentError",
    "CoarseOptions",
    "CoarseResult",
    "FloorPlan",
    "GlobalAlignOptions",
    "GlobalAlignResult",
    "GlobalAlignmentError",
    "RegistrationError",
    "RegistrationInputError",
    "Schedule",
    "ScheduleStage",
    "SemanticSamples",
    "StageKind",
    "WindowResult",
    "coarse_register",
    "global_align",
    "initial_free_fraction",
]
