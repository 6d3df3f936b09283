"""Where the front end's per-frame and per-pair jobs run: a local process pool or a Dask cluster.

:class:`ExecutorOptions` names the executor (:class:`bimcap.methods.ExecutorKind`):

- ``LOCAL``: a ``spawn`` process pool of ``workers`` processes on this machine (1: this process).
- ``DASK``: a Dask ``distributed`` cluster. Without ``scheduler`` the run starts a
  ``LocalCluster`` of ``dask_workers`` worker processes (one thread each) on this machine and
  closes it when the front end is done, on every exit path; with ``scheduler``
  (``tcp://HOST:PORT``) it connects to a running cluster (``dask scheduler`` plus
  ``dask worker tcp://HOST:PORT`` on each node, docs/dask.md) and leaves it running.

Both run the same job functions (``bimcap.frontend.runner.compute_frame`` / ``compute_pair``)
and give the same result bit for bit; the assembly (tracks, landmarks, the solver's arrays), the
frame cache and the solve stay in the calling process. This module imports ``distributed`` only
when a Dask executor is opened.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields
from typing import Any
from urllib.parse import urlsplit

from bimcap.frontend.errors import FrontendError, FrontendInputError
from bimcap.methods import ExecutorKind

#: Protocols whose address is a TCP host and port (checked with a plain socket connect).
_TCP_PROTOCOLS = ("tcp", "tls")


class SchedulerUnreachableError(FrontendInputError):
    """The Dask scheduler address given cannot be parsed or reached (names the address)."""


@dataclass(frozen=True)
class ExecutorOptions:
    """Where the front end's jobs run.

    Attributes
    ----------
    kind: LOCAL (a process pool on this machine) or DASK (a Dask cluster).
    scheduler: DASK only: address of a running scheduler, ``tcp://HOST:PORT``; None starts a
        ``LocalCluster`` on this machine for the run.
    dask_workers: worker processes of the ``LocalCluster`` (None: the run's ``workers``, else
        all cores). Ignored with ``scheduler`` (the cluster has the workers it has).
    threads_per_worker: threads of each ``LocalCluster`` worker process (1: the jobs hold the
        GIL in numpy / OpenCV code often enough that processes scale better).
    connect_timeout_s: seconds to wait for the scheduler to answer.
    worker_timeout_s: seconds to wait for a running scheduler to have at least one worker.
    """

    kind: ExecutorKind = ExecutorKind.LOCAL
    scheduler: str | None = None
    dask_workers: int | None = None
    threads_per_worker: int = 1
    connect_timeout_s: float = 10.0
    worker_timeout_s: float = 60.0

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "kind", ExecutorKind(self.kind))
        except ValueError:
            raise FrontendInputError(
                f"executor must be one of {', '.join(k.value for k in ExecutorKind)}, "
                f"got {self.kind!r}", None, "executor") from None
        for name in ("dask_workers", "threads_per_worker"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or isinstance(value, bool)
                                      or value < 1):
                key = "workers" if name == "dask_workers" else name
                raise FrontendInputError(f"must be an integer >= 1, got {value!r}", None,
                                         f"dask.{key}")
        for name in ("connect_timeout_s", "worker_timeout_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise FrontendInputError(f"must be > 0 s, got {value!r}", None, f"dask.{name}")
        if self.scheduler is not None:
            if not isinstance(self.scheduler, str):
                raise FrontendInputError(f"must be an address tcp://HOST:PORT, got "
                                         f"{self.scheduler!r}", None, "dask.scheduler")
            parse_scheduler_address(self.scheduler)

    @classmethod
    def from_table(cls, kind: ExecutorKind | str, table: dict[str, Any],
                   where: str | os.PathLike[str] | None = None) -> ExecutorOptions:
        """Options from a ``[dask]`` settings table (keys: the fields other than ``kind``,
        ``workers`` for ``dask_workers``); an unknown key raises naming ``dask.<key>``."""
        known = sorted(({f.name for f in fields(cls)} - {"kind", "dask_workers"}) | {"workers"})
        unknown = sorted(set(table) - set(known))
        if unknown:
            raise FrontendInputError(f"unknown key(s) {unknown}; known: {known}", where,
                                     f"dask.{unknown[0]}")
        values = dict(table)
        if "workers" in values:
            values["dask_workers"] = values.pop("workers")
        try:
            return cls(kind=ExecutorKind(kind), **values)
        except FrontendInputError as exc:
            raise FrontendInputError(exc.message, where, exc.field) from None

    @property
    def is_dask(self) -> bool:
        return self.kind is ExecutorKind.DASK

    def to_dict(self) -> dict[str, object]:
        return {"kind": self.kind.value, "scheduler": self.scheduler,
                "dask_workers": self.dask_workers, "threads_per_worker": self.threads_per_worker,
                "connect_timeout_s": self.connect_timeout_s,
                "worker_timeout_s": self.worker_timeout_s}


def parse_scheduler_address(address: str) -> tuple[str, str, int]:
    """``(protocol, host, port)`` of ``tcp://HOST:PORT`` (``HOST:PORT`` means tcp).

    Raises
    ------
    SchedulerUnreachableError
        The address has no host or no valid port (the message names it).
    """
    text = address.strip()
    parts = urlsplit(text if "://" in text else f"tcp://{text}")
    try:
        port = parts.port
    except ValueError:
        port = None
    if not parts.hostname or port is None or port == 0:
        raise SchedulerUnreachableError(
            f"{address!r} is not a scheduler address: expected tcp://HOST:PORT "
            "(e.g. tcp://10.0.0.5:8786)", None, "dask.scheduler")
    return parts.scheme, parts.hostname, port


def check_scheduler(address: str, timeout_s: float = 10.0) -> None:
    """Raise :class:`SchedulerUnreachableError` naming ``address`` unless something accepts a
    connection there (a cheap check before any expensive work; the Dask handshake comes later).
    Addresses of other protocols than tcp / tls are only parsed."""
    protocol, host, port = parse_scheduler_address(address)
    if protocol not in _TCP_PROTOCOLS:
        return
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        raise SchedulerUnreachableError(_unreachable(address, exc), None,
                                        "dask.scheduler") from None


def _unreachable(address: str, exc: BaseException) -> str:
    reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
    return (f"cannot reach the Dask scheduler at {address}: {reason or type(exc).__name__} "
            "(start one with `dask scheduler` and workers with `dask worker ADDRESS`, or use "
            "--dask without a scheduler for a LocalCluster on this machine)")


def require_distributed() -> None:
    """Raise :class:`bimcap.errors.MissingDependencyError` (install ``bimcap[dask]``) unless
    ``distributed`` imports."""
    from bimcap.errors import require

    require("distributed", "dask[distributed]", "dask", "the Dask executor (--dask)")


def local_dask_workers(options: ExecutorOptions, workers: int | None) -> int:
    """Worker processes of a LocalCluster: ``dask_workers``, else ``workers``, else all cores."""
    return int(options.dask_workers or workers or os.cpu_count() or 1)


@contextmanager
def dask_client(options: ExecutorOptions, workers: int | None = None) -> Iterator[Any]:
    """A ``distributed.Client`` for ``options`` (kind DASK), closed on exit.

    With ``options.scheduler`` it connects to that cluster (left running) and waits for at
    least one worker; otherwise it starts a ``LocalCluster`` of :func:`local_dask_workers`
    processes (no dashboard, a free port) and closes it on exit, however the block ends.

    Raises
    ------
    SchedulerUnreachableError
        Nothing answers at ``options.scheduler``.
    MissingDependencyError
        ``distributed`` is not installed (``bimcap[dask]``).
    FrontendError
        The scheduler has no worker after ``worker_timeout_s``.
    """
    require_distributed()
    from distributed import Client, LocalCluster

    if options.scheduler is not None:
        check_scheduler(options.scheduler, options.connect_timeout_s)
        try:
            client = Client(options.scheduler,  # type: ignore[no-untyped-call]
                            timeout=options.connect_timeout_s, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise SchedulerUnreachableError(_unreachable(options.scheduler, exc), None,
                                            "dask.scheduler") from None
        with client:
            try:
                client.wait_for_workers(1, timeout=options.worker_timeout_s)
            except TimeoutError:
                raise FrontendError(
                    f"the Dask scheduler at {options.scheduler} has no worker after "
                    f"{options.worker_timeout_s:g} s; start some with "
                    f"`dask worker {options.scheduler}`") from None
            yield client
        return
    n = local_dask_workers(options, workers)
    with (
        LocalCluster(n_workers=n,  # type: ignore[no-untyped-call]
                     threads_per_worker=options.threads_per_worker, processes=True,
                     dashboard_address="127.0.0.1:0") as cluster,
        Client(cluster, set_as_default=False) as client,  # type: ignore[no-untyped-call]
    ):
        yield client


def cluster_threads(client: Any) -> int:
    """Threads of all the workers of ``client``'s cluster now (at least 1)."""
    return max(1, sum(int(n) for n in client.nthreads().values()))
