"""Segmentation providers producing label ids: from disk, any ONNX model, a no-weights segmenter."""
