"""On-disk sequence directories (manifest, images, LiDAR, labels, poses) and importers (ConSLAM)."""
