"""Scan-vs-BIM deviations: the refined LiDAR map, and per IFC element where the scans say it is.

``refined_map``: every scan through the refined poses, voxel-downsampled and labelled
(``map_refined.ply``). ``analysis``: per element (walls, columns, slabs, coverings) coverage,
offset along the face normal, tilt and a status (ok / deviating / missing / unobserved), and the
clusters of points no element explains. ``outputs``: ``deviations.json``, the CSV, the
deviation-coloured PLY, the floor-plan picture, the IFC property sets; ``bcf``: the BCF 2.1
export (one topic per deviating or missing element). Heavy imports (open3d,
ifcopenshell, scipy) happen inside the functions that need them.
"""
