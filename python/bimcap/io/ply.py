"""Labelled point clouds as PLY: the one writer and reader of bimcap's semantic clouds and maps.

The format is binary little-endian: ``x y z`` as ``float`` (float32) or ``double`` (float64),
then ``red green blue label`` as ``uchar``: label ids of :class:`bimcap.labels.Label`, colours
of :data:`bimcap.labels.LABEL_COLORS`. The BIM's semantic cloud is written as float32 (sampled
surfaces, millimetre precision is plenty); the front end's semantic map as float64 (it is
compared point by point across poses). The reader takes either. float32 keeps millimetres only
near the origin: a cloud asked for as float32 with a coordinate beyond :data:`FLOAT32_MAX_M`
(a georeferenced model's eastings and northings) is written as float64.
"""

from __future__ import annotations

from enum import Enum
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.io.atomic import atomic_write_bytes
from bimcap.labels import LABEL_COLORS

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

_END = b"end_header\n"

#: Largest coordinate (metres) written as float32, whose step there is 1 mm; beyond it float64.
FLOAT32_MAX_M = 8192.0


class Precision(str, Enum):
    """The PLY type of the coordinates."""

    FLOAT32 = "float"
    FLOAT64 = "double"


class PlyError(InputError):
    """A PLY that is not a labelled binary cloud, or labels out of range."""


def _record(precision: Precision) -> np.dtype[np.void]:
    f = "<f4" if precision is Precision.FLOAT32 else "<f8"
    return np.dtype([("x", f), ("y", f), ("z", f), ("red", "u1"), ("green", "u1"),
                     ("blue", "u1"), ("label", "u1")])


def write_labelled_ply(path: str | PathLike[str], points: F64, labels: NDArray[np.integer],
                       precision: Precision, comment: str) -> None:
    """Write (P, 3) ``points`` (metres) with their (P,) ``labels`` (ids in 0..7) atomically,
    with coordinates of ``precision`` (float64 instead of float32 when a coordinate is beyond
    :data:`FLOAT32_MAX_M`, where float32 loses millimetres).

    Raises :class:`PlyError` (naming the file) on mismatched sizes or label ids out of range.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lab = np.asarray(labels).reshape(-1)
    if len(lab) != len(p):
        raise PlyError(f"{len(p)} points but {len(lab)} labels", path, "label")
    if len(lab) and (lab.min() < 0 or lab.max() >= len(LABEL_COLORS)):
        raise PlyError(f"label ids must be in 0..{len(LABEL_COLORS) - 1}", path, "label")
    lab8 = lab.astype(np.uint8)
    if precision is Precision.FLOAT32 and len(p) and float(np.abs(p).max()) > FLOAT32_MAX_M:
        precision = Precision.FLOAT64
    rec = np.empty(len(p), dtype=_record(precision))
    rec["x"], rec["y"], rec["z"] = p[:, 0], p[:, 1], p[:, 2]
    rgb = LABEL_COLORS[lab8]
    rec["red"], rec["green"], rec["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    rec["label"] = lab8
    t = precision.value
    header = (
        f"ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {len(p)}\n"
        f"property {t} x\nproperty {t} y\nproperty {t} z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar label\n"
        "end_header\n"
    )
    atomic_write_bytes(path, header.encode("ascii") + rec.tobytes())


def read_labelled_ply(path: str | PathLike[str]) -> tuple[F64, U8]:
    """Read a cloud written by :func:`write_labelled_ply`: (P, 3) float64 points, (P,) labels."""
    p = Path(path)
    data = p.read_bytes()
    end = data.find(_END)
    if not data.startswith(b"ply\n") or end < 0:
        raise PlyError("not a PLY file", p, "header")
    header = data[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise PlyError("expected a binary little-endian PLY", p, "header")
    if "property uchar label" not in header:
        raise PlyError("not a bimcap labelled cloud (label property missing)", p, "header")
    n = next((int(h.split()[2]) for h in header if h.startswith("element vertex")), None)
    if n is None:
        raise PlyError("no vertex element", p, "header")
    precision = Precision.FLOAT64 if "property double x" in header else Precision.FLOAT32
    rec_type = _record(precision)
    body = data[end + len(_END):]
    if len(body) != n * rec_type.itemsize:
        raise PlyError(f"expected {n} vertices ({n * rec_type.itemsize} bytes), got "
                       f"{len(body)} bytes", p, "vertex")
    rec = np.frombuffer(body, dtype=rec_type)
    pts = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    return pts, rec["label"].copy()
