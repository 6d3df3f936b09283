"""glibc's heap kept between the front end's jobs instead of handed back to the kernel.

A frame's work allocates and frees a few hundred arrays of 0.1–5 MB (image-sized maps in
float32 and float64, the returns' tables, OpenCV's SIFT pyramid). With glibc's defaults each
such block is either its own ``mmap`` (above the dynamic mmap threshold) or carved from the heap
top, which ``free`` trims back to the kernel as soon as more than the trim threshold lies free
there (glibc raises both thresholds as blocks are freed, but how far depends on the order in
which the first blocks came and went). In some processes the next frame then faults the same
memory in again, zeroed by the kernel: on ifc-SampleHouse4 ~2,800 minor page faults a frame
(150,000 in a 40-frame bench against 33,000 with the thresholds set, 0.2 s of system time), on
gen-small-s3 in one run of two, on gen-demo-s0 ~200 a frame (docs/speed.md, "The heap kept
between frames").

:func:`keep_freed_heap` fixes both thresholds once a process (``mallopt``): blocks under
:data:`MMAP_THRESHOLD_BYTES` come from the heap, and up to :data:`TRIM_THRESHOLD_BYTES` of freed
heap top stays mapped for the next frame. Nothing the front end computes changes (the same
bytes, in other pages); a process keeps at most that much more memory than it uses. The front
end's jobs call it (:func:`bimcap.frontend.runner.compute_frame`, ``compute_pair``), so it
applies in the worker processes and in Dask's (whose nanny starts them with
``MALLOC_TRIM_THRESHOLD_=65536``, the opposite), but not in the process that called
``run_frontend`` (one worker, or a Dask cluster of threads): that heap is the caller's, whose
other work glibc's own thresholds may suit better (:func:`callers_heap`). Elsewhere than glibc
(macOS, musl) it does nothing.
"""

from __future__ import annotations

import ctypes
import platform
from collections.abc import Iterator
from contextlib import contextmanager

#: Blocks smaller than this come from the heap, not from their own ``mmap`` (32 MiB, glibc's
#: largest: a 1032×772 float64 map is 6.4 MB).
MMAP_THRESHOLD_BYTES = 32 << 20
#: Freed heap top kept mapped up to this size (64 MiB: a frame's arrays at 1032×772 fit).
TRIM_THRESHOLD_BYTES = 64 << 20

# mallopt's parameter numbers (glibc's malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: Whether this process's thresholds were set (None: not tried yet).
_APPLIED: bool | None = None
#: How many front ends this process is running (:func:`callers_heap`): while any, its heap is
#: left as it is.
_CALLERS = 0


@contextmanager
def callers_heap() -> Iterator[None]:
    """The block runs a front end from this process (``run_frontend``): jobs that run here meanwhile
    leave its heap's thresholds as they are (:func:`keep_freed_heap` returns False)."""
    global _CALLERS
    _CALLERS += 1
    try:
        yield
    finally:
        _CALLERS -= 1


def keep_freed_heap() -> bool:
    """Set glibc's mmap and trim thresholds for the front end's jobs, once a process.

    Returns whether they are set (False where the C library is not glibc or refused them, and
    inside :func:`callers_heap`, where nothing is tried). Never raises: a C library without
    ``mallopt`` leaves the process as it was.
    """
    global _APPLIED
    if _CALLERS and not _APPLIED:
        return False
    if _APPLIED is None:
        _APPLIED = _mallopt_thresholds()
    return _APPLIED


def _mallopt_thresholds() -> bool:
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    # mallopt returns 1 on success, 0 for a value it does not take
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
