"""How bimcap reports what it is doing: :mod:`logging`, one logger per module
(``logging.getLogger(__name__)``, all under the ``bimcap`` logger), and progress bars
(:mod:`bimcap.progress`).

The library installs no handler and prints nothing: an application decides what is shown. The
``bimcap`` command line does it in one place (:func:`bimcap.cli.configure_logging`: INFO on
stderr by default, ``-q`` WARNING, ``-v`` DEBUG). A script gets bimcap's progress messages with::

    import logging
    logging.basicConfig(level=logging.INFO)

Levels: DEBUG for detail (per-stage problem sizes, timings), INFO for the steps of a run, WARNING
for a result the user must look at (a failed plane check, an ambiguous alignment, a diverged
solve).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager

#: The logger every bimcap module's logger hangs under.
ROOT = "bimcap"


@contextmanager
def quieted(quiet: bool | None) -> Iterator[None]:
    """The deprecated ``quiet=True`` keyword of the pipeline functions (``prepare``,
    ``solve_prepared``, ``refine``, ``run_demo``, ...): bimcap's INFO messages and progress bars
    off for the call (the ``bimcap`` logger at WARNING at least), warnings still shown. None or
    False changes nothing; configure the ``bimcap`` logger instead."""
    if not quiet:
        yield
        return
    logger = logging.getLogger(ROOT)
    previous = logger.level
    if logger.getEffectiveLevel() < logging.WARNING:
        logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(previous)
