"""The semantic point cloud: uniform surface samples of the BIM meshes, one label per point.

Sampling is area-uniform: triangle ``i`` gets ``Poisson(area_i · density)`` points, placed with
uniform barycentric coordinates, so the expected count per m² is ``density`` on every surface.
The PLY is binary little-endian with ``x y z`` float32 (metres, world frame) and ``red green blue
label`` uchar (label ids of :class:`~bimcap.labels.Label`, colours of ``LABEL_COLORS``).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bimcap.bim.ingest import BimModel, concatenate_meshes, label_name
from bimcap.io.atomic import atomic_write_text
from bimcap.io.ply import Precision, read_labelled_ply, write_labelled_ply
from bimcap.labels import Label


def sample_surface(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int32],
    density_per_m2: float,
    rng: np.random.Generator,
) -> NDArray[np.float64]:
    """Area-uniform random points on a triangle mesh.

    Parameters
    ----------
    vertices: (V, 3) metres. faces: (F, 3) int32. density_per_m2: expected points per m².
    rng: the random generator.

    Returns
    -------
    (P, 3) float64 points in metres.
    """
    if len(faces) == 0 or density_per_m2 <= 0:
        return np.zeros((0, 3))
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    counts = rng.poisson(area * density_per_m2)
    idx = np.repeat(np.arange(len(tri)), counts)
    r1 = np.sqrt(rng.random(idx.size))
    r2 = rng.random(idx.size)
    a = 1.0 - r1
    b = r1 * (1.0 - r2)
    c = r1 * r2
    t = tri[idx]
    return a[:, None] * t[:, 0] + b[:, None] * t[:, 1] + c[:, None] * t[:, 2]


def sample_model(
    model: BimModel,
    density_per_m2: float,
    seed: int,
    labels: tuple[Label, ...] = tuple(Label),
) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """The semantic cloud of ``model``: (P, 3) float64 metres and (P,) uint8 labels."""
    rng = np.random.default_rng(seed)
    pts, labs = [], []
    for lab in labels:
        if not model.by_label(lab):
            continue
        v, f = model.mesh(lab)
        p = sample_surface(v, f, density_per_m2, rng)
        pts.append(p)
        labs.append(np.full(len(p), int(lab), dtype=np.uint8))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.uint8)
    return np.concatenate(pts), np.concatenate(labs)


def write_ply(
    path: str | PathLike[str], points: NDArray[np.float64], labels: NDArray[np.uint8]
) -> None:
    """Write the semantic cloud: (P, 3) points, (P,) labels, float32 coordinates, atomically
    (:func:`bimcap.io.ply.write_labelled_ply`)."""
    write_labelled_ply(path, points, labels, Precision.FLOAT32,
                       "bimcap semantic cloud: world frame (IFC), metres; "
                       "label = bimcap.labels.Label")


def read_ply(path: str | PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """Read a cloud written by :func:`write_ply`: (P, 3) float64 points, (P,) uint8 labels."""
    return read_labelled_ply(path)


def write_class_meshes(model: BimModel, directory: str | PathLike[str]) -> list[Path]:
    """One Wavefront OBJ per semantic class (``mesh_wall.obj`` ...), world metres; returns paths."""
    d = Path(directory)
    out = []
    for lab in Label:
        elems = model.by_label(lab)
        if not elems:
            continue
        v, f = concatenate_meshes(elems)
        lines = [f"# bimcap {label_name(lab)} mesh, world frame (IFC), metres\n"]
        lines.append("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in v))
        lines.append("".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
        path = d / f"mesh_{label_name(lab)}.obj"
        atomic_write_text(path, "".join(lines))
        out.append(path)
    return out
