"""The shared cache (bimcap.io.cache): a second run on the same IFC with another output directory
starts from the finished BIM reference instead of loading the model again."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from bimcap.bim.cache import ReferenceSource, reference_for
from bimcap.io.cache import cache_root, file_key, publish

building = pytest.importorskip("bimcap.sim.building")


@pytest.fixture(scope="module")
def ifc(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("world") / "tiny.ifc"
    building.generate_building(building.PRESETS["tiny"], seed=1, ifc_path=path)
    return path


def test_cache_root_settings(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("BIMCAP_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_root() == tmp_path / "xdg" / "bimcap"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cache_root() == Path.home() / ".cache" / "bimcap"
    monkeypatch.setenv("BIMCAP_CACHE_DIR", str(tmp_path / "env"))
    assert cache_root() == tmp_path / "env"
    assert cache_root(tmp_path / "given") == tmp_path / "given"  # the setting wins
    assert cache_root("off") is None and cache_root("OFF") is None
    monkeypatch.setenv("BIMCAP_CACHE_DIR", "off")
    assert cache_root() is None


def test_second_run_reads_the_shared_reference(ifc: Path, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    import bimcap.bim.reference as reference

    root = tmp_path / "shared"
    first, source = reference_for(ifc, tmp_path / "a" / "bim", shared_root=root)
    assert source is ReferenceSource.BUILT
    entries = list((root / "bim").iterdir())
    assert [e.name for e in entries] == [f"{file_key(ifc)}-v{reference.VERSION}"]
    assert not [p for p in (root / "bim").iterdir() if p.name.startswith(".")]

    def no_build(*args: object, **kwargs: object) -> None:
        raise AssertionError("the reference was built again")

    monkeypatch.setattr(reference, "build_reference", no_build)
    second, source = reference_for(ifc, tmp_path / "b" / "bim", shared_root=root)
    assert source is ReferenceSource.SHARED
    for name in ("segments", "planes", "points", "labels"):
        np.testing.assert_array_equal(getattr(second, name), getattr(first, name))
    # the run's own copy is written too, and a third run reads it without the shared cache
    assert (tmp_path / "b" / "bim" / "reference.npz").is_file()
    assert reference_for(ifc, tmp_path / "b" / "bim", shared_root="off")[1] is ReferenceSource.RUN


def test_another_file_content_is_another_entry(ifc: Path, tmp_path: Path) -> None:
    root = tmp_path / "shared"
    reference_for(ifc, None, shared_root=root)
    edited = tmp_path / "edited.ifc"
    edited.write_bytes(ifc.read_bytes().replace(b"IfcWall", b"IfcWall", 1) + b"\n")
    reference_for(edited, None, shared_root=root)
    assert len(list((root / "bim").iterdir())) == 2


def test_damaged_shared_entry_is_rebuilt(ifc: Path, tmp_path: Path) -> None:
    root = tmp_path / "shared"
    reference_for(ifc, None, shared_root=root)
    (entry,) = (root / "bim").iterdir()
    (entry / "reference.npz").write_bytes(b"not an npz")
    ref, source = reference_for(ifc, None, shared_root=root)
    assert source is ReferenceSource.BUILT
    assert len(ref.segments) > 0


def test_unwritable_shared_cache_is_a_warning(ifc: Path, tmp_path: Path) -> None:
    root = tmp_path / "not-a-directory"
    root.write_text("a file where the cache root should be")  # unwritable, even for root
    with pytest.warns(UserWarning, match="could not write the shared BIM cache"):
        ref, _ = reference_for(ifc, tmp_path / "run" / "bim", shared_root=root)
    assert len(ref.segments) > 0 and (tmp_path / "run" / "bim" / "reference.npz").is_file()


def test_publish_keeps_an_entry_that_appeared_meanwhile(tmp_path: Path) -> None:
    entry = tmp_path / "bim" / "k-v1"

    def fill(tmp: Path) -> None:
        (tmp / "x").write_text("mine")
        entry.mkdir(parents=True)  # another run finished first
        (entry / "x").write_text("theirs")

    publish(entry, fill)
    assert (entry / "x").read_text() == "theirs"
    assert [p.name for p in entry.parent.iterdir()] == ["k-v1"]  # no hidden leftovers


def test_a_failing_copy_from_the_shared_cache_leaves_no_temporary_file(
        ifc: Path, tmp_path: Path) -> None:
    """A full disk while the shared entry is copied into ``OUT/bim`` (RLIMIT_FSIZE, what a full
    disk does to a write): the error surfaces and no ``.tmp`` file is left behind."""
    import resource
    import signal
    import subprocess
    import sys

    root = tmp_path / "shared"
    reference_for(ifc, tmp_path / "a" / "bim", shared_root=root)
    run = tmp_path / "b" / "bim"
    code = ("import sys; from bimcap.bim.cache import reference_for; "
            f"reference_for({str(ifc)!r}, {str(run)!r}, shared_root={str(root)!r})")

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       preexec_fn=limit, env={**os.environ})
    assert r.returncode != 0 and "File too large" in r.stderr, r.stderr
    assert run.is_dir()
    assert not [p.name for p in run.iterdir() if p.name.endswith(".tmp")]
