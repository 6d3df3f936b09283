"""Exceptions of the coarse registration stage."""

from __future__ import annotations

from bimcap.errors import BimcapError, InputError


class RegistrationError(BimcapError):
    """Base class of the errors raised by :mod:`bimcap.registration`."""


class RegistrationInputError(RegistrationError, InputError):
    """Malformed input arrays or options; the message names the array (``field``)."""
