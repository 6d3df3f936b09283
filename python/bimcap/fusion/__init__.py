"""LiDAR → camera projection and depth completion (interpolation, classical, ONNX, hybrid)."""
