"""Coarse registration to the BIM (before bundle adjustment): bring frames or windows of frames
near the right pose using the floor plan and the floor/ceiling planes alone.

Public API: :func:`coarse_register` with :class:`CoarseOptions`, :class:`SemanticSamples`,
:class:`FloorPlan` → :class:`CoarseResult`; the refinement :class:`Schedule` that follows it.
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
from bimcap.registration.errors import RegistrationError, RegistrationInputError
from bimcap.registration.schedule import (
    BIM_TERMS,
    PoseBlock,
    Schedule,
    ScheduleStage,
    StageKind,
    Term,
)

__all__ = [
    "BIM_TERMS",
    "CoarseOptions",
    "CoarseResult",
    "FloorPlan",
    "PoseBlock",
    "RegistrationError",
    "RegistrationInputError",
    "Schedule",
    "ScheduleStage",
    "SemanticSamples",
    "StageKind",
    "Term",
    "WindowResult",
    "coarse_register",
]
