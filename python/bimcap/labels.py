"""Semantic label ids, shared by label images, point clouds and the solver."""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class Label(IntEnum):
    """Per-pixel / per-point semantic class. Stored as uint8 in PNGs and PLY files."""

    UNKNOWN = 0
    WALL = 1
    FLOOR = 2
    CEILING = 3
    COLUMN = 4
    DOOR = 5
    WINDOW = 6
    CLUTTER = 7


#: RGB colour of each label for pictures and coloured PLYs, indexed by label id, shape (8, 3) uint8.
LABEL_COLORS = np.array(
    [
        [128, 128, 128],  # unknown
        [220, 60, 60],  # wall
        [60, 100, 220],  # floor
        [240, 200, 60],  # ceiling
        [40, 180, 90],  # column
        [150, 80, 200],  # door
        [80, 210, 230],  # window
        [250, 140, 40],  # clutter
    ],
    dtype=np.uint8,
)
