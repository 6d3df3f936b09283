"""On-disk cache of per-frame and per-pair front-end results.

An entry is one ``.npz`` file named by a SHA-256 key over everything that determines it: the
frame's input files (resolved path, size and modification time in nanoseconds; a changed file
gives a new key), the settings of every step that ran (as canonical JSON) and a format version.
Entries are written atomically, so a killed run never leaves a half entry that a later run
would trust; an unreadable entry counts as a miss and is recomputed. They are not flushed to
the disk before the rename (:func:`bimcap.io.atomic.atomic_write_bytes` with ``durable=False``):
after a power loss an entry may be torn, which its zip CRC-32 or the ``.npy`` header shows, so
it reads as a miss too.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from collections.abc import Iterable, Mapping
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.io.atomic import atomic_write_bytes

#: Bump when the content of cache entries changes meaning.
CACHE_FORMAT_VERSION = 1


def file_fingerprint(path: str | PathLike[str]) -> str:
    """``"resolved-path:size:mtime_ns"`` of a file, or ``"path:missing"``."""
    p = Path(path).resolve()
    try:
        st = p.stat()
    except OSError:
        return f"{p}:missing"
    return f"{p}:{st.st_size}:{st.st_mtime_ns}"


def stable_hash(obj: Any) -> str:
    """SHA-256 hex digest of ``obj`` serialised as canonical JSON (sorted keys)."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str, allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def frame_cache_key(input_files: Iterable[str | PathLike[str]], settings: Mapping[str, Any]) -> str:
    """Key of one frame's result: its input files' fingerprints and the settings."""
    return stable_hash(
        {
            "version": CACHE_FORMAT_VERSION,
            "files": [file_fingerprint(f) for f in input_files],
            "settings": dict(settings),
        }
    )


class ResultCache:
    """A folder of ``<kind>/<key[:2]>/<key>.npz`` entries holding named arrays.

    Parameters
    ----------
    root: the cache folder (created on first write); None disables caching.
    """

    def __init__(self, root: str | PathLike[str] | None) -> None:
        self.root = None if root is None else Path(root)

    @property
    def enabled(self) -> bool:
        return self.root is not None

    def _path(self, kind: str, key: str) -> Path:
        assert self.root is not None
        return self.root / kind / key[:2] / f"{key}.npz"

    def get(self, kind: str, key: str) -> dict[str, NDArray[Any]] | None:
        """The arrays stored under ``(kind, key)``, or None when absent or unreadable."""
        if self.root is None:
            return None
        path = self._path(kind, key)
        if not path.is_file():
            return None
        try:
            # the file opened here, so that it is closed also when np.load refuses it
            with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, NotImplementedError):
            return None

    def put(self, kind: str, key: str, arrays: Mapping[str, NDArray[Any]]) -> None:
        """Store ``arrays`` under ``(kind, key)`` atomically (no-op when disabled)."""
        if self.root is None:
            return
        buf = io.BytesIO()
        np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
        atomic_write_bytes(os.fspath(self._path(kind, key)), buf.getvalue(), durable=False)
