"""Tiny ONNX models built with onnx.helper for the fusion and segmentation tests (no weights
are downloaded). ir_version 10, opset 17."""

from __future__ import annotations

from pathlib import Path

import numpy as np

IR_VERSION = 10
OPSET = 17


def _save(graph, path: Path) -> Path:  # type: ignore[no-untyped-def]
    import onnx
    from onnx import helper

    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = IR_VERSION
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def completion_identity(path: Path, rgb_name: str = "rgb", depth_name: str = "depth",
                        depth_channels: int = 1, hw: tuple[int | str, int | str] = ("H", "W"),
                        depth_rank3: bool = False) -> Path:
    """out = depth + 0 · mean(rgb): returns its depth input (uses both inputs)."""
    from onnx import TensorProto, helper

    h, w = hw
    rgb = helper.make_tensor_value_info(rgb_name, TensorProto.FLOAT, [1, 3, h, w])
    dshape = [1, h, w] if depth_rank3 else [1, depth_channels, h, w]
    dep = helper.make_tensor_value_info(depth_name, TensorProto.FLOAT, dshape)
    out = helper.make_tensor_value_info("dense", TensorProto.FLOAT, [1, 1, h, w])
    zero = helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0])
    nodes = [
        helper.make_node("ReduceMean", [rgb_name], ["m"], axes=[1], keepdims=1),
        helper.make_node("Mul", ["m", "zero"], ["m0"]),
        helper.make_node("Add", [depth_name, "m0"], ["dense"]),
    ]
    return _save(helper.make_graph(nodes, "identity", [rgb, dep], [out], [zero]), path)


def completion_normalized_conv(path: Path, k: int = 9) -> Path:
    """out = box(depth) / box(depth > 0) over a k × k window (a normalised-convolution fill), plus
    0 · mean(rgb); 0 where no return is in the window."""
    from onnx import TensorProto, helper

    rgb = helper.make_tensor_value_info("rgb", TensorProto.FLOAT, [1, 3, "H", "W"])
    dep = helper.make_tensor_value_info("depth", TensorProto.FLOAT, [1, 1, "H", "W"])
    out = helper.make_tensor_value_info("dense", TensorProto.FLOAT, [1, 1, "H", "W"])
    inits = [
        helper.make_tensor("kern", TensorProto.FLOAT, [1, 1, k, k],
                           np.ones(k * k, np.float32).tolist()),
        helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]),
        helper.make_tensor("eps", TensorProto.FLOAT, [], [1e-6]),
    ]
    p = k // 2
    nodes = [
        helper.make_node("Greater", ["depth", "zero"], ["valid_b"]),
        helper.make_node("Cast", ["valid_b"], ["valid"], to=TensorProto.FLOAT),
        helper.make_node("Conv", ["depth", "kern"], ["num"], pads=[p, p, p, p]),
        helper.make_node("Conv", ["valid", "kern"], ["den"], pads=[p, p, p, p]),
        helper.make_node("Max", ["den", "eps"], ["den_s"]),
        helper.make_node("Div", ["num", "den_s"], ["fill"]),
        helper.make_node("ReduceMean", ["rgb"], ["m"], axes=[1], keepdims=1),
        helper.make_node("Mul", ["m", "zero"], ["m0"]),
        helper.make_node("Add", ["fill", "m0"], ["dense"]),
    ]
    return _save(helper.make_graph(nodes, "nconv", [rgb, dep], [out], inits), path)


def segmentation_linear(path: Path, weights: np.ndarray,
                        hw: tuple[int | str, int | str] = ("H", "W")) -> Path:
    """logits (1, C, H, W) = 1×1 conv of the (normalised) RGB input with ``weights`` (C, 3)."""
    from onnx import TensorProto, helper

    c = weights.shape[0]
    h, w = hw
    inp = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, h, w])
    out = helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, c, h, w])
    kern = helper.make_tensor("w", TensorProto.FLOAT, [c, 3, 1, 1],
                              weights.astype(np.float32).ravel().tolist())
    nodes = [helper.make_node("Conv", ["image", "w"], ["logits"])]
    return _save(helper.make_graph(nodes, "seg", [inp], [out], [kern]), path)
