"""The BIM reference of an IFC, built once per file content and reused.

:func:`reference_for` looks in the run's own directory (``OUT/bim``), then in the shared cache
(:mod:`bimcap.io.cache`: one entry per IFC content, reused by runs with other output
directories), and builds the reference only when neither holds it; both get a copy. A cached
reference is checked like a built one (:meth:`BimReference.check_usable`); a damaged one is
rebuilt; a shared cache that cannot be written is a warning, never a failure.
"""

from __future__ import annotations

import warnings
from enum import Enum
from os import PathLike
from pathlib import Path

from bimcap.bim.reference import VERSION, BimReference
from bimcap.errors import InputError
from bimcap.io.atomic import atomic_copy
from bimcap.io.cache import cache_root, file_key, publish

#: The file in a reference directory naming the IFC content it was built from.
STAMP = "source.key"


class ReferenceSource(str, Enum):
    """Where :func:`reference_for` found the reference."""

    RUN = "run"  # the run's own directory
    SHARED = "shared"  # the shared cache
    BUILT = "built"  # built from the IFC


def reference_for(
    ifc_path: str | PathLike[str],
    run_dir: str | PathLike[str] | None,
    max_lost_fraction: float = 0.02,
    shared_root: str | PathLike[str] | None = None,
) -> tuple[BimReference, ReferenceSource]:
    """The BIM reference of ``ifc_path`` and where it came from.

    ``run_dir``: the run's reference directory (``OUT/bim``) or None; ``shared_root``: the shared
    cache's root (:func:`bimcap.io.cache.cache_root`: None for the default, ``"off"``).
    An unusable model (damaged beyond ``max_lost_fraction``, an empty floor plan or cloud, an
    implausible unit) raises ``BimInputError`` naming the IFC, cached or not.
    """
    from bimcap.bim import ingest, reference

    ifc = Path(ifc_path)
    if not ifc.is_file():
        raise InputError("no such IFC file", ifc)
    key = file_key(ifc)
    root = cache_root(shared_root)
    shared = None if root is None else root / "bim" / f"{key}-v{VERSION}"
    run = None if run_dir is None else Path(run_dir)
    ref = _cached(run, key, ifc)
    if ref is not None:
        return ref, ReferenceSource.RUN
    ref = _cached(shared, key, ifc)
    if ref is not None and shared is not None:
        if run is not None:
            _copy_entry(shared, run)
        return ref, ReferenceSource.SHARED
    ref = reference.build_reference(ingest.load_model(ifc, max_lost_fraction=max_lost_fraction))
    if run is not None:
        _save(ref, run, key)
    if shared is not None:
        try:
            publish(shared, lambda tmp: _save(ref, tmp, key))
        except OSError as exc:
            warnings.warn(f"could not write the shared BIM cache {shared}: {exc}", stacklevel=2)
    return ref, ReferenceSource.BUILT


def _cached(directory: Path | None, key: str, ifc: Path) -> BimReference | None:
    """The reference saved in ``directory`` from the IFC content ``key``, or None (absent, from
    another file, or unreadable: it is then rebuilt)."""
    if directory is None:
        return None
    stamp = directory / STAMP
    if not stamp.is_file() or stamp.read_text().strip() != key:
        return None
    try:
        ref = BimReference.load(directory)
    except Exception:  # a damaged cache is rebuilt, never fatal
        return None
    ref.check_usable(ifc)
    return ref


def _save(ref: BimReference, directory: Path, key: str) -> None:
    """Save ``ref`` into ``directory``, stamped with the IFC content ``key`` (stamp last)."""
    ref.save(directory)
    (directory / STAMP).write_text(key + "\n")


def _copy_entry(entry: Path, directory: Path) -> None:
    """Copy a shared cache entry's files into ``directory``, the stamp last."""
    directory.mkdir(parents=True, exist_ok=True)
    files = sorted((p for p in entry.iterdir() if p.is_file()), key=lambda p: p.name == STAMP)
    for f in files:
        atomic_copy(f, directory / f.name)
