"""The BIM reference: IFC → per-class meshes, semantic point cloud, planes, vectorized floor plan."""
