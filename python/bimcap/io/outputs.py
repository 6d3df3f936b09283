"""Output directories: checked before any work, written as one consistent set.

A run (``bimcap refine``, the refine part of ``bimcap demo``) writes several files into one
directory. :class:`OutputSet` makes them a set:

1. :meth:`OutputSet.check` (before the expensive stages): every path the run may write that
   already exists must be an output of an earlier bimcap run, i.e. listed in that run's
   ``result.json`` with the same SHA-256; anything else (a ``refined.tum`` the user wrote, a file
   they edited) is refused unless ``overwrite`` is set. Nothing the user made is replaced silently.
2. :meth:`OutputSet.open`: creates the directory if needed and a fresh, hidden staging directory
   inside it (``.bimcap-staging-<pid>-<random>/``); the run writes its files there.
3. :meth:`OutputSet.commit`: removes the earlier run's ``result.json`` first (from then on the
   directory holds no complete run), then the earlier run's files, moves the new files into place
   (renames on one file system) and writes ``result.json`` last, listing every file of the run
   with its SHA-256 and size. A run interrupted at any point leaves either the old set, or no
   ``result.json`` (an incomplete set, recognisable as such), or the new set; never old and new
   files under one ``result.json``. :func:`verify_outputs` checks a directory against its
   ``result.json``.
4. :meth:`OutputSet.abort` (on failure): removes the staging directory, and the output directory
   itself when the run created it and left no file in it. Caches written before the failure
   stay (a rerun reuses them).

Caches (``bim/``, ``cache/``) live beside the outputs and are not part of the set.

:func:`check_output_dir` and :func:`check_output_file` are the checks the command line runs
before any command (``bimcap.cli``): they raise the :class:`OSError` the write would meet
(``NotADirectoryError`` for a file in the way, ``PermissionError`` / ``EROFS`` for a directory
that cannot be written), which the CLI turns into one line and exit status 4.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Mapping
from os import PathLike
from pathlib import Path
from typing import Any

from bimcap.errors import InputError
from bimcap.io.atomic import atomic_write_json

RESULT_NAME = "result.json"
RESULT_FORMAT = "bimcap-run"
RESULT_VERSION = 1
STAGING_PREFIX = ".bimcap-staging-"


class OutputExistsError(InputError):
    """An output would replace a file that bimcap did not write (use ``--overwrite``)."""


def sha256_file(path: str | PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not os.path.lexists(p) and p != p.parent:
        p = p.parent
    return p


def _check_writable_dir(d: Path) -> None:
    """Raise the OSError that creating a file in the existing path ``d`` would meet."""
    if not d.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(d))
    if not os.access(d, os.W_OK | os.X_OK):
        try:
            read_only = bool(os.statvfs(d).f_flag & os.ST_RDONLY)
        except OSError:
            read_only = False
        code = errno.EROFS if read_only else errno.EACCES
        raise OSError(code, os.strerror(code), str(d))


def check_output_dir(path: str | PathLike[str]) -> None:
    """Raise the :class:`OSError` that writing into the directory ``path`` would meet: a file in
    its place (or in place of a parent), a directory that is read-only or not writable. Creates
    nothing."""
    p = Path(path)
    if os.path.lexists(p):
        if not p.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(p))
        _check_writable_dir(p)
    else:
        _check_writable_dir(_nearest_existing(p))


def check_output_file(path: str | PathLike[str]) -> None:
    """As :func:`check_output_dir` for a file ``path``: its directory must be writable (or
    creatable) and ``path`` must not be a directory."""
    p = Path(path)
    if p.is_dir():
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(p))
    check_output_dir(p.parent if str(p.parent) else Path("."))


def read_result(directory: str | PathLike[str]) -> dict[str, Any] | None:
    """The ``result.json`` of ``directory`` as a dict, or None when there is none or it is not a
    bimcap result (unreadable JSON, not an object)."""
    path = Path(directory) / RESULT_NAME
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


def earlier_outputs(directory: str | PathLike[str]) -> dict[str, str | None] | None:
    """The files of the earlier run in ``directory``: relative path → SHA-256 (None for a
    ``result.json`` written before hashes were recorded, whose ``files`` are trusted by name).
    None when the directory holds no bimcap ``result.json``."""
    doc = read_result(directory)
    if doc is None:
        return None
    outputs = doc.get("outputs")
    if doc.get("format") == RESULT_FORMAT and isinstance(outputs, dict):
        return {str(k): (v.get("sha256") if isinstance(v, dict) else None)
                for k, v in outputs.items()}
    files = doc.get("files")
    if isinstance(files, dict) and "command" in doc:  # bimcap refine before issue 12
        out: dict[str, str | None] = {str(v): None for v in files.values() if isinstance(v, str)}
        if "report" in files:
            figures = Path(directory) / "figures"
            if figures.is_dir():
                out.update({f"figures/{p.name}": None for p in figures.iterdir() if p.is_file()})
        return out
    return None


def verify_outputs(directory: str | PathLike[str]) -> list[str]:
    """Problems of the set in ``directory`` against its ``result.json``: files listed but missing
    or with another SHA-256. Empty when the set is complete and unchanged."""
    d = Path(directory)
    doc = read_result(d)
    if doc is None or doc.get("format") != RESULT_FORMAT:
        return [f"{d / RESULT_NAME}: no bimcap result"]
    problems = []
    for rel, info in dict(doc.get("outputs", {})).items():
        p = d / rel
        if not p.is_file():
            problems.append(f"{p}: listed in {RESULT_NAME} but missing")
        elif sha256_file(p) != info.get("sha256"):
            problems.append(f"{p}: changed since the run (SHA-256 differs)")
    return problems


class OutputSet:
    """The outputs of one run in ``directory``, written as a set (module docstring).

    Parameters
    ----------
    directory: the output directory (``-o``).
    names: relative paths the run may write; a name ending in ``/`` stands for every file in that
        sub-directory (e.g. ``"figures/"``). ``result.json`` is always part of the set.
    overwrite: replace files bimcap did not write (``--overwrite``).
    inputs: files the run reads; an output that is one of them is always refused.
    """

    def __init__(self, directory: str | PathLike[str], names: Iterable[str],
                 overwrite: bool = False, inputs: Iterable[str | PathLike[str]] = ()) -> None:
        self.directory = Path(directory)
        self.names = [n for n in names if n != RESULT_NAME] + [RESULT_NAME]
        self.overwrite = overwrite
        self.inputs = [Path(p).resolve() for p in inputs]
        self.stage: Path | None = None
        self.created = False

    # ------------------------------------------------------------------ before the run
    def existing(self) -> list[str]:
        """Relative paths of the set that exist now."""
        out = []
        for name in self.names:
            p = self.directory / name
            if name.endswith("/"):
                if p.is_dir():
                    out += [f"{name}{q.relative_to(p).as_posix()}" for q in sorted(p.rglob("*"))
                            if q.is_file() or q.is_symlink()]
                elif os.path.lexists(p):  # a file where the sub-directory goes
                    out.append(name.rstrip("/"))
            elif os.path.lexists(p):
                out.append(name)
        return out

    def check(self) -> None:
        """Refuse (:class:`OutputExistsError`, naming the file) an output that is an input, or
        that exists and was not written by an earlier bimcap run, unless ``overwrite``."""
        for name in self.names:
            target = (self.directory / name.rstrip("/")).resolve()
            for item in self.inputs:
                if target == item or (name.endswith("/") and target in item.parents):
                    raise OutputExistsError(f"refusing to overwrite the input file {item}",
                                            self.directory / name)
        if self.overwrite:
            return
        earlier = earlier_outputs(self.directory) or {}
        for rel in self.existing():
            p = self.directory / rel
            if rel == RESULT_NAME:
                if read_result(self.directory) is None:
                    raise OutputExistsError(
                        "exists and is not a bimcap result; move it away or use --overwrite", p)
                continue
            if not p.is_file() or p.is_symlink():
                raise OutputExistsError(
                    "exists and is not a file bimcap wrote; move it away or use --overwrite", p)
            if rel not in earlier:
                raise OutputExistsError(
                    f"exists and was not written by bimcap (not listed in {RESULT_NAME}); move it "
                    "away or use --overwrite to replace it", p)
            digest = earlier[rel]
            if digest is not None and sha256_file(p) != digest:
                raise OutputExistsError(
                    f"was changed after bimcap wrote it (its SHA-256 differs from {RESULT_NAME}); "
                    "move it away or use --overwrite to replace it", p)

    # ------------------------------------------------------------------ the run
    def open(self) -> Path:
        """Create the directory (if needed) and a fresh staging directory; return the latter.
        Call :meth:`check` first (before the expensive work); :meth:`commit` checks again."""
        if not self.directory.exists():
            self.directory.mkdir(parents=True)
            self.created = True
        self._remove_stale_stages()
        self.stage = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-",
                                           dir=self.directory))
        return self.stage

    def _remove_stale_stages(self) -> None:
        """Staging directories of runs that died (their process is gone)."""
        for p in self.directory.glob(f"{STAGING_PREFIX}*"):
            pid_text = p.name[len(STAGING_PREFIX):].split("-", 1)[0]
            try:
                os.kill(int(pid_text), 0)
                alive = True
            except (ValueError, ProcessLookupError):
                alive = False
            except PermissionError:
                alive = True
            if not alive and p.is_dir():
                shutil.rmtree(p, ignore_errors=True)

    def commit(self, result: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
        """Move the staged files into place and write ``result.json`` (``result`` plus
        ``format``, ``version`` and ``outputs``: relative path → ``{"sha256", "bytes"}``) last.
        Returns ``outputs``."""
        if self.stage is None:
            raise RuntimeError("OutputSet.commit before open")
        self.check()  # nothing appeared in the meantime
        staged = sorted(p for p in self.stage.rglob("*") if p.is_file())
        outputs = {p.relative_to(self.stage).as_posix(): {"sha256": sha256_file(p),
                                                          "bytes": p.stat().st_size}
                   for p in staged}
        if RESULT_NAME in outputs:
            raise RuntimeError(f"the run must not write {RESULT_NAME} itself")
        # 1. From here on the directory holds no complete run.
        result_path = self.directory / RESULT_NAME
        if os.path.lexists(result_path):
            result_path.unlink()
        # 2. The earlier run's files (checked above: bimcap's, or --overwrite).
        for rel in self.existing():
            stale = self.directory / rel
            if stale.is_dir() and not stale.is_symlink():
                shutil.rmtree(stale)
            else:
                stale.unlink()
        for name in self.names:
            d = self.directory / name
            if name.endswith("/") and d.is_dir() and not any(d.iterdir()):
                d.rmdir()
        # 3. The new files, by rename.
        for p in staged:
            target = self.directory / p.relative_to(self.stage)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(p, target)
        shutil.rmtree(self.stage, ignore_errors=True)
        self.stage = None
        # 4. The certificate, last.
        doc = {"format": RESULT_FORMAT, "version": RESULT_VERSION, **dict(result),
               "outputs": outputs}
        atomic_write_json(result_path, doc)
        return outputs

    def abort(self) -> None:
        """Remove the staging directory, and the output directory when this run created it and
        left no file in it (empty cache directories included)."""
        if self.stage is not None:
            shutil.rmtree(self.stage, ignore_errors=True)
            self.stage = None
        if (self.created and self.directory.is_dir()
                and not any(p.is_file() or p.is_symlink() for p in self.directory.rglob("*"))):
            shutil.rmtree(self.directory, ignore_errors=True)
