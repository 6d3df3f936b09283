"""Progress bars: the one place bimcap draws them (tqdm), so that every long step looks alike and
none of them litters a log file.

A bar is drawn only when

* stderr is a terminal (a log file or a pipe gets the log lines alone), and
* the ``bimcap`` logger shows INFO (:mod:`bimcap.logs`): the ``bimcap`` command's default, not
  under ``-q``, and not in a script that has not configured logging.

Otherwise :func:`progress` returns a bar that counts but draws nothing. Log lines written while a
bar is drawn go through :func:`write_line`, which keeps the bar below them
(``bimcap.cli.configure_logging`` does so).

Example::

    for frame in progress(frames, desc="render", unit="frame"):
        ...

    with progress(total=n_jobs, desc="front end", unit="job") as bar:
        ...
        bar.update()
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterable
from typing import Any, TypeVar

from bimcap.logs import ROOT

T = TypeVar("T")


def bars_enabled() -> bool:
    """Whether a bar would be drawn now: stderr is a terminal and bimcap logs at INFO."""
    isatty = getattr(sys.stderr, "isatty", None)
    return bool(isatty is not None and isatty()) and logging.getLogger(ROOT).isEnabledFor(
        logging.INFO)


def progress(iterable: Iterable[T] | None = None, *, total: int | None = None, desc: str = "",
             unit: str = "it", enabled: bool = True, leave: bool = False) -> Any:
    """A ``tqdm`` bar over ``iterable`` (or counted by hand with ``update`` when None) on stderr.

    Parameters
    ----------
    iterable: what to iterate over, or None for a bar moved by ``bar.update(n)``.
    total: the number of steps (default ``len(iterable)`` when it has one).
    desc: the label in front of the bar ("front end", "render").
    unit: what one step is ("frame", "job", "stage", "message").
    enabled: False draws nothing whatever the terminal (a caller's own switch).
    leave: keep the finished bar on screen (default: it disappears; the log says what was done).

    Returns
    -------
    A ``tqdm`` object: iterate over it, or call ``update`` / ``set_postfix_str`` / ``close``; a
    context manager. It draws nothing unless :func:`bars_enabled`.
    """
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, file=sys.stderr, leave=leave,
                disable=not (enabled and bars_enabled()), dynamic_ncols=True)


def write_line(text: str) -> None:
    """Write one line to stderr above the bars being drawn (``tqdm.write``), or plainly when
    there are none."""
    from tqdm import tqdm

    tqdm.write(text, file=sys.stderr)


class StageProgress:
    """A ``progress(stage, done, total)`` callback (the importers' ``ImportOptions.progress``)
    drawn as one :func:`progress` bar per stage: the bar of ``stage`` is moved to ``done`` and
    closed when ``done`` reaches ``total``."""

    def __init__(self) -> None:
        self._bars: dict[str, Any] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        bar = self._bars.get(stage)
        if bar is None:
            bar = self._bars[stage] = progress(total=total, desc=stage)
        bar.total = total
        bar.update(done - bar.n)
        if done >= total:
            bar.close()
            self._bars.pop(stage, None)
