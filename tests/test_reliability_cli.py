"""Issue 12 on the command line: OS errors mapped in one place (item 3), one ``--overwrite`` flag
everywhere (item 6), no numpy reprs in messages (item 6)."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from bimcap.cli import build_parser, main
from bimcap.errors import InputError

EXIT_OS_ERROR = 4


def describe_os_error(exc: OSError) -> str:
    from bimcap.errors import describe_os_error as describe

    return describe(exc)


@pytest.mark.parametrize(("code", "words"), [
    (errno.EACCES, "permission denied"),
    (errno.EROFS, "read-only file system"),
    (errno.ENOSPC, "no space left on the device (disk full)"),
    (errno.EDQUOT, "disk quota exceeded"),
    (errno.ENOTDIR, "not a directory"),
    (errno.EISDIR, "is a directory"),
])
def test_describe_os_error_names_path_and_reason(code: int, words: str) -> None:
    line = describe_os_error(OSError(code, os.strerror(code), "/some/where"))
    assert line == f"/some/where: {words}" or line.startswith(f"/some/where: {words}")
    assert "\n" not in line and "Errno" not in line


def test_existing_file_where_a_directory_is_needed(tmp_path: Path) -> None:
    f = tmp_path / "out"
    f.write_text("x")
    with pytest.raises(FileExistsError) as info:
        f.mkdir(parents=True, exist_ok=True)
    assert describe_os_error(info.value) == f"{f}: is a file, not a directory"


def test_an_unexpected_oserror_in_any_command_is_one_line(monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The mapping lives in bimcap.cli.main: whatever command raises an OSError, it prints one
    line and exits 4 (``--debug`` shows the traceback)."""
    import bimcap.geometry.trajectory as trajectory  # evaluate imports read_tum when it runs

    def boom(*args, **kwargs):
        raise OSError(errno.EIO, "Input/output error", "/mnt/nas/gt.tum")

    monkeypatch.setattr(trajectory, "read_tum", boom)
    assert main(["evaluate", "a.tum", "b.tum"]) == EXIT_OS_ERROR
    err = capsys.readouterr().err.strip()
    assert err == "bimcap evaluate: error: /mnt/nas/gt.tum: input/output error (a failing disk " \
                  "or network file system?)"
    with pytest.raises(OSError, match="Input/output error"):
        main(["--debug", "evaluate", "a.tum", "b.tum"])


# ----------------------------------------------------------------------------- --overwrite
def test_generate_building_refuses_an_existing_file(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "house.ifc"
    assert main(["generate-building", "-o", str(path), "--building", "tiny"]) == 0
    before = path.read_bytes()
    capsys.readouterr()
    assert main(["generate-building", "-o", str(path), "--building", "tiny", "--seed", "3"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "--overwrite" in err
    assert path.read_bytes() == before
    # The sidecar alone in the way is refused too.
    other = tmp_path / "other.ifc"
    (tmp_path / "other.truth.json").write_text("{}")
    assert main(["generate-building", "-o", str(other), "--building", "tiny"]) == 2
    assert not other.exists()
    assert main(["generate-building", "-o", str(path), "--building", "tiny", "--seed", "3",
                 "--overwrite"]) == 0
    assert path.read_bytes() != before


@pytest.mark.parametrize("command", ["generate-building", "simulate", "drift", "import-conslam",
                                     "import-bag", "import-folder", "refine", "demo"])
def test_every_command_that_can_replace_files_takes_overwrite(command: str) -> None:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    options = {o for a in sub.choices[command]._actions for o in a.option_strings}
    assert "--overwrite" in options


@pytest.mark.parametrize("command", ["drift", "import-conslam"])
def test_force_is_a_deprecated_alias(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser()
    base = {"drift": ["drift", "seq"], "import-conslam": ["import-conslam", "x.bag", "-o", "o"]}
    args = parser.parse_args([*base[command], "--force"])
    assert args.overwrite is True
    assert "--force is deprecated, use --overwrite" in capsys.readouterr().err


# ----------------------------------------------------------------------------- numpy reprs
def test_no_numpy_reprs_in_messages(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dup = tmp_path / "dup.tum"
    dup.write_text("1.5 0 0 0 0 0 0 1\n1.5 0 0 0 0 0 0 1\n")
    assert main(["evaluate", str(dup), str(dup)]) == 2
    err = capsys.readouterr().err
    assert "entry 1 (1.5)" in err and "np." not in err
    import numpy as np

    msg = str(InputError(f"got {np.float64(2.5)!r} and {[np.int32(3)]}", "f.json", "k"))
    assert msg == "f.json: k: got 2.5 and [3]"
    from bimcap.errors import clean_message

    assert clean_message("np.float32(1.0), np.int64(-2), np.bool_(True)") == "1.0, -2, True"
