"""Coarse registration to the BIM (before bundle adjustment): bring frames or windows of frames
near the right pose using the floor plan and the floor/ceiling planes alone."""
