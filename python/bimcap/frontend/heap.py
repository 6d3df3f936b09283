"""glibc's heap kept between the front end's jobs instead of handed back to the kernel.

A frame's work allocates and frees a few hundred arrays of 0.1–5 MB (image-sized maps in
float32 and float64, the returns' tables, OpenCV's SIFT pyramid). With glibc's defaults each
such block is either its own ``mmap`` (above the dynamic mmap threshold) or carved from the heap
top, which ``free`` trims back to the kernel as soon as more than the trim threshold lies free
there (128 KiB at first; glibc raises both as blocks are freed, but not past the trim of a heap
top that keeps moving). Either way the next frame faults the same memory in again, zeroed by the
kernel: ~4,000 minor page faults a frame at 516×386, 5–8 % of the front end's CPU time (docs/
speed.md, "The heap kept between frames").

:func:`keep_freed_heap` fixes both thresholds once a process (``mallopt``): blocks under
:data:`MMAP_THRESHOLD_BYTES` come from the heap, and up to :data:`TRIM_THRESHOLD_BYTES` of freed
heap top stays mapped for the next frame. Nothing the front end computes changes (the same
bytes, in other pages); a process keeps at most that much more memory than it uses. The front
end's jobs call it (:func:`bimcap.frontend.runner.compute_frame`, ``compute_pair``), so it
applies in the worker processes, in Dask workers (whose nanny starts them with
``MALLOC_TRIM_THRESHOLD_=65536``, the opposite) and, with one worker, in the calling process.
Elsewhere than glibc (macOS, musl) it does nothing.
"""

from __future__ import annotations

import ctypes
import platform

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


def keep_freed_heap() -> bool:
    """Set glibc's mmap and trim thresholds for the front end's jobs, once a process.

    Returns whether they are set (False where the C library is not glibc or refused them).
    Never raises: a C library without ``mallopt`` leaves the process as it was.
    """
    global _APPLIED
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
