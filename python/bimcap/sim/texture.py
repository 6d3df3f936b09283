"""Procedural, view-consistent surface textures for the simulated camera.

A texture is a function of the 3-D surface point, never of the pixel: a hit point ``p_in_world``
on a face with normal ``n`` gets planar surface coordinates ``(s, t)`` in metres by dropping the
normal's dominant axis (floors and ceilings use ``(x, y)``, walls facing ±x use ``(y, z)``, walls
facing ±y use ``(x, z)``), shifted by a per-element random offset so that neighbouring elements do
not share a pattern. ``(s, t)`` index a periodic albedo tile of the element's :class:`Material`
(multi-octave value noise plus a per-material pattern: floor tiles with grout, plaster blotches,
concrete speckle and formwork seams, wood grain ...). The same surface point therefore has the same
albedo in every frame, which is what SIFT needs to match neighbouring images.

Tiles are baked once per seed into mip-mapped atlases and sampled with trilinear filtering at the
mip level of each pixel's footprint (``depth / (f cos θ)``), so distant surfaces do not alias into
view-dependent noise. A second, coarse "grime" tile multiplies the albedo at a 50 m period to break
the tile's 4 m periodicity.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]

#: Texels per tile side (a power of two) and texel size in metres: a 4.096 m period.
TILE_TEXELS = 1024
TEXEL_M = 0.004
#: Texel size of the coarse grime modulation tile (256 texels → 51.2 m period).
GRIME_TEXELS = 256
GRIME_TEXEL_M = 0.2
#: Period of the grime tile (a multiple of the albedo tile's 4.096 m period is not needed).
GRIME_PERIOD_M = GRIME_TEXELS * GRIME_TEXEL_M


class Material(IntEnum):
    """Surface appearance classes; one baked albedo tile each."""

    PLASTER = 0  # walls
    TILES = 1  # floors
    CONCRETE = 2  # columns, bare slabs
    CEILING = 3  # acoustic ceiling panels
    WOOD = 4  # doors, pallets
    GLASS = 5  # windows
    CARDBOARD = 6  # boxes
    METAL = 7  # scaffolding
    FABRIC = 8  # people


#: Diffuse LiDAR reflectivity (0..1) of each material, indexed by Material value.
REFLECTIVITY = np.array([0.75, 0.45, 0.35, 0.8, 0.5, 0.08, 0.55, 0.6, 0.25], dtype=np.float32)


def _periodic_value_noise(rng: np.random.Generator, n: int, cells: int) -> F32:
    """(n, n) periodic value noise in [0, 1] with ``cells`` lattice cells per side.

    The random lattice is wrap-padded and upsampled by ``n / cells`` with bicubic interpolation
    (``cells`` must divide ``n``), then cropped to exactly one period.
    """
    import cv2

    if n % cells:
        raise ValueError(f"{cells} cells do not divide {n} texels")
    lattice = rng.random((cells, cells), dtype=np.float32)
    if cells == n:
        return lattice
    k = n // cells
    pad = 2
    padded = np.pad(lattice, pad, mode="wrap")
    big = cv2.resize(padded, ((cells + 2 * pad) * k, (cells + 2 * pad) * k),
                     interpolation=cv2.INTER_CUBIC)
    return np.ascontiguousarray(big[pad * k : pad * k + n, pad * k : pad * k + n])


def fractal_noise(
    rng: np.random.Generator,
    n: int,
    base_cells: int = 4,
    octaves: int = 8,
    persistence: float = 0.6,
) -> F32:
    """(n, n) periodic multi-octave value noise normalised to zero mean and unit std."""
    acc = np.zeros((n, n), dtype=np.float32)
    amp = 1.0
    cells = base_cells
    for _ in range(octaves):
        if cells > n:
            break
        acc += amp * _periodic_value_noise(rng, n, cells)
        amp *= persistence
        cells *= 2
    acc -= acc.mean()
    acc /= acc.std() + 1e-6
    return acc


def _grid_lines(n: int, period: int, width: int, offset: int = 0) -> F32:
    """(n,) 1 on texels within ``width`` of a multiple of ``period`` (periodic), else 0."""
    i = (np.arange(n) + offset) % period
    return ((i < width) | (i >= period - width + 1)).astype(np.float32)


def _bake_material(material: Material, rng: np.random.Generator, n: int) -> F32:
    """(n, n, 3) albedo in [0, 1] of one material; axis 0 = t (vertical / y), axis 1 = s."""
    noise = fractal_noise(rng, n)
    fine = fractal_noise(rng, n, base_cells=64, octaves=4, persistence=0.7)
    speck = rng.random((n, n), dtype=np.float32)
    # blob-like marks of 2-6 cm (stains, aggregate, filler patches): what SIFT locks on to
    blob_field = fractal_noise(rng, n, base_cells=64, octaves=3, persistence=0.5)
    blobs = np.clip((np.abs(blob_field) - 1.4) * 2.5, 0.0, 1.0) * np.sign(blob_field)
    if material is Material.PLASTER:
        blotch = fractal_noise(rng, n, base_cells=8, octaves=4)
        grey = 0.72 + 0.06 * noise + 0.07 * fine + 0.09 * np.tanh(2.0 * blotch) + 0.14 * blobs
        grey -= 0.25 * (speck > 0.996)  # small pores
        colour = np.array([1.0, 0.97, 0.9], dtype=np.float32)
    elif material is Material.TILES:
        period = n // 8  # 0.512 m tiles
        grout = np.maximum(_grid_lines(n, period, 2)[:, None], _grid_lines(n, period, 2)[None, :])
        tile_id = (np.arange(n) // period)[:, None] * 8 + (np.arange(n) // period)[None, :]
        tint = rng.random(64, dtype=np.float32)[tile_id]
        grey = 0.55 + 0.12 * tint + 0.07 * noise + 0.08 * fine + 0.12 * blobs
        grey = grey * (1.0 - 0.6 * grout)
        grey += 0.2 * (speck > 0.997)
        colour = np.array([0.95, 0.9, 0.82], dtype=np.float32)
    elif material is Material.CONCRETE:
        seams = np.maximum(_grid_lines(n, n // 4, 1)[:, None], _grid_lines(n, n // 2, 1)[None, :])
        grey = 0.5 + 0.08 * noise + 0.1 * fine + 0.15 * blobs
        grey -= 0.3 * (speck > 0.985) - 0.15 * (speck < 0.01)
        grey *= 1.0 - 0.45 * seams
        colour = np.array([1.0, 1.0, 0.98], dtype=np.float32)
    elif material is Material.CEILING:
        period = n // 8
        frame = np.maximum(_grid_lines(n, period, 3)[:, None], _grid_lines(n, period, 3)[None, :])
        holes = (speck > 0.97).astype(np.float32)
        grey = 0.8 + 0.04 * noise + 0.06 * fine - 0.35 * holes + 0.1 * blobs
        grey = grey * (1.0 - 0.35 * frame)
        colour = np.array([0.98, 0.98, 1.0], dtype=np.float32)
    elif material is Material.WOOD:
        t_coord = np.arange(n, dtype=np.float32)[:, None]
        warp = fractal_noise(rng, n, base_cells=4, octaves=3)
        grain = np.sin(2.0 * np.pi * (t_coord / 6.0 + 0.8 * warp))
        grey = 0.5 + 0.1 * grain + 0.08 * noise + 0.07 * fine + 0.1 * blobs
        colour = np.array([1.0, 0.72, 0.45], dtype=np.float32)
    elif material is Material.GLASS:
        grey = 0.18 + 0.06 * noise + 0.03 * fine
        colour = np.array([0.75, 0.9, 1.0], dtype=np.float32)
    elif material is Material.CARDBOARD:
        tape = _grid_lines(n, n // 2, 12, offset=-n // 4)[None, :]
        grey = 0.55 + 0.07 * noise + 0.08 * fine + 0.15 * tape + 0.12 * blobs
        grey -= 0.25 * (speck > 0.995)
        colour = np.array([0.95, 0.72, 0.45], dtype=np.float32)
    elif material is Material.METAL:
        scratches = (fractal_noise(rng, n, base_cells=128, octaves=2) > 2.0).astype(np.float32)
        grey = 0.55 + 0.08 * noise + 0.07 * fine + 0.3 * scratches + 0.12 * blobs
        colour = np.array([0.55, 0.65, 0.95], dtype=np.float32)
    elif material is Material.FABRIC:
        weave = _grid_lines(n, 6, 1)[:, None] * 0.5 + _grid_lines(n, 6, 1)[None, :] * 0.5
        hivis = _grid_lines(n, n // 4, 16)[:, None]  # reflective band
        grey = 0.35 + 0.06 * noise + 0.05 * fine - 0.05 * weave + 0.4 * hivis
        colour = np.array([0.35, 0.45, 0.8], dtype=np.float32) * (1 - hivis[..., None]) + (
            np.array([1.0, 0.6, 0.1], dtype=np.float32) * hivis[..., None]
        )
        return np.clip(grey[..., None] * colour, 0.0, 1.0).astype(np.float32)
    else:  # pragma: no cover - every enum member is handled above
        raise ValueError(material)
    return np.clip(grey[..., None] * colour, 0.0, 1.0).astype(np.float32)


def _mip_chain(tile: F32, levels: int) -> list[F32]:
    """Box-filtered mip levels of a periodic (n, n, C) tile, level 0 first."""
    chain = [tile]
    for _ in range(levels - 1):
        t = chain[-1]
        t = 0.25 * (t[0::2, 0::2] + t[1::2, 0::2] + t[0::2, 1::2] + t[1::2, 1::2])
        chain.append(t)
    return chain


@dataclass
class TextureBank:
    """Baked albedo tiles of every :class:`Material` with their mip chains, in one atlas.

    Attributes
    ----------
    atlas: (rows, cols, 3) uint8 image holding, for every material ``m`` and mip level ``l``,
        the tile of side ``n_l = TILE_TEXELS / 2^l`` padded with one wrapped row and column (so
        bilinear filtering across the period edge needs no special case). Level 0 tiles are
        stacked in the first column, the coarser levels of each material in a second column.
    origin_x: (levels,) float32 atlas column of texel (0, 0) of level ``l``.
    origin_y: (materials, levels) float32 atlas row of texel (0, 0) of material ``m``, level ``l``.
    grime: (GRIME_TEXELS+1, GRIME_TEXELS+1) float32 multiplicative modulation around 1.
    seed: the seed the bank was baked from.
    """

    atlas: NDArray[np.uint8]
    origin_x: F32
    origin_y: F32
    grime: F32
    seed: int

    @classmethod
    def bake(cls, seed: int, levels: int = 9) -> TextureBank:
        """Bake every :class:`Material` tile and its mip chain from ``seed`` (deterministic).

        Banks are cached per ``(seed, levels)`` within a process (they are read-only).
        """
        return _bake_cached(seed, levels)

    @classmethod
    def _bake(cls, seed: int, levels: int) -> TextureBank:
        n = TILE_TEXELS
        chains = []
        for m in Material:
            rng = np.random.default_rng([seed, 7919, int(m)])
            chains.append(_mip_chain(_bake_material(m, rng, n), levels))
        n_mat = len(chains)
        coarse_h = sum((n >> lev) + 1 for lev in range(1, levels))
        block_h = max(n + 1, coarse_h)
        atlas = np.zeros((n_mat * block_h, (n + 1) + (n // 2 + 1), 3), np.float32)
        origin_x = np.array([0.0] + [n + 1.0] * (levels - 1), np.float32)
        origin_y = np.zeros((n_mat, levels), np.float32)
        for m, chain in enumerate(chains):
            y = m * block_h
            for lev in range(levels):
                tile = np.pad(chain[lev], ((0, 1), (0, 1), (0, 0)), mode="wrap")
                side = tile.shape[0]
                x0 = int(origin_x[lev])
                atlas[y : y + side, x0 : x0 + side] = tile
                origin_y[m, lev] = y
                if lev > 0:
                    y += side
                else:
                    y = m * block_h  # the coarse column starts at the block's top
        grime_rng = np.random.default_rng([seed, 104729])
        g = 1.0 + 0.12 * np.tanh(fractal_noise(grime_rng, GRIME_TEXELS, base_cells=4, octaves=5))
        grime = np.pad(g, ((0, 1), (0, 1)), mode="wrap").astype(np.float32)
        atlas8 = np.clip(np.rint(atlas * 255.0), 0, 255).astype(np.uint8)
        return cls(atlas8, origin_x, origin_y, grime, seed)

    @property
    def levels(self) -> int:
        return len(self.origin_x)

    def sample(
        self,
        st_m: NDArray[np.float64],
        material: NDArray[np.integer],
        footprint_m: NDArray[np.floating],
    ) -> F32:
        """Albedo at surface coordinates, trilinearly filtered (two mip levels blended).

        Parameters
        ----------
        st_m: (M, 2) surface coordinates ``(s, t)`` in metres (already element-offset; float32 is
            exact enough when they stay below ~100 m).
        material: (M,) :class:`Material` ids.
        footprint_m: (M,) size of one pixel on the surface in metres (selects the mip level).

        Returns
        -------
        (M, 3) float32 albedo in [0, 1].
        """
        m = len(st_m)
        if m == 0:
            return np.zeros((0, 3), np.float32)
        fp = np.maximum(np.asarray(footprint_m, np.float32), np.float32(1e-9))
        lod = np.log2(fp * np.float32(1.0 / TEXEL_M))
        np.clip(lod, 0.0, self.levels - 1.0, out=lod)
        l0 = np.minimum(lod.astype(np.int32), self.levels - 2)
        frac = (lod - l0)[:, None]
        # level-0 texel coordinates in 24.8 fixed point: level l is a right shift by l, the
        # wrap into the tile period a bit mask (periods are powers of two), negatives included
        fixed = (np.asarray(st_m, np.float32) * np.float32(256.0 / TEXEL_M)).astype(np.int32)
        mat = np.asarray(material, np.int32)
        masks = ((TILE_TEXELS >> np.arange(self.levels)) * 256 - 1).astype(np.int32)
        flat_origin_y = self.origin_y.reshape(-1)
        out = None
        for lev in (l0, l0 + 1):
            # texel centres sit at integer + 0.5: shift by half a texel so cv2's grid matches
            q = np.right_shift(fixed, lev[:, None])
            q -= 128
            q &= masks[lev][:, None]
            xy = q.astype(np.float32)
            xy *= np.float32(1.0 / 256.0)
            xy[:, 0] += self.origin_x[lev]
            xy[:, 1] += flat_origin_y[mat * self.levels + lev]
            vals = _remap_points(self.atlas, xy[:, 0], xy[:, 1]).astype(np.float32)
            if out is None:
                out = vals * (1.0 - frac)
            else:
                vals *= frac
                out += vals
        assert out is not None
        g = np.asarray(st_m, np.float32) * np.float32(1.0 / GRIME_TEXEL_M)
        g = np.mod(g, np.float32(GRIME_TEXELS))
        grime = _remap_points(self.grime, g[:, 0], g[:, 1]).reshape(-1, 1)
        out *= grime * np.float32(1.0 / 255.0)
        return out


def _remap_points(image: NDArray[Any], x: NDArray[Any], y: NDArray[Any]) -> NDArray[Any]:
    """Bilinear samples of ``image`` at M points (``x`` column, ``y`` row, texel centres at ints).

    ``cv2.remap`` limits each side of its maps to < 32767, so the M points are laid out as a
    (rows, 4096) map and the padding dropped afterwards. Returns (M, C) or (M,) like ``image``.
    """
    import cv2

    m = len(x)
    cols = 4096
    rows = -(-m // cols)
    map_x = np.zeros(rows * cols, np.float32)
    map_y = np.zeros(rows * cols, np.float32)
    map_x[:m] = x
    map_y[:m] = y
    out = cv2.remap(
        image, map_x.reshape(rows, cols), map_y.reshape(rows, cols), cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out.reshape((rows * cols, *image.shape[2:]))[:m]


@functools.lru_cache(maxsize=2)
def _bake_cached(seed: int, levels: int) -> TextureBank:
    return TextureBank._bake(seed, levels)
