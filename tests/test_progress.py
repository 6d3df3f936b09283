"""bimcap.progress: one bar helper, drawn only on a terminal while bimcap logs at INFO."""

from __future__ import annotations

import io
import logging
from collections.abc import Callable, Iterator

import pytest

from bimcap.logs import quieted
from bimcap.progress import bars_enabled, progress, write_line


class _Terminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def _stderr(monkeypatch: pytest.MonkeyPatch, err: io.StringIO) -> io.StringIO:
    """``err`` as sys.stderr, set in the test's body (pytest's capture resets it after the
    fixtures)."""
    monkeypatch.setattr("sys.stderr", err)
    return err


@pytest.fixture
def bimcap_level() -> Iterator[Callable[[int], None]]:
    """Sets the ``bimcap`` logger's level for the test; restores it afterwards."""
    logger = logging.getLogger("bimcap")
    before = logger.level

    def set_level(level: int) -> None:
        logger.setLevel(level)

    yield set_level
    logger.setLevel(before)


def test_a_bar_on_a_terminal_at_info(monkeypatch: pytest.MonkeyPatch, bimcap_level) -> None:
    terminal = _stderr(monkeypatch, _Terminal())
    bimcap_level(logging.INFO)
    assert bars_enabled()
    assert list(progress(range(3), desc="render", unit="frame")) == [0, 1, 2]
    text = terminal.getvalue()
    assert "render" in text and "0/3" in text and "frame/s" in text
    assert text.endswith("\r")  # leave=False: the finished bar is wiped, the log says the rest


def test_no_bar_under_quiet_or_without_logging(monkeypatch: pytest.MonkeyPatch,
                                               bimcap_level) -> None:
    terminal = _stderr(monkeypatch, _Terminal())
    bimcap_level(logging.WARNING)  # bimcap -q
    assert list(progress(range(3), desc="render")) == [0, 1, 2]
    bimcap_level(logging.NOTSET)  # a script that configured nothing: the root's WARNING
    with progress(total=2, desc="front end") as bar:
        bar.update(2)
    bimcap_level(logging.INFO)
    with quieted(True):  # the deprecated quiet=True of the pipeline functions
        assert not bars_enabled()
        list(progress(range(2), desc="solve"))
    list(progress(range(2), desc="solve", enabled=False))  # the caller's own switch
    assert terminal.getvalue() == ""


def test_no_bar_in_a_log_file(monkeypatch: pytest.MonkeyPatch, bimcap_level) -> None:
    err = _stderr(monkeypatch, io.StringIO())  # not a terminal
    bimcap_level(logging.DEBUG)
    assert not bars_enabled()
    list(progress(range(3), desc="render"))
    write_line("[bimcap] a log line")
    assert err.getvalue() == "[bimcap] a log line\n"


def test_quieted_restores_the_level(bimcap_level) -> None:
    logger = logging.getLogger("bimcap")
    bimcap_level(logging.DEBUG)
    with quieted(True):
        assert logger.getEffectiveLevel() == logging.WARNING
    assert logger.level == logging.DEBUG
    with quieted(None):
        assert logger.level == logging.DEBUG
