"""bimcap: snap a drifting camera + LiDAR trajectory onto the building's BIM.

Conventions (see the README): world = the IFC frame, z up, metres; poses are
``world_from_cam`` arrays of shape (N, 7) in TUM order ``[tx, ty, tz, qx, qy, qz, qw]``;
camera frame is OpenCV optical (x right, y down, z forward); label ids are
:class:`bimcap.labels.Label`.
"""

from __future__ import annotations

from bimcap.errors import BimcapError, InputError

__version__ = "0.1.0"

__all__ = ["BimcapError", "InputError", "__version__"]
