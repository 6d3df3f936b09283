from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from _fusion_onnx_models import segmentation_linear
from bimcap.fusion.onnx_completion import OnnxModelError
from bimcap.geometry import Camera
from bimcap.labels import Label
from bimcap.segmentation import FrameInput, SegmentationInputError, iou_per_class
from bimcap.segmentation.disk import (
    DiskLabelProvider,
    DiskMaskProvider,
    read_class_masks,
    read_label_image,
)
from bimcap.segmentation.onnx_seg import (
    ADE20K_CLASS_MAP,
    OnnxSegmentationOptions,
    OnnxSegmentationProvider,
    class_map_from_names,
)

CAM = Camera(40, 30, 30.0, 30.0, 19.5, 14.5)


def test_iou_per_class_hand_computed() -> None:
    gt = np.array([[1, 1, 2, 2], [1, 1, 2, 0]], np.uint8)
    pred = np.array([[1, 2, 2, 2], [1, 1, 3, 3]], np.uint8)
    iou = iou_per_class(pred, gt)
    assert iou[Label.WALL] == pytest.approx(3 / 4)  # 3 agree, 4 in the union
    # pred floor at 3 cells, gt at 3; gt-unknown pixel ignored
    assert iou[Label.FLOOR] == pytest.approx(2 / 4)
    assert iou[Label.CEILING] == 0.0
    assert Label.UNKNOWN not in iou


def test_label_image_round_trip_and_errors(tmp_path: Path) -> None:
    lab = (np.arange(40 * 30).reshape(30, 40) % 8).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "frame-000001.png"), lab)
    out = DiskLabelProvider(tmp_path).segment(FrameInput(CAM, stem="frame-000001"))
    np.testing.assert_array_equal(out, lab)
    cv2.imwrite(str(tmp_path / "bad.png"), np.full((30, 40), 9, np.uint8))
    with pytest.raises(SegmentationInputError, match="outside"):
        read_label_image(tmp_path / "bad.png")
    with pytest.raises(SegmentationInputError, match="does not match"):
        read_label_image(tmp_path / "frame-000001.png", Camera(50, 30, 30.0, 30.0, 25.0, 15.0))
    with pytest.raises(SegmentationInputError, match="not found"):
        DiskLabelProvider(tmp_path).segment(FrameInput(CAM, stem="frame-000002"))


def test_bimcap_masks_merge_with_priority(tmp_path: Path) -> None:
    h, w = 30, 40
    masks = {name: np.zeros((h, w), np.uint8) for name in ("wall", "floor", "ceiling", "columns")}
    masks["floor"][20:] = 255
    masks["ceiling"][:5] = 255
    masks["wall"][5:20] = 255
    masks["columns"][:, 10:14] = 255  # overlaps everything: a column in front wins
    for name, m in masks.items():
        cv2.imwrite(str(tmp_path / f"frame-0007_{name}.png"), m)
    lab = DiskMaskProvider(tmp_path).segment(FrameInput(CAM, stem="frame-0007"))
    assert (lab[:, 10:14] == Label.COLUMN).all()
    assert (lab[25, :10] == Label.FLOOR).all() and (lab[2, 20:] == Label.CEILING).all()
    assert (lab[10, 20:] == Label.WALL).all()
    (tmp_path / "frame-0007_columns.png").unlink()
    with pytest.raises(SegmentationInputError, match=re.escape("columns.png")):
        read_class_masks(tmp_path, "frame-0007")
    lab2 = read_class_masks(tmp_path, "frame-0007", missing_ok=True)
    assert (lab2[:, 10:14] != Label.COLUMN).all()
    with pytest.raises(SegmentationInputError, match="no class masks"):
        read_class_masks(tmp_path, "frame-9999", missing_ok=True)


def test_class_map_from_ade20k_names() -> None:
    names = ["wall", "building", "sky", "floor;flooring", "tree", "ceiling", "road", "bed",
             "windowpane;window", "grass", "cabinet", "sidewalk", "person", "earth",
             "door;double;door"]
    cmap = class_map_from_names(names)
    assert cmap == {k: v for k, v in ADE20K_CLASS_MAP.items() if k < len(names)}
    assert class_map_from_names(["column;pillar"]) == {0: Label.COLUMN}


def _colour_image() -> np.ndarray:
    img = np.zeros((30, 40, 3), np.uint8)
    img[:10] = (255, 0, 0)  # red → class 2
    img[10:20] = (0, 255, 0)  # green → class 1
    img[20:] = (0, 0, 255)  # blue → class 0
    return img


def test_onnx_segmenter_with_a_built_model(tmp_path: Path) -> None:
    # logits = W · normalised rgb with W picking one channel per class (+ a 4th class never max)
    weights = np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0], [-1, -1, -1]], np.float32)
    model = segmentation_linear(tmp_path / "seg.onnx", weights)
    cmap = {0: Label.FLOOR, 1: Label.WALL, 2: Label.CEILING}
    opts = OnnxSegmentationOptions(model, class_map=cmap, rgb_mean=(0.0, 0.0, 0.0),
                                   rgb_std=(1.0, 1.0, 1.0))
    lab = OnnxSegmentationProvider(opts).segment(FrameInput(CAM, image=_colour_image()))
    assert ((lab[:10] == Label.CEILING).all() and (lab[10:20] == Label.WALL).all()
            and (lab[20:] == Label.FLOOR).all())
    # at a smaller input size, labels come back at the image size (nearest-neighbour)
    small = OnnxSegmentationProvider(OnnxSegmentationOptions(
        model, class_map=cmap, rgb_mean=(0.0,) * 3, rgb_std=(1.0,) * 3, input_size=(15, 20)))
    lab_s = small.segment(FrameInput(CAM, image=_colour_image()))
    assert lab_s.shape == (30, 40) and np.mean(lab_s == lab) > 0.9
    # unmapped classes become clutter
    lab_u = OnnxSegmentationProvider(OnnxSegmentationOptions(
        model, class_map={0: Label.FLOOR}, rgb_mean=(0.0,) * 3, rgb_std=(1.0,) * 3,
    )).segment(FrameInput(CAM, image=_colour_image()))
    assert (lab_u[:20] == Label.CLUTTER).all()


def test_onnx_segmenter_bad_inputs(tmp_path: Path) -> None:
    weights = np.eye(3, dtype=np.float32)
    model = segmentation_linear(tmp_path / "seg.onnx", weights)
    fixed = segmentation_linear(tmp_path / "fixed.onnx", weights, hw=(16, 16))
    img = _colour_image()
    with pytest.raises(OnnxModelError,
                       match=r"class_map names classes \[3, 5, 8, 14, 42\] but the model has 3"):
        OnnxSegmentationProvider(OnnxSegmentationOptions(model)).segment(FrameInput(CAM, image=img))
    with pytest.raises(OnnxModelError, match="no input 'rgb'"):
        OnnxSegmentationProvider(OnnxSegmentationOptions(
            model, class_map={0: Label.WALL}, input_name="rgb")).segment(FrameInput(CAM, image=img))
    with pytest.raises(OnnxModelError, match="fixed at"):
        OnnxSegmentationProvider(OnnxSegmentationOptions(
            fixed, class_map={0: Label.WALL}, input_size=(30, 40),
        )).segment(FrameInput(CAM, image=img))
    with pytest.raises(SegmentationInputError, match="does not match"):
        OnnxSegmentationProvider(OnnxSegmentationOptions(
            model, class_map={0: Label.WALL})).segment(FrameInput(CAM, image=img[:20]))
    with pytest.raises(SegmentationInputError, match="needs the RGB image"):
        OnnxSegmentationProvider(OnnxSegmentationOptions(model)).segment(FrameInput(CAM))
