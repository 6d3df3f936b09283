"""Any ONNX semantic-segmentation model with a class map → bimcap label ids.

The model takes one RGB image ``(1, 3, h, w)`` float32 (normalised ``(rgb/255 - mean) / std``) and
returns per-class scores ``(1, C, h', w')`` (logits or probabilities; any h', w': the arg-max is
resized to the image with nearest-neighbour). ``class_map`` maps model class indices to
:class:`Label`; unmapped classes become ``unmapped`` (CLUTTER by default: things the BIM does not
hold). :data:`ADE20K_CLASS_MAP` holds the ADE20K-150 indices (0-based, SceneParsing
objectInfo150 order) of wall 0, floor 3, ceiling 5, windowpane 8, door 14, column 42.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bimcap.labels import Label
from bimcap.segmentation.base import U8, FrameInput, check_shape
from bimcap.segmentation.errors import SegmentationInputError

ADE20K_CLASS_MAP: dict[int, Label] = {
    0: Label.WALL,
    3: Label.FLOOR,
    5: Label.CEILING,
    8: Label.WINDOW,
    14: Label.DOOR,
    42: Label.COLUMN,
}

_NAME_TO_LABEL = {
    "wall": Label.WALL,
    "floor": Label.FLOOR,
    "flooring": Label.FLOOR,
    "ceiling": Label.CEILING,
    "column": Label.COLUMN,
    "pillar": Label.COLUMN,
    "door": Label.DOOR,
    "window": Label.WINDOW,
    "windowpane": Label.WINDOW,
}


def class_map_from_names(names: Sequence[str]) -> dict[int, Label]:
    """Class map from a model's class names (e.g. ``"column;pillar"``): each name's first
    ``;``/``,``-separated word that bimcap knows decides its label."""
    out: dict[int, Label] = {}
    for i, name in enumerate(names):
        for word in name.replace(",", ";").split(";"):
            lab = _NAME_TO_LABEL.get(word.strip().lower())
            if lab is not None:
                out[i] = lab
                break
    return out


@dataclass(frozen=True)
class OnnxSegmentationOptions:
    """model_path; input/output names (None = the model's only/first); class_map; normalisation;
    input_size (h, w) or None = the image size (or the model's fixed size); bgr: feed BGR order."""

    model_path: str | Path
    class_map: Mapping[int, Label] = field(default_factory=lambda: dict(ADE20K_CLASS_MAP))
    input_name: str | None = None
    output_name: str | None = None
    rgb_mean: tuple[float, float, float] = (0.485, 0.456, 0.406)
    rgb_std: tuple[float, float, float] = (0.229, 0.224, 0.225)
    input_size: tuple[int, int] | None = None
    bgr: bool = False
    unmapped: Label = Label.CLUTTER
    providers: tuple[str, ...] = ("CPUExecutionProvider",)


def _check_model(sess: Any,
                 opts: OnnxSegmentationOptions) -> tuple[str, str, tuple[int, int] | None]:
    from bimcap.fusion.onnx_completion import OnnxModelError

    path = opts.model_path
    inputs = sess.get_inputs()
    if opts.input_name is None:
        if len(inputs) != 1:
            raise OnnxModelError(
                f"model has inputs {[i.name for i in inputs]}; name one with input_name",
                path=path, field="inputs",
            )
        inp = inputs[0]
    else:
        match = [i for i in inputs if i.name == opts.input_name]
        if not match:
            raise OnnxModelError(
                f"model has no input {opts.input_name!r}; "
                f"its inputs are {[i.name for i in inputs]}",
                path=path, field="inputs",
            )
        inp = match[0]
    shape = inp.shape
    if len(shape) != 4:
        raise OnnxModelError(
            f"input {inp.name!r} has rank {len(shape)}, expected 4 (N, 3, H, W)",
            path=path, field=inp.name,
        )
    if isinstance(shape[1], int) and shape[1] != 3:
        raise OnnxModelError(
            f"input {inp.name!r} has {shape[1]} channels, expected 3", path=path, field=inp.name
        )
    fixed = ((shape[2], shape[3]) if isinstance(shape[2], int) and isinstance(shape[3], int)
             else None)
    outputs = list(sess.get_outputs())
    out = opts.output_name or outputs[0].name
    match_o = [o for o in outputs if o.name == out]
    if not match_o:
        raise OnnxModelError(
            f"model has no output {out!r}; its outputs are {[o.name for o in outputs]}",
            path=path, field="output",
        )
    oshape = match_o[0].shape
    if len(oshape) != 4:
        raise OnnxModelError(
            f"output {out!r} has rank {len(oshape)}, expected 4 (N, C, H, W) scores",
            path=path, field=out,
        )
    if isinstance(oshape[1], int):
        too_big = [k for k in opts.class_map if not 0 <= k < oshape[1]]
        if too_big:
            raise OnnxModelError(
                f"class_map names classes {too_big} but the model has {oshape[1]}",
                path=path, field="class_map",
            )
    return inp.name, out, fixed


@dataclass(frozen=True)
class OnnxSegmentationProvider:
    """Runs :class:`OnnxSegmentationOptions`' model on ``frame.image``."""

    options: OnnxSegmentationOptions

    def segment(self, frame: FrameInput) -> U8:
        import cv2

        from bimcap.fusion.onnx_completion import OnnxModelError, load_session

        opts = self.options
        if frame.image is None:
            raise SegmentationInputError("the ONNX segmenter needs the RGB image", field="image")
        img = np.asarray(frame.image)
        if img.ndim != 3 or img.shape[2] != 3:
            raise SegmentationInputError(f"image must be (H, W, 3), got {img.shape}", field="image")
        check_shape(img, frame.camera, "image")
        sess = load_session(opts.model_path, opts.providers)
        in_name, out_name, fixed = _check_model(sess, opts)
        size = opts.input_size or fixed or img.shape[:2]
        if fixed is not None and tuple(size) != fixed:
            raise OnnxModelError(
                f"input_size {size} but the model is fixed at {fixed}",
                path=opts.model_path, field="input_size",
            )
        h, w = img.shape[:2]
        x = img[:, :, ::-1] if opts.bgr else img
        if tuple(size) != (h, w):
            x = cv2.resize(x, (int(size[1]), int(size[0])), interpolation=cv2.INTER_AREA)
        mean = np.asarray(opts.rgb_mean[::-1] if opts.bgr else opts.rgb_mean, np.float32)
        std = np.asarray(opts.rgb_std[::-1] if opts.bgr else opts.rgb_std, np.float32)
        t = ((x.astype(np.float32) / 255.0 - mean) / std).transpose(2, 0, 1)[None]
        try:
            (scores,) = sess.run([out_name], {in_name: np.ascontiguousarray(t)})
        except Exception as exc:
            raise OnnxModelError(f"ONNX Runtime failed: {exc}", path=opts.model_path) from None
        scores = np.asarray(scores)
        if scores.ndim != 4 or scores.shape[0] != 1:
            raise OnnxModelError(
                f"output has shape {scores.shape}, expected (1, C, H, W)",
                path=opts.model_path, field=out_name,
            )
        cls = np.argmax(scores[0], axis=0).astype(np.int64)
        lut = np.full(scores.shape[1], int(opts.unmapped), dtype=np.uint8)
        for k, lab in opts.class_map.items():
            if 0 <= k < len(lut):
                lut[k] = int(lab)
        labels = lut[cls]
        if labels.shape != (h, w):
            labels = cv2.resize(labels, (w, h), interpolation=cv2.INTER_NEAREST)
        return labels
