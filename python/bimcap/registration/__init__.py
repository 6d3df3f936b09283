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
    Schedule,
    ScheduleStage,
    StageKind,
)

__all__ = [
    "BIM_TERMS",
    "CoarseOptions",
    "CoarseResult",
    "FloorPlan",
    "RegistrationError",
    "RegistrationInputError",
    "Schedule",
    "ScheduleStage",
    "SemanticSamples",
    "StageKind",
    "WindowResult",
    "coarse_register",
]
