"""Exceptions of the front end (``bimcap.frontend.runner`` re-exports them)."""

from __future__ import annotations

from bimcap.errors import BimcapError, InputError


class FrontendError(BimcapError):
    """The front end cannot run (a provider failed, an option is invalid)."""


class FrontendInputError(FrontendError, InputError):
    """Bad input to the front end: a missing frame, an image or map of the wrong size."""
