"""The exception hierarchy shared by every stage, and the exit codes of the command line.

Each stage defines its own subclass of :class:`BimcapError` (``BimError``, ``SimError``,
``FrontendError``, ``SolverError``, ``EvaluationError`` ...) so that callers can catch one stage or
all of bimcap. Errors about user input derive from :class:`InputError` and name the file and the
field that is wrong. Errors of the operating system (:class:`OSError`: permission denied, a
read-only file system, a full disk, a file where a directory is needed) are turned into one line
by :func:`describe_os_error`, the one place that maps them.

Exit codes of ``bimcap`` (and ``bimcap_solve``), docs/reliability.md:

==== =====================================================================================
0    success
1    ``bimcap_solve`` only: usage error (``bimcap`` reports usage errors with 2, as argparse)
2    bad input or settings: a malformed file, a wrong shape, an unusable IFC, an output that
     would replace a file bimcap did not write (without ``--overwrite``)
3    a stage failed on valid input: the solve (non-finite cost, Ceres failure), a pipeline step
4    the operating system refused a file operation: permission denied, read-only file system,
     no space left on the device, a file where a directory is needed
130  interrupted (Ctrl-C)
==== =====================================================================================
"""

from __future__ import annotations

import errno
import importlib
import os
import re
from os import PathLike
from types import ModuleType

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_FAILED = 3
EXIT_OS_ERROR = 4
EXIT_INTERRUPTED = 130


class BimcapError(Exception):
    """Base class of every error bimcap raises on purpose."""


class InputError(BimcapError, ValueError):
    """Bad user input: a malformed file, a wrong shape, NaN poses, a missing frame.

    Parameters
    ----------
    message:
        What is wrong, in words.
    path:
        The file (or directory) the bad input came from, if any.
    field:
        The field, array, column or line inside that file, if known.
    """

    def __init__(
        self, message: str, path: str | PathLike[str] | None = None, field: str | None = None
    ) -> None:
        self.path = None if path is None else str(path)
        self.field = field
        self.message = message
        where = ""
        if self.path is not None:
            where = f"{self.path}: "
        if field is not None:
            where += f"{field}: "
        super().__init__(clean_message(where + message))


class MissingDependencyError(BimcapError, ImportError):
    """An optional dependency that a command needs is not installed (exit code 2): the message
    names the package, what needs it and the pip extra that brings it
    (``pip install 'bimcap[ros]'``).

    Parameters
    ----------
    package: the distribution that is missing ("rosbags").
    extra: the extra of bimcap's pyproject.toml that installs it ("ros"), or None for a core
        dependency that the install lacks (then the message says to install the package).
    needed_for: what needs it, in words ("import-conslam (reading ROS1 bags)").
    reason: the ImportError's text.
    """

    def __init__(self, package: str, extra: str | None, needed_for: str,
                 reason: str = "") -> None:
        self.package, self.extra = package, extra
        why = f" ({reason})" if reason else ""
        how = (f"install bimcap[{extra}]: pip install 'bimcap[{extra}]'" if extra else
               f"bimcap depends on it: pip install {package}")
        super().__init__(f"{needed_for} needs the {package} package, which is not installed"
                         f"{why}; {how}")


def require(module: str, package: str, extra: str | None, needed_for: str) -> ModuleType:
    """``module`` imported, or :class:`MissingDependencyError` naming ``package`` and the
    ``extra`` that installs it: the one guard of bimcap's optional dependencies (Dask, rosbags,
    ONNX Runtime), called where they are used, before any expensive work."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(package, extra, needed_for, str(exc)) from None


_NUMPY_REPR = re.compile(r"\bnp\.(?:float|int|uint|bool|complex|str)_?\d*\((.*?)\)")


def clean_message(message: str) -> str:
    """``message`` without numpy scalar reprs: ``np.float64(1.5)`` reads ``1.5`` (numpy 2 prints
    scalars in lists and ``!r`` that way, which means nothing to a user)."""
    return _NUMPY_REPR.sub(r"\1", message)


#: The words for the errno values a user can meet when bimcap reads and writes files.
_OS_REASONS: dict[int, str] = {
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.ENOSPC: "no space left on the device (disk full)",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large (file-size limit reached)",
    errno.EEXIST: "already exists",
    errno.ENOTDIR: "not a directory (a file is in the way)",
    errno.EISDIR: "is a directory (a file was expected)",
    errno.ENOENT: "no such file or directory",
    errno.ENAMETOOLONG: "file name too long",
    errno.ELOOP: "too many levels of symbolic links",
    errno.EMFILE: "too many open files",
    errno.ENFILE: "too many open files in the system",
    errno.EIO: "input/output error (a failing disk or network file system?)",
    errno.EBUSY: "device or resource busy",
    errno.EXDEV: "cannot move across file systems",
    errno.ENOTEMPTY: "directory not empty",
}


def describe_os_error(exc: OSError) -> str:
    """One line for an :class:`OSError`: the path(s) it concerns and the reason in words.

    ``FileExistsError`` on a path that is an existing file (``mkdir`` of ``-o out`` when ``out`` is
    a file) reads "is a file, not a directory".
    """
    code = exc.errno
    reason = _OS_REASONS.get(code) if code is not None else None
    if reason is None:
        reason = exc.strerror or str(exc) or type(exc).__name__
    path = exc.filename
    if code in (errno.EEXIST, errno.ENOTDIR) and path is not None:
        p = os.fspath(path)
        if os.path.lexists(p) and not os.path.isdir(p):
            reason = "is a file, not a directory"
    where = ""
    if path is not None:
        where = f"{os.fsdecode(path)}: "
        if exc.filename2 is not None:
            where = f"{os.fsdecode(path)} -> {os.fsdecode(exc.filename2)}: "
    return clean_message(f"{where}{reason}")
