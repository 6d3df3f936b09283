"""The BIM reference: IFC → per-class meshes, semantic point cloud, planes, vectorized floor plan.

Public API (heavy imports happen inside the functions):

* :func:`load_model` (``bimcap.bim.ingest``) → :class:`BimModel` of world-metre meshes;
* :func:`build_reference` (``bimcap.bim.reference``) → :class:`BimReference` with planes,
  floor-plan segments and the semantic cloud; :meth:`BimReference.save` / :meth:`BimReference.load`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bimcap.bim.errors import (
    BimError,
    BimInputError,
    BimWarning,
    DamagedModelWarning,
    MissingFloorWarning,
    ProxyElementWarning,
    StoreyHeightWarning,
)

if TYPE_CHECKING:
    from bimcap.bim.ingest import BimElement, BimModel, Storey, load_model
    from bimcap.bim.reference import BimReference, ReferenceOptions, build_reference

__all__ = [
    "BimElement",
    "BimError",
    "BimInputError",
    "BimModel",
    "BimReference",
    "BimWarning",
    "DamagedModelWarning",
    "MissingFloorWarning",
    "ProxyElementWarning",
    "ReferenceOptions",
    "Storey",
    "StoreyHeightWarning",
    "build_reference",
    "load_model",
]

_LAZY = {
    "BimElement": "bimcap.bim.ingest",
    "BimModel": "bimcap.bim.ingest",
    "Storey": "bimcap.bim.ingest",
    "load_model": "bimcap.bim.ingest",
    "BimReference": "bimcap.bim.reference",
    "ReferenceOptions": "bimcap.bim.reference",
    "build_reference": "bimcap.bim.reference",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'bimcap.bim' has no attribute {name!r}")
