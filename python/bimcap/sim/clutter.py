"""Clutter the BIM does not have: boxes, pallets, scaffolding frames and people.

Objects are placed on the storey floor in free cells that keep clear of the walking path (so the
walker never runs into them) and of each other; they may stand against walls, as on a real site.
Every clutter triangle is labelled :attr:`~bimcap.labels.Label.CLUTTER`.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from bimcap.labels import Label
from bimcap.sim.render import MeshPart
from bimcap.sim.texture import Material
from bimcap.sim.walk import FreeSpace

F64 = NDArray[np.float64]

# the 12 triangles of the unit cube [0, 1]³ with outward normals
_CUBE_V = np.array(
    [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
    dtype=np.float64,
)
_CUBE_F = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
     [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]],
    dtype=np.int32,
)


class ClutterKind(str, Enum):
    BOXES = "boxes"
    PALLET = "pallet"
    SCAFFOLD = "scaffold"
    PERSON = "person"


def box_mesh(
    lo: F64, hi: F64, yaw: float = 0.0, pivot: F64 | None = None
) -> tuple[F64, NDArray[np.int32]]:
    """A box ``[lo, hi]`` (3,) rotated by ``yaw`` about the vertical through ``pivot``.

    Returns (8, 3) vertices and (12, 3) faces.
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    v = lo + _CUBE_V * (hi - lo)
    if yaw != 0.0:
        p = np.zeros(3) if pivot is None else np.asarray(pivot, np.float64)
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        v = (v - p) @ rot.T + p
    return v, _CUBE_F.copy()


def cylinder_mesh(center_xy: F64, z0: float, z1: float, radius: float, segments: int = 16
                  ) -> tuple[F64, NDArray[np.int32]]:
    """A closed vertical cylinder: (2·segments + 2, 3) vertices, (4·segments, 3) faces."""
    a = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a)], axis=-1) * radius + np.asarray(center_xy)
    bottom = np.concatenate([ring, np.full((segments, 1), z0)], axis=1)
    top = np.concatenate([ring, np.full((segments, 1), z1)], axis=1)
    cx, cy = center_xy
    v = np.concatenate([bottom, top, [[cx, cy, z0], [cx, cy, z1]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    cb, ct = 2 * segments, 2 * segments + 1
    side1 = np.stack([i, j, j + segments], axis=-1)
    side2 = np.stack([i, j + segments, i + segments], axis=-1)
    cap_b = np.stack([np.full(segments, cb), j, i], axis=-1)
    cap_t = np.stack([np.full(segments, ct), i + segments, j + segments], axis=-1)
    return v, np.concatenate([side1, side2, cap_b, cap_t]).astype(np.int32)


def _merge(parts: list[tuple[F64, NDArray[np.int32]]]) -> tuple[F64, NDArray[np.int32]]:
    verts, faces, n = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces).astype(np.int32)


@dataclass(frozen=True)
class ClutterObject:
    """One placed object: kind, centre xy (metres), footprint radius and its mesh part."""

    kind: ClutterKind
    center_xy: tuple[float, float]
    radius: float
    part: MeshPart

    def to_dict(self) -> dict[str, object]:
        return {"kind": self.kind.value, "center_xy": list(self.center_xy), "radius": self.radius}


def make_object(kind: ClutterKind, center: F64, z0: float, rng: np.random.Generator, name: str
                ) -> tuple[MeshPart, float]:
    """Build one clutter object standing on ``z0`` at ``center`` (2,); returns (part, radius)."""
    cx, cy = float(center[0]), float(center[1])
    yaw = float(rng.uniform(0.0, np.pi))
    piv = np.array([cx, cy, z0])
    pieces: list[tuple[F64, NDArray[np.int32]]] = []
    if kind is ClutterKind.BOXES:
        material = Material.CARDBOARD
        size = rng.uniform(0.35, 0.8)
        z = z0
        for _ in range(int(rng.integers(1, 4))):
            s = size * rng.uniform(0.7, 1.0)
            h = s * rng.uniform(0.6, 1.0)
            off = rng.uniform(-0.05, 0.05, 2)
            lo = np.array([cx - s / 2 + off[0], cy - s / 2 + off[1], z])
            pieces.append(box_mesh(lo, lo + np.array([s, s, h]), yaw, piv))
            z += h
        radius = size * 0.75
    elif kind is ClutterKind.PALLET:
        material = Material.WOOD
        lx, ly = 1.2, 0.8
        for k in range(3):  # runners
            y = cy - ly / 2 + k * (ly - 0.1) / 2
            lo = [cx - lx / 2, y, z0]
            pieces.append(box_mesh(lo, [cx + lx / 2, y + 0.1, z0 + 0.1], yaw, piv))
        for k in range(5):  # top boards
            x = cx - lx / 2 + k * (lx - 0.14) / 4
            pieces.append(box_mesh([x, cy - ly / 2, z0 + 0.1], [x + 0.14, cy + ly / 2, z0 + 0.144],
                                   yaw, piv))
        if rng.random() < 0.6:  # a load of bagged material or blocks
            h = rng.uniform(0.3, 0.9)
            top = z0 + 0.144
            pieces.append(box_mesh([cx - 0.5, cy - 0.35, top], [cx + 0.5, cy + 0.35, top + h],
                                   yaw, piv))
        radius = 0.75
    elif kind is ClutterKind.SCAFFOLD:
        material = Material.METAL
        lx, ly, hz, t = rng.uniform(1.5, 2.5), 0.75, rng.uniform(1.8, 2.4), 0.05
        for sx in (-1, 1):
            for sy in (-1, 1):
                x, y = cx + sx * (lx / 2 - t), cy + sy * (ly / 2 - t)
                lo = [x - t / 2, y - t / 2, z0]
                pieces.append(box_mesh(lo, [x + t / 2, y + t / 2, z0 + hz], yaw, piv))
        for zl in (z0 + 0.15, z0 + hz / 2, z0 + hz - 0.05):
            for sy in (-1, 1):
                y = cy + sy * (ly / 2 - t)
                pieces.append(box_mesh([cx - lx / 2, y - t / 2, zl - t / 2],
                                       [cx + lx / 2, y + t / 2, zl + t / 2], yaw, piv))
        # a deck board at mid height
        deck = z0 + hz / 2
        pieces.append(box_mesh([cx - lx / 2, cy - ly / 2, deck],
                               [cx + lx / 2, cy + ly / 2, deck + 0.04],
                               yaw, piv))
        radius = float(np.hypot(lx, ly) / 2)
    elif kind is ClutterKind.PERSON:
        material = Material.FABRIC
        r = rng.uniform(0.18, 0.25)
        pieces.append(cylinder_mesh((cx, cy), z0, z0 + rng.uniform(1.6, 1.85), r))
        radius = r
    else:  # pragma: no cover
        raise ValueError(kind)
    v, f = _merge(pieces)
    return MeshPart(name, Label.CLUTTER, v, f, material), float(radius)


def place_clutter(
    free: FreeSpace,
    path_xy: F64,
    rng: np.random.Generator,
    density_per_m2: float = 0.08,
    path_margin_m: float = 0.6,
    kinds: tuple[ClutterKind, ...] = tuple(ClutterKind),
) -> list[ClutterObject]:
    """Place clutter objects in ``free`` away from the walking path ``path_xy`` (P, 2).

    An object of footprint radius r goes to a cell whose clearance is ≥ r·0.9 (it fits, possibly
    touching a wall), whose distance to the path is ≥ r + ``path_margin_m``, and which is at least
    r + r' + 0.2 m from every placed object. About ``density_per_m2`` objects per m² of free area.
    """
    from scipy.spatial import cKDTree

    res = free.resolution
    rr, cc = np.nonzero(free.region)
    xy = np.stack([cc, rr], axis=-1) * res + free.origin_xy
    clear = free.clearance[rr, cc]
    d_path, _ = cKDTree(path_xy).query(xy)
    n_obj = round(density_per_m2 * len(rr) * res * res)
    placed: list[ClutterObject] = []
    for k in range(n_obj):
        kind = kinds[int(rng.integers(len(kinds)))]
        part, radius = make_object(kind, np.zeros(2), free.z_floor, rng, f"clutter-{k:03d}")
        ok = (clear >= 0.9 * radius) & (d_path >= radius + path_margin_m)
        for obj in placed:
            ok &= np.linalg.norm(xy - obj.center_xy, axis=1) >= radius + obj.radius + 0.2
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            continue
        c = xy[idx[int(rng.integers(len(idx)))]]
        dz = float(free.floor_at(c[None, :])[0]) - free.z_floor  # stands on the local floor
        part = MeshPart(part.name, part.label, part.vertices + np.array([c[0], c[1], dz]),
                        part.faces, part.material)
        # the object was built around the origin; its yaw pivot moved with it
        placed.append(ClutterObject(kind, (float(c[0]), float(c[1])), radius, part))
    return placed
