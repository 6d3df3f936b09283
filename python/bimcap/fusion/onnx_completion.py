"""Depth completion with a user-supplied ONNX network (CompletionFormer-like) on the CPU.

The model takes an RGB image ``(1, 3, h, w)`` float32 and a depth map ``(1, 1, h, w)`` float32 and
returns a dense depth ``(1, 1, h, w)`` (or ``(1, h, w)``). Names, normalisation, depth scale and
the input size are configurable; images of another size are resized to the model's input
(``SizeMode.RESIZE``) or cut into overlapping tiles (``SizeMode.TILE``, averaged where tiles
overlap). Sparse depth is resized without losing returns (each return goes to its nearest pixel,
nearest return kept); dense depth (the HYBRID input) with nearest-neighbour resampling. Sessions
are cached per (path, providers). No weights are ever downloaded: the user supplies the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.fusion.projection import FusionInputError

F32 = NDArray[np.float32]


class OnnxModelError(FusionInputError):
    """The ONNX model cannot be used as configured (missing file, wrong inputs or outputs)."""


class SizeMode(Enum):
    RESIZE = "resize"  #: resize image and depth to ``input_size``, the output back
    TILE = "tile"  #: run overlapping ``input_size`` tiles over the full-resolution image


@dataclass(frozen=True)
class OnnxCompletionOptions:
    """How to feed a completion network.

    model_path: the ``.onnx`` file.
    rgb_input, depth_input: input names; output: output name (None = the first output).
    rgb_mean, rgb_std: per-channel normalisation applied to ``rgb / 255`` (ImageNet by default).
    depth_scale: model depth units per metre (network input = metres × scale, output ÷ scale).
    input_size: (h, w) the network runs at; None = the image's size (needs dynamic or equal dims).
    size_mode: RESIZE or TILE when the image differs from ``input_size``.
    tile_overlap: overlap of tiles in pixels (TILE).
    providers: ONNX Runtime execution providers.
    """

    model_path: str | Path
    rgb_input: str = "rgb"
    depth_input: str = "depth"
    output: str | None = None
    rgb_mean: tuple[float, float, float] = (0.485, 0.456, 0.406)
    rgb_std: tuple[float, float, float] = (0.229, 0.224, 0.225)
    depth_scale: float = 1.0
    input_size: tuple[int, int] | None = None
    size_mode: SizeMode = SizeMode.RESIZE
    tile_overlap: int = 32
    providers: tuple[str, ...] = ("CPUExecutionProvider",)


_SESSIONS: dict[tuple[str, tuple[str, ...]], Any] = {}


def load_session(path: str | Path,
                 providers: tuple[str, ...] = ("CPUExecutionProvider",)) -> Any:
    """A cached ``onnxruntime.InferenceSession`` for ``path`` (one thread per call site's
    process). Raises :class:`bimcap.errors.MissingDependencyError` without ONNX Runtime (a core
    dependency; an install can still lack it)."""
    from bimcap.errors import require

    ort = require("onnxruntime", "onnxruntime", None, "an ONNX model (depth completion or "
                  "segmentation)")

    p = Path(path)
    if not p.is_file():
        raise OnnxModelError("model file not found", path=p, field="model_path")
    key = (str(p.resolve()), tuple(providers))
    sess = _SESSIONS.get(key)
    if sess is None:
        so = ort.SessionOptions()
        so.intra_op_num_threads = 1
        so.inter_op_num_threads = 1
        try:
            sess = ort.InferenceSession(str(p), sess_options=so, providers=list(providers))
        except Exception as exc:  # onnxruntime raises its own non-public exception types
            raise OnnxModelError(f"ONNX Runtime cannot load the model: {exc}", path=p) from None
        _SESSIONS[key] = sess
    return sess


def _dim_ok(dim: Any, want: int) -> bool:
    return not isinstance(dim, int) or dim == want


def check_completion_model(sess: Any,
                           opts: OnnxCompletionOptions) -> tuple[str, tuple[int, int] | None]:
    """Validate the model's signature; returns (output name, fixed (h, w) or None if dynamic)."""
    path = opts.model_path
    inputs = {i.name: i for i in sess.get_inputs()}
    fixed: tuple[int, int] | None = None
    for name, channels in ((opts.rgb_input, 3), (opts.depth_input, 1)):
        if name not in inputs:
            raise OnnxModelError(
                f"model has no input {name!r}; its inputs are {sorted(inputs)}",
                path=path, field="inputs",
            )
        shape = inputs[name].shape
        if len(shape) != 4:
            raise OnnxModelError(
                f"input {name!r} has rank {len(shape)}, expected 4 (N, C, H, W)",
                path=path, field=name,
            )
        if not _dim_ok(shape[1], channels):
            raise OnnxModelError(
                f"input {name!r} has {shape[1]} channels, expected {channels}",
                path=path, field=name,
            )
        if "float" not in inputs[name].type:
            raise OnnxModelError(
                f"input {name!r} is {inputs[name].type}, expected float", path=path, field=name
            )
        if isinstance(shape[2], int) and isinstance(shape[3], int):
            hw = (shape[2], shape[3])
            if fixed is not None and fixed != hw:
                raise OnnxModelError(
                    f"rgb and depth inputs differ in size {fixed} vs {hw}", path=path, field=name
                )
            fixed = hw
    extra = sorted(set(inputs) - {opts.rgb_input, opts.depth_input})
    if extra:
        raise OnnxModelError(
            f"model needs inputs {extra} that bimcap does not feed", path=path, field="inputs"
        )
    outputs = [o.name for o in sess.get_outputs()]
    out = opts.output or outputs[0]
    if out not in outputs:
        raise OnnxModelError(
            f"model has no output {out!r}; its outputs are {outputs}", path=path, field="output"
        )
    return out, fixed


def _resize_depth(depth: F32, hw: tuple[int, int]) -> F32:
    import cv2

    from bimcap.fusion.sparse import resize_sparse

    if depth.shape == hw:
        return depth
    valid = depth > 0
    if valid.mean() > 0.5:  # dense (HYBRID): plain nearest-neighbour resampling
        return cv2.resize(depth, (hw[1], hw[0]), interpolation=cv2.INTER_NEAREST)
    rows, cols = np.nonzero(valid)
    uv = np.stack([cols, rows], 1).astype(np.float64)
    out, _, _ = resize_sparse(uv, depth[rows, cols].astype(np.float64), depth.shape, hw)
    return out


def _run_once(sess: Any, out_name: str, rgb: F32, depth: F32, opts: OnnxCompletionOptions) -> F32:
    feeds = {opts.rgb_input: rgb[None], opts.depth_input: depth[None, None]}
    try:
        (res,) = sess.run([out_name], feeds)
    except Exception as exc:
        raise OnnxModelError(f"ONNX Runtime failed: {exc}", path=opts.model_path) from None
    arr = np.asarray(res, dtype=np.float32)
    if arr.ndim == 4 and arr.shape[:2] == (1, 1):
        arr = arr[0, 0]
    elif arr.ndim == 3 and arr.shape[0] == 1:
        arr = arr[0]
    else:
        raise OnnxModelError(
            f"output {out_name!r} has shape {arr.shape}, expected (1, 1, H, W)",
            path=opts.model_path, field="output",
        )
    if arr.shape != depth.shape:
        raise OnnxModelError(
            f"output size {arr.shape} differs from the input's {depth.shape}",
            path=opts.model_path, field="output",
        )
    return arr


def _tile_starts(n: int, t: int, overlap: int) -> list[int]:
    if n <= t:
        return [0]
    step = max(1, t - overlap)
    starts = list(range(0, n - t, step))
    starts.append(n - t)
    return starts


def run_completion_model(image: NDArray[Any], depth: F32, opts: OnnxCompletionOptions) -> F32:
    """Complete ``depth`` (H, W) float32 metres (sparse or interpolated) guided by ``image``
    (H, W, 3) uint8 RGB through the ONNX model. Returns (H, W) float32 metres (negative → 0)."""
    import cv2

    if image.ndim != 3 or image.shape[2] != 3:
        raise FusionInputError(f"image must be (H, W, 3) RGB, got {image.shape}", field="image")
    if image.shape[:2] != depth.shape:
        raise FusionInputError(
            f"image {image.shape[:2]} and depth {depth.shape} differ in size", field="image"
        )
    sess = load_session(opts.model_path, opts.providers)
    out_name, fixed = check_completion_model(sess, opts)
    size = opts.input_size or fixed or depth.shape
    if fixed is not None and tuple(size) != fixed:
        raise OnnxModelError(
            f"input_size {size} but the model's inputs are fixed at {fixed}",
            path=opts.model_path, field="input_size",
        )
    mean = np.asarray(opts.rgb_mean, dtype=np.float32)
    std = np.asarray(opts.rgb_std, dtype=np.float32)
    rgb = ((image.astype(np.float32) / 255.0 - mean) / std).transpose(2, 0, 1)
    d = depth.astype(np.float32) * np.float32(opts.depth_scale)
    h, w = depth.shape
    th, tw = int(size[0]), int(size[1])
    if (th, tw) == (h, w):
        out = _run_once(sess, out_name, np.ascontiguousarray(rgb), d, opts)
    elif opts.size_mode is SizeMode.RESIZE:
        rgb_s = cv2.resize(rgb.transpose(1, 2, 0), (tw, th),
                           interpolation=cv2.INTER_AREA).transpose(2, 0, 1)
        res = _run_once(sess, out_name, np.ascontiguousarray(rgb_s), _resize_depth(d, (th, tw)),
                        opts)
        out = cv2.resize(res, (w, h), interpolation=cv2.INTER_LINEAR)
    else:
        if h < th or w < tw:
            raise OnnxModelError(
                f"image {h}x{w} smaller than the tile {th}x{tw}",
                path=opts.model_path, field="input_size",
            )
        acc = np.zeros((h, w), np.float32)
        cnt = np.zeros((h, w), np.float32)
        for r0 in _tile_starts(h, th, opts.tile_overlap):
            for c0 in _tile_starts(w, tw, opts.tile_overlap):
                sl = (slice(r0, r0 + th), slice(c0, c0 + tw))
                acc[sl] += _run_once(sess, out_name, np.ascontiguousarray(rgb[:, sl[0], sl[1]]),
                                     np.ascontiguousarray(d[sl]), opts)
                cnt[sl] += 1.0
        out = acc / cnt
    out = out / np.float32(opts.depth_scale)
    out[~np.isfinite(out) | (out < 0)] = 0.0
    return out.astype(np.float32)
