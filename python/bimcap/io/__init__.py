"""Low-level file helpers shared by every stage (atomic writes, input protection, output sets:
``bimcap.io.outputs``)."""

from __future__ import annotations

from bimcap.io.atomic import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    check_not_input,
)

__all__ = ["atomic_write_bytes", "atomic_write_json", "atomic_write_text", "check_not_input"]
