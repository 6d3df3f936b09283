"""Exceptions of the coarse registration stage."""

from __future__ import annotations

from typing import Any

from bimcap.errors import BimcapError, InputError


class RegistrationError(BimcapError):
    """Base class of the errors raised by :mod:`bimcap.registration`."""


class RegistrationInputError(RegistrationError, InputError):
    """Malformed input arrays or options; the message names the array (``field``)."""


class GlobalAlignmentError(RegistrationError):
    """No placement of a trajectory in the BIM fits (:mod:`.global_align`; exit status 3).

    ``result`` holds what was found (a ``GlobalAlignResult`` with the ranked placements), or
    None.
    """

    exit_code = 3

    def __init__(self, message: str, result: Any = None) -> None:
        super().__init__(message)
        self.result = result


class AmbiguousAlignmentError(GlobalAlignmentError):
    """The best and the second-best distinct placements score alike: refused unless accepted
    (``accept_ambiguous`` / ``bimcap refine --accept-ambiguous``)."""
