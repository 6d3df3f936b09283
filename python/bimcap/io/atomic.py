"""Atomic writes: write to a temporary file in the target directory, fsync, then rename.

A reader never sees a half-written output, and a crash leaves the previous file intact.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable
from os import PathLike
from pathlib import Path
from typing import Any

from bimcap.errors import InputError


def atomic_write_bytes(path: str | PathLike[str], data: bytes, durable: bool = True) -> None:
    """Write ``data`` to ``path`` atomically, creating parent directories.

    ``durable``: flush the data to the disk (``fsync``) before the rename, so that the file
    survives a power loss too. False skips it for files that a later run can rebuild and that
    their reader checks (the front end's cache entries: a zip member's CRC-32): a killed process
    still never leaves a half file under ``path`` (the rename is atomic), only a power loss can,
    which the reader then takes as a miss. The flush is ~0.5 ms CPU and 3-4 ms wall a file on
    the shared box (docs/speed.md, "LiDAR stages, the triangulation and the cache writes").
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        # mkstemp creates 0600 files; give the output the usual permissions (0666 & ~umask).
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_copy(source: str | PathLike[str], path: str | PathLike[str]) -> None:
    """Copy the file ``source`` to ``path`` atomically: a failed copy (a full disk) leaves
    neither a partial ``path`` nor a temporary file behind."""
    import shutil

    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    try:
        shutil.copyfile(source, tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 → the usual permissions
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str | PathLike[str], text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | PathLike[str], obj: Any) -> None:
    """Write ``obj`` as indented JSON atomically (NaN is refused: JSON has no NaN)."""
    atomic_write_text(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def check_not_input(output: str | PathLike[str], inputs: Iterable[str | PathLike[str]]) -> None:
    """Raise :class:`InputError` if the file ``output`` would replace one of the files ``inputs``.

    Every command calls this before writing, so that nothing the user gave is overwritten.
    """
    out = Path(output).resolve()
    for item in inputs:
        if out == Path(item).resolve():
            raise InputError(f"refusing to overwrite the input file {item}", output)
