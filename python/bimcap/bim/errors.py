"""Errors and warnings of the BIM stage (:mod:`bimcap.bim`)."""

from __future__ import annotations

from bimcap.errors import BimcapError, InputError


class BimError(BimcapError):
    """Base class of every error the BIM stage raises on purpose."""


class BimInputError(BimError, InputError):
    """An IFC file that cannot be used: missing, not IFC, truncated, or without walls.

    The message names the file (``path``) and what is missing (``field``), e.g. ``IfcWall``.
    """


class BimOptionsError(BimError, ValueError):
    """Options that cannot work (a non-positive resolution, an empty band ...); names the field."""


class BimWarning(UserWarning):
    """Base class of the BIM stage's warnings (something was missing and has been worked around)."""


class MissingFloorWarning(BimWarning):
    """A storey with walls has no floor slab; its floor planes were derived from spaces or the
    storey elevation instead."""


class MissingCeilingWarning(BimWarning):
    """A storey with walls has neither a ceiling covering nor a slab above it: no ceiling plane."""


class DamagedModelWarning(BimWarning):
    """The IFC file is damaged (instances IfcOpenShell could not read, references to instances
    that are missing, elements without geometry), but it lost no more than the allowed share of
    its elements; the message gives the counts."""


class StoreyHeightWarning(BimWarning):
    """A storey's ``Elevation`` disagrees with the height its own elements stand at (a
    georeferenced model moved up, a wrong attribute), or the model has no ``IfcBuildingStorey``:
    the storey heights were taken from the geometry instead."""


class ProxyElementWarning(BimWarning):
    """The model writes walls or columns as ``IfcBuildingElementProxy``; those whose names and
    shapes say so were taken as walls / columns (the message gives the counts)."""
