"""Exceptions of the optimisation stage."""

from __future__ import annotations

from bimcap.errors import BimcapError, InputError


class SolverError(BimcapError):
    """The solve itself failed (Ceres reported an unusable solution). CLI exit status 3."""

    exit_code = 3


class SolverInputError(InputError):
    """A problem array, a problem file or an option is malformed; names the file and field."""


class SolverUnavailableError(BimcapError):
    """The compiled core ``bimcap._core`` is missing (bimcap was not built / installed)."""
