"""The shared cache: work that depends only on an input file's content, reused by every run.

A run's own output directory keeps its copy (``OUT/bim/``); the shared cache lets a second run on
the same IFC, with another ``-o``, start from the finished BIM reference instead of loading and
tessellating the model again (minutes for a large real model).

Root (:func:`cache_root`): the setting ``cache_dir`` when given, else ``$BIMCAP_CACHE_DIR``, else
``$XDG_CACHE_HOME/bimcap``, else ``~/.cache/bimcap``; the value ``off`` switches the shared cache
off. Entries are directories named by the content hash of their input (:func:`file_key`) and a
format version, written into a hidden sibling and renamed into place, so that a reader never sees
half an entry and two runs may fill the same entry at once.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable
from os import PathLike
from pathlib import Path

from bimcap.io.outputs import sha256_file

#: The value of ``cache_dir`` / ``$BIMCAP_CACHE_DIR`` that switches the shared cache off.
OFF = "off"


def cache_root(setting: str | PathLike[str] | None = None) -> Path | None:
    """The shared cache's root directory, or None when it is switched off (see the module)."""
    value = os.fspath(setting) if setting is not None else os.environ.get("BIMCAP_CACHE_DIR")
    if value is not None and value.strip() != "":
        return None if value.strip().lower() == OFF else Path(value).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "bimcap"


def file_key(path: str | PathLike[str]) -> str:
    """The first 16 hex digits of the SHA-256 of the file's content."""
    return sha256_file(path)[:16]


def publish(entry: Path, fill: Callable[[Path], None]) -> None:
    """Create the cache entry ``entry`` (a directory) with ``fill(tmp)``: filled in a hidden
    sibling, then renamed into place. An entry that appeared meanwhile is kept; the hidden
    directory is removed whatever happens. Raises ``OSError`` from the file system."""
    entry.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{entry.name}-", dir=entry.parent))
    try:
        fill(tmp)
        try:
            os.rename(tmp, entry)
        except OSError:
            if not entry.is_dir():
                raise
    finally:
        if tmp.exists():
            with contextlib.suppress(OSError):
                shutil.rmtree(tmp)
