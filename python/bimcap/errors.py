"""The exception hierarchy shared by every stage.

Each stage defines its own subclass of :class:`BimcapError` (``BimError``, ``SimError``,
``FrontendError``, ``SolverError``, ``EvaluationError`` ...) so that callers can catch one stage or
all of bimcap. Errors about user input derive from :class:`InputError` and name the file and the
field that is wrong.
"""

from __future__ import annotations

from os import PathLike


class BimcapError(Exception):
    """Base class of every error bimcap raises on purpose."""


class InputError(BimcapError, ValueError):
    """Bad user input: a malformed file, a wrong shape, NaN poses, a missing frame.

    Parameters
    ----------
    message:
        What is wrong, in words.
    path:
        The file (or directory) the bad input came from, if any.
    field:
        The field, array, column or line inside that file, if known.
    """

    def __init__(
        self, message: str, path: str | PathLike[str] | None = None, field: str | None = None
    ) -> None:
        self.path = None if path is None else str(path)
        self.field = field
        where = ""
        if self.path is not None:
            where = f"{self.path}: "
        if field is not None:
            where += f"{field}: "
        super().__init__(where + message)
