"""The evaluation stage's exception."""

from __future__ import annotations

from bimcap.errors import InputError


class EvaluationError(InputError):
    """Inputs that cannot be evaluated: no matching timestamps, too few poses to align, an empty
    or malformed point cloud. Names the file and field when known."""
