"""The BIM reference: what the solver and the simulator use from the IFC, and its files.

:func:`build_reference` turns a :class:`~bimcap.bim.ingest.BimModel` into a
:class:`BimReference` with dense arrays (docs/architecture.md, "BIM reference"):

* ``planes (Q, 4)`` ``[nx, ny, nz, d]``, unit n, signed distance ``n·p + d``. Floor planes have
  the normal **up**; ceiling planes have the normal **down**, pointing into the room; so a point
  inside a room is at positive distance from both (:mod:`bimcap.bim.planes`);
* ``segments (S, 4)`` ``x1 y1 x2 y2`` metres, ``segment_class (S,)`` int32 (1 wall, 4 column),
  ``segment_z (S, 2)`` the z range (storey) each segment applies to;
* the semantic cloud ``points (P, 3)`` metres and ``labels (P,)`` uint8.

Files written by :meth:`BimReference.save` into a directory::

    reference.json      version, source IFC, storeys, options, counts, per-storey agreement
    planes.json         every plane: kind, storey, [nx ny nz d], height, xy polygon (+ holes)
    floorplan.json      segments (x1 y1 x2 y2, class, storey), band, resolution, origin
    reference.npz       planes, plane_kind, segments, segment_class, segment_z, points, labels
    semantic_cloud.ply  binary PLY: x y z (float32), red green blue label (uchar)
    floorplan_NN_<storey>.svg / .png   the plan of each storey, classes coloured
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict, dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.bim.errors import BimInputError
from bimcap.bim.floorplan import FloorPlan, FloorPlanOptions, Vectorizer, build_floor_plan
from bimcap.bim.ingest import BimModel, Storey, read_spaces
from bimcap.bim.planes import PlaneOptions, ReferencePlane, extract_planes, plane_under
from bimcap.bim.semantic_cloud import sample_model, write_ply
from bimcap.geometry.local_frame import local_origin
from bimcap.io.atomic import atomic_write_bytes, atomic_write_json
from bimcap.labels import Label

FORMAT = "bimcap-bim-reference"
VERSION = 5  # 2: planes are the visible surfaces only (bimcap.bim.planes); caches of 1 are rebuilt
# 3: planes no longer average faces up to 2 cm apart (PlaneOptions.height_tol_m 2 mm)
# 4: they do again (2 cm: the 2 mm planes left a Duplex_A global alignment silently wrong)
# 5: a model far from the origin is built in a local frame (georeferenced models lost the walls'
#    footprints from their floor planes to shapely round-off)


@dataclass(frozen=True)
class ReferenceOptions:
    """Options of :func:`build_reference`.

    Attributes
    ----------
    density_per_m2: semantic-cloud sampling density (points per m² of surface).
    seed: seed of the cloud sampling.
    cloud_labels: classes sampled into the cloud (default: all but "other").
    floorplan: floor-plan options. planes: plane-extraction options.
    """

    density_per_m2: float = 100.0
    seed: int = 0
    cloud_labels: tuple[Label, ...] = (
        Label.WALL, Label.FLOOR, Label.CEILING, Label.COLUMN, Label.DOOR, Label.WINDOW,
    )
    floorplan: FloorPlanOptions = field(default_factory=FloorPlanOptions)
    planes: PlaneOptions = field(default_factory=PlaneOptions)

    def to_dict(self) -> dict[str, Any]:
        return {
            "density_per_m2": self.density_per_m2,
            "seed": self.seed,
            "cloud_labels": [int(c) for c in self.cloud_labels],
            "floorplan": self.floorplan.to_dict(),
            "planes": asdict(self.planes),
        }


@dataclass
class BimReference:
    """The BIM reference of one model (see the module docstring for conventions and files).

    Attributes
    ----------
    planes: (Q, 4) float64. plane_info: per plane its :class:`ReferencePlane` (kind, storey,
    polygon). segments: (S, 4) float64. segment_class: (S,) int32. segment_z: (S, 2) float64.
    segment_storey: (S,) storey names. points: (P, 3) float64. labels: (P,) uint8.
    storeys: the model's storeys. floor_plan: the full floor plan (None after :meth:`load`,
    which keeps its JSON in ``floor_plan_json``). source: the IFC path.
    """

    planes: NDArray[np.float64]
    plane_info: list[ReferencePlane]
    segments: NDArray[np.float64]
    segment_class: NDArray[np.int32]
    segment_z: NDArray[np.float64]
    segment_storey: list[str]
    points: NDArray[np.float64]
    labels: NDArray[np.uint8]
    storeys: list[Storey]
    source: str = ""
    floor_plan: FloorPlan | None = None
    floor_plan_json: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    failed: list[tuple[str, str]] = field(default_factory=list)

    @property
    def plane_kind(self) -> NDArray[np.int32]:
        """(Q,) int32 Label ids (2 floor, 3 ceiling)."""
        return np.array([int(p.kind) for p in self.plane_info], dtype=np.int32)

    def plane_under(
        self, p_in_world: NDArray[np.float64], kind: Label, side_tol_m: float = 0.5
    ) -> NDArray[np.int32]:
        """For each point (M, 3) metres, the index of the plane of ``kind`` (Label.FLOOR or
        Label.CEILING) whose xy polygon contains it, on whose room side it is (signed distance
        ≥ −side_tol_m), and whose height is nearest; −1 where none. Returns (M,) int32 indices
        into :attr:`planes` (see :func:`bimcap.bim.planes.plane_under`)."""
        return plane_under(self.plane_info, self.planes, p_in_world, Label(kind), side_tol_m)

    def summary(self) -> dict[str, Any]:
        """Counts for the CLI and reference.json."""
        seg_len = np.hypot(self.segments[:, 2] - self.segments[:, 0],
                           self.segments[:, 3] - self.segments[:, 1])
        fp = self.floor_plan.to_dict() if self.floor_plan is not None else self.floor_plan_json
        return {
            "source": self.source,
            "elements": self.counts,
            "failed": [list(f) for f in self.failed],
            "storeys": [s.to_dict() for s in self.storeys],
            "planes": {
                "floor": int((self.plane_kind == Label.FLOOR).sum()),
                "ceiling": int((self.plane_kind == Label.CEILING).sum()),
            },
            "segments": {
                c.name.lower(): {
                    "count": int((self.segment_class == c).sum()),
                    "length_m": float(seg_len[self.segment_class == c].sum()),
                }
                for c in (Label.WALL, Label.COLUMN)
            },
            "points": len(self.points),
            "floorplan_storeys": fp.get("storeys", []),
        }

    def check_usable(self, ifc: str | PathLike[str] | None = None) -> None:
        """Raise :class:`BimInputError` naming the IFC (``ifc``, else :attr:`source`) when the
        reference cannot serve the solver: an empty floor plan (no wall or column cut by any
        storey's band), an empty semantic cloud, or non-finite arrays."""
        where = Path(ifc) if ifc is not None else (Path(self.source) if self.source else None)
        storeys = ", ".join(f"{st.name} {st.elevation_m:.3f} m" for st in self.storeys) or "none"
        if len(self.segments) == 0:
            raise BimInputError(
                "empty floor plan: no wall or column is cut by any storey's floor-plan band "
                f"(storeys: {storeys}); check the storey heights against the walls and the "
                "file's length unit",
                where,
                "floor plan",
            )
        if len(self.points) == 0:
            raise BimInputError(
                "empty semantic cloud: sampling the walls, floors and ceilings gave no point "
                "(are the elements' surfaces degenerate, or the length unit wrong?)",
                where,
                "semantic cloud",
            )
        for name in ("planes", "segments", "segment_z", "points"):
            arr = getattr(self, name)
            if not np.isfinite(arr).all():
                raise BimInputError(f"{name} of the BIM reference are not finite", where, name)

    # ------------------------------------------------------------------ files

    def save(self, directory: str | PathLike[str]) -> None:
        """Write every artefact into ``directory`` atomically (see the module docstring)."""
        from bimcap.bim.export import write_pictures

        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        np.savez(
            buf,
            planes=self.planes,
            plane_kind=self.plane_kind,
            segments=self.segments,
            segment_class=self.segment_class,
            segment_z=self.segment_z,
            points=self.points,
            labels=self.labels,
        )
        atomic_write_bytes(d / "reference.npz", buf.getvalue())
        atomic_write_json(d / "planes.json", {
            "format": "bimcap-planes", "version": VERSION, "units": "m",
            "convention": "signed distance n.p + d; floor normals up, ceiling normals down "
                          "(into the room)",
            "planes": [p.to_dict() for p in self.plane_info],
        })
        fp = self.floor_plan.to_dict() if self.floor_plan is not None else self.floor_plan_json
        atomic_write_json(d / "floorplan.json", fp)
        write_ply(d / "semantic_cloud.ply", self.points, self.labels)
        meta = {"format": FORMAT, "version": VERSION, **self.summary(), "options": self.options}
        atomic_write_json(d / "reference.json", meta)
        if self.floor_plan is not None:
            write_pictures(self.floor_plan, d)

    @staticmethod
    def load(directory: str | PathLike[str]) -> BimReference:
        """Read a reference written by :meth:`save`; raises :class:`BimInputError` on bad files."""
        d = Path(directory)
        files = {n: d / n for n in ("reference.json", "planes.json", "floorplan.json",
                                    "reference.npz")}
        for name, path in files.items():
            if not path.is_file():
                raise BimInputError("missing file of a BIM reference", path, name)
        try:
            meta = json.loads(files["reference.json"].read_text())
            pj = json.loads(files["planes.json"].read_text())
            fj = json.loads(files["floorplan.json"].read_text())
        except json.JSONDecodeError as exc:
            raise BimInputError(f"invalid JSON: {exc}", d) from exc
        if meta.get("format") != FORMAT or meta.get("version") != VERSION:
            raise BimInputError(
                f"expected format {FORMAT!r} version {VERSION}", files["reference.json"], "format"
            )
        try:
            with np.load(files["reference.npz"]) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise BimInputError(f"unreadable arrays: {exc}", files["reference.npz"]) from exc
        needed = ("planes", "segments", "segment_class", "segment_z", "points", "labels")
        for key in needed:
            if key not in arrays:
                raise BimInputError("array missing", files["reference.npz"], key)
        plane_info = [ReferencePlane.from_dict(p) for p in pj["planes"]]
        planes = np.ascontiguousarray(arrays["planes"], dtype=np.float64).reshape(-1, 4)
        if len(plane_info) != len(planes):
            raise BimInputError("planes.json and reference.npz disagree on the plane count",
                                files["planes.json"], "planes")
        segs = np.ascontiguousarray(arrays["segments"], dtype=np.float64).reshape(-1, 4)
        storey_of = [s["storey"] for s in fj.get("segments", [])]
        if len(storey_of) != len(segs):
            raise BimInputError("floorplan.json and reference.npz disagree on the segment count",
                                files["floorplan.json"], "segments")
        return BimReference(
            planes=planes,
            plane_info=plane_info,
            segments=segs,
            segment_class=np.ascontiguousarray(arrays["segment_class"], dtype=np.int32),
            segment_z=np.ascontiguousarray(arrays["segment_z"], dtype=np.float64).reshape(-1, 2),
            segment_storey=storey_of,
            points=np.ascontiguousarray(arrays["points"], dtype=np.float64).reshape(-1, 3),
            labels=np.ascontiguousarray(arrays["labels"], dtype=np.uint8),
            storeys=[Storey(s["name"], float(s["elevation_m"]), s["guid"])
                     for s in meta.get("storeys", [])],
            source=str(meta.get("source", "")),
            floor_plan=None,
            floor_plan_json=fj,
            options=meta.get("options", {}),
            counts=meta.get("elements", {}),
            failed=[tuple(f) for f in meta.get("failed", [])],  # type: ignore[misc]
        )


def build_reference(model: BimModel, options: ReferenceOptions | None = None) -> BimReference:
    """Planes, floor plan and semantic cloud of a model.

    Parameters
    ----------
    model: from :func:`bimcap.bim.ingest.load_model`.
    options: see :class:`ReferenceOptions`.

    Returns
    -------
    :class:`BimReference`. Floor planes have normals up, ceiling planes normals down (into the
    room); signed distance ``n·p + d``.

    Raises
    ------
    BimInputError: an empty floor plan or cloud (:meth:`BimReference.check_usable`).

    Warns
    -----
    MissingFloorWarning / MissingCeilingWarning for storeys with walls but no floor / ceiling.

    A model far from the origin in xy (a georeferenced one) is built in a local frame
    (:func:`~bimcap.geometry.local_frame.local_origin`, z kept) and the result moved back: the
    shapely and raster operations keep their precision, and the reference is the same as the
    model's near the origin, moved.
    """
    opts = options or ReferenceOptions()
    offset = local_origin(np.concatenate([e.vertices for e in model.elements])
                          if model.elements else np.zeros((0, 3)))
    offset[2] = 0.0
    if offset.any():
        ref = _build(_moved_model(model, -offset), opts)
        _move_reference(ref, offset)
    else:
        ref = _build(model, opts)
    ref.check_usable(model.path)
    return ref


def _moved_model(model: BimModel, offset: NDArray[np.float64]) -> BimModel:
    """``model`` with every element (and IfcSpace, read now) moved by ``offset`` (3,) metres."""
    spaces = read_spaces(model)
    return replace(model, elements=[replace(e, vertices=e.vertices + offset)
                                    for e in model.elements],
                   spaces=[replace(e, vertices=e.vertices + offset) for e in spaces])


def _move_reference(ref: BimReference, offset: NDArray[np.float64]) -> None:
    """Move a reference built in a local frame by ``offset`` (3,) metres, in place."""
    xy = offset[:2]
    ref.planes = ref.planes.copy()
    if len(ref.planes):
        ref.planes[:, 3] -= ref.planes[:, :3] @ offset
    for p in ref.plane_info:
        p.plane = p.plane.copy()
        p.plane[3] -= float(p.plane[:3] @ offset)
        p.polygon = p.polygon + xy
        p.holes = [h + xy for h in p.holes]
    seg_shift = np.concatenate([xy, xy])
    ref.segments = ref.segments + seg_shift
    ref.segment_z = ref.segment_z + offset[2]
    ref.points = ref.points + offset
    fp = ref.floor_plan
    if fp is not None:
        fp.origin = fp.origin + xy
        for st in fp.storeys:
            st.segments = st.segments + seg_shift
            st.exact = {k: v + seg_shift for k, v in st.exact.items()}
            st.exact_band = {k: v + seg_shift for k, v in st.exact_band.items()}


def _build(model: BimModel, opts: ReferenceOptions) -> BimReference:
    """:func:`build_reference` in the model's own frame, unchecked."""
    plane_info = extract_planes(model, opts.planes)
    planes = (np.stack([p.plane for p in plane_info]) if plane_info
              else np.zeros((0, 4), dtype=np.float64))
    fp = build_floor_plan(model, opts.floorplan)
    points, labels = sample_model(model, opts.density_per_m2, opts.seed, opts.cloud_labels)
    ref = BimReference(
        planes=np.ascontiguousarray(planes, dtype=np.float64),
        plane_info=plane_info,
        segments=np.ascontiguousarray(fp.segments, dtype=np.float64),
        segment_class=np.ascontiguousarray(fp.segment_class, dtype=np.int32),
        segment_z=np.ascontiguousarray(fp.segment_z, dtype=np.float64),
        segment_storey=fp.segment_storey,
        points=points,
        labels=labels,
        storeys=list(model.storeys),
        source=str(model.path),
        floor_plan=fp,
        options=opts.to_dict(),
        counts=model.counts(),
        failed=list(model.failed),
    )
    return ref


__all__ = ["BimReference", "ReferenceOptions", "Vectorizer", "build_reference"]
