"""SIFT features, sequential matching with geometric verification, tracks, keypoint depths."""
