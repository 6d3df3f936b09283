"""Exceptions of the segmentation stage."""

from __future__ import annotations

from bimcap.errors import BimcapError, InputError


class SegmentationError(BimcapError):
    """A segmentation failure that is not an input problem."""


class SegmentationInputError(SegmentationError, InputError):
    """Bad input to a segmentation provider (missing mask file, wrong size, bad class map)."""
