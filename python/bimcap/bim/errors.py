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
