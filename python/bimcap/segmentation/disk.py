"""Label images from disk: bimcap label-id PNGs, or BIMCaP-style per-class binary masks.

BIMCaP/FACaP ship, per frame, binary masks named ``{stem}_wall.png``, ``{stem}_floor.png``,
``{stem}_ceiling.png`` and ``{stem}_columns.png`` (``stem`` like ``frame-000123``; non-zero =
in the class). They are merged into one label image; where masks overlap the later class in
``priority`` wins (default floor < ceiling < wall < column: a column in front of a wall is the
usual overlap). Pixels in no mask get ``background``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimcap.geometry import Camera
from bimcap.labels import Label
from bimcap.segmentation.base import U8, FrameInput, check_shape
from bimcap.segmentation.errors import SegmentationInputError

#: mask file suffix of each class in BIMCaP's data
BIMCAP_MASK_SUFFIXES: dict[Label, str] = {
    Label.FLOOR: "floor",
    Label.CEILING: "ceiling",
    Label.WALL: "wall",
    Label.COLUMN: "columns",
}


def _imread(path: Path) -> np.ndarray:
    import cv2

    if not path.is_file():
        raise SegmentationInputError("label file not found", path=path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SegmentationInputError("cannot decode the image", path=path)
    return img


def read_label_image(path: str | Path, camera: Camera | None = None) -> U8:
    """Read an (H, W) uint8 PNG of bimcap label ids; checks the ids and (optionally) the size."""
    p = Path(path)
    img = _imread(p)
    if img.ndim != 2:
        raise SegmentationInputError(
            f"label image must be single-channel, got shape {img.shape}", path=p
        )
    if img.dtype != np.uint8:
        raise SegmentationInputError(f"label image must be 8-bit, got {img.dtype}", path=p)
    if camera is not None:
        check_shape(img, camera, "labels", str(p))
    bad = img > max(int(x) for x in Label)
    if bad.any():
        raise SegmentationInputError(
            f"{int(bad.sum())} pixels hold ids outside 0..{max(Label)}", path=p, field="labels"
        )
    return img


def read_class_masks(
    directory: str | Path,
    stem: str,
    camera: Camera | None = None,
    suffixes: dict[Label, str] | None = None,
    priority: tuple[Label, ...] = (Label.FLOOR, Label.CEILING, Label.WALL, Label.COLUMN),
    background: Label = Label.UNKNOWN,
    missing_ok: bool = False,
) -> U8:
    """Merge per-class masks ``{directory}/{stem}_{suffix}.png`` into one label image.

    ``missing_ok`` lets a class's mask be absent (treated as empty); at least one must exist.
    """
    d = Path(directory)
    sfx = suffixes or BIMCAP_MASK_SUFFIXES
    out: U8 | None = None
    found = 0
    for label in priority:
        if label not in sfx:
            continue
        path = d / f"{stem}_{sfx[label]}.png"
        if not path.is_file():
            if missing_ok:
                continue
            raise SegmentationInputError(f"mask of class {label.name.lower()} not found", path=path)
        m = _imread(path)
        if m.ndim == 3:
            m = m.max(axis=2)
        if camera is not None:
            check_shape(m, camera, f"{label.name.lower()} mask", str(path))
        if out is None:
            out = np.full(m.shape[:2], int(background), dtype=np.uint8)
        elif m.shape[:2] != out.shape:
            raise SegmentationInputError(
                f"mask size {m.shape[:2]} differs from the others' {out.shape}", path=path
            )
        out[m > 0] = int(label)
        found += 1
    if out is None or found == 0:
        raise SegmentationInputError(f"no class masks for frame {stem!r}", path=d)
    return out


@dataclass(frozen=True)
class DiskLabelProvider:
    """Label-id PNGs ``{directory}/{stem}.png``."""

    directory: Path

    def segment(self, frame: FrameInput) -> U8:
        if frame.stem is None:
            raise SegmentationInputError("frame has no file stem", field="stem")
        return read_label_image(Path(self.directory) / f"{frame.stem}.png", frame.camera)


@dataclass(frozen=True)
class DiskMaskProvider:
    """BIMCaP per-class masks ``{directory}/{stem}_{class}.png``."""

    directory: Path
    suffixes: dict[Label, str] = field(default_factory=lambda: dict(BIMCAP_MASK_SUFFIXES))
    background: Label = Label.UNKNOWN
    missing_ok: bool = False

    def segment(self, frame: FrameInput) -> U8:
        if frame.stem is None:
            raise SegmentationInputError("frame has no file stem", field="stem")
        return read_class_masks(
            self.directory, frame.stem, frame.camera, self.suffixes,
            background=self.background, missing_ok=self.missing_ok,
        )
