"""BCF 2.1 export of the deviations (``deviations.bcfzip``): one topic per ``deviating`` or
``missing`` element, for BIM issue trackers and viewers (BIMcollab, Solibri, Navisworks,
Bonsai/BlenderBIM, the IfcOpenShell BCF client).

The file is a zip (BIM Collaboration Format 2.1, buildingSMART):

* ``bcf.version``: ``<Version VersionId="2.1"><DetailedVersion>2.1</DetailedVersion></Version>``;
* one folder per topic, named by the topic's GUID (a UUID), holding

  - ``markup.bcf``: a ``Header`` naming the design IFC (``Filename``, its ``IfcProject`` GUID),
    the ``Topic`` (``TopicType`` :data:`TOPIC_TYPE`, ``TopicStatus`` :data:`TOPIC_STATUS`;
    ``Title`` e.g. ``Wall 'Partition 3' built 4.2 cm off (deviating)`` or ``Column 'C2'
    missing``; ``Labels``: the status and the IFC class; ``Description``: ``offset_m``,
    ``coverage``, ``n_points``, the tolerance and what they mean) and one ``Viewpoints`` entry;
  - ``viewpoint.bcfv``: ``Components`` with the element's IFC GUID as the ``Selection`` (every
    other element visible) and a ``PerspectiveCamera``.

No snapshot PNG is written (the viewpoint's camera is what a viewer restores).

The camera (IFC world coordinates, metres, as BCF wants them) looks at the element's centre (the
centre of its mesh's bounding box) along the inward normal of the face it stands in front of: a
wall's side (either one), a column's side, a floor's top, a ceiling's underside; of these, the
face turned towards the nearest sensor centre of the walk when the walk is given (the side the
scanner saw, or would have seen, the element from), unless another element stands closer than
:data:`MIN_DISTANCE_M` in front of it (then the next face, or the one with the most room). It
stands back far enough for a :data:`FIELD_OF_VIEW_DEG` view to take in the element (at least
:data:`MIN_DISTANCE_M`, at most :data:`MAX_DISTANCE_M` from the face) but stops :data:`CLEARANCE_M`
short of the first other element in front of the face (the wall across the room), so that nothing
of the model stands between the camera and the element's face. Its up vector is world z, or world y
when it looks straight up or down.
"""

from __future__ import annotations

import uuid
import zipfile
from dataclasses import dataclass
from datetime import UTC, datetime
from os import PathLike
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

import numpy as np
from numpy.typing import NDArray

from bimcap.deviations.analysis import (
    DeviationReport,
    ElementDeviation,
    ElementStatus,
    LocalScene,
)
from bimcap.errors import InputError
from bimcap.geometry.local_frame import local_origin
from bimcap.io.atomic import atomic_write_bytes
from bimcap.labels import Label

F64 = NDArray[np.float64]

#: BCF version written.
BCF_VERSION = "2.1"
#: The statuses that get a topic.
REPORTED = (ElementStatus.DEVIATING, ElementStatus.MISSING)
#: ``TopicType`` / ``TopicStatus`` / ``CreationAuthor`` of every topic.
TOPIC_TYPE = "Issue"
TOPIC_STATUS = "Open"
AUTHOR = "bimcap"
#: The viewpoint camera: field of view (degrees), distance from the face (metres), and how far
#: short of the next element behind it the camera stops.
FIELD_OF_VIEW_DEG = 60.0
MIN_DISTANCE_M = 1.0
MAX_DISTANCE_M = 6.0
CLEARANCE_M = 0.3
#: Elements within this of the face (a window's sill) do not block the camera.
FLUSH_M = 0.1
#: File names inside a topic folder.
MARKUP_NAME = "markup.bcf"
VIEWPOINT_NAME = "viewpoint.bcfv"


class BcfExportError(InputError):
    """The BCF export cannot be written (an element of the report is not in the model)."""


@dataclass(frozen=True)
class BcfCamera:
    """A BCF perspective camera (IFC world frame, metres).

    Attributes
    ----------
    eye: (3,) the camera position (``CameraViewPoint``).
    direction: (3,) unit viewing direction (``CameraDirection``).
    up: (3,) unit up vector, perpendicular to ``direction`` (``CameraUpVector``).
    field_of_view_deg: vertical field of view (``FieldOfView``, degrees).
    target: (3,) the point looked at (the element's centre; not written, BCF has no field).
    """

    eye: tuple[float, float, float]
    direction: tuple[float, float, float]
    up: tuple[float, float, float]
    field_of_view_deg: float
    target: tuple[float, float, float]

    def to_dict(self) -> dict[str, Any]:
        return {"eye": list(self.eye), "direction": list(self.direction), "up": list(self.up),
                "field_of_view_deg": self.field_of_view_deg, "target": list(self.target)}


@dataclass(frozen=True)
class BcfTopic:
    """One topic of the export.

    Attributes
    ----------
    guid: the topic's GUID (a UUID; its folder's name). viewpoint_guid: its viewpoint's.
    element_guid: the IFC GlobalId of the element (the viewpoint's selection).
    title, description: the topic's ``Title`` and ``Description``.
    labels: its ``Labels`` (status, IFC class).
    camera: the viewpoint's camera.
    """

    guid: str
    viewpoint_guid: str
    element_guid: str
    title: str
    description: str
    labels: tuple[str, ...]
    camera: BcfCamera


def _kind(ifc_class: str) -> str:
    """A readable class name: ``IfcWallStandardCase`` → ``Wall``, ``IfcCovering`` → ``Covering``."""
    name = ifc_class[3:] if ifc_class.startswith("Ifc") else ifc_class
    return name.removesuffix("StandardCase") or ifc_class


def topic_title(e: ElementDeviation) -> str:
    """``Wall 'Partition 3' built 4.2 cm off (deviating)`` / ``Column 'C2' missing``."""
    who = f"{_kind(e.ifc_class)} '{e.name or e.guid}'"
    if e.status == ElementStatus.MISSING:
        return f"{who} missing"
    off = 100 * abs(e.offset_m or 0.0)
    return f"{who} built {off:.1f} cm off ({e.status.value})"


def topic_description(e: ElementDeviation, tolerance_m: float) -> str:
    """What the scans say about ``e``, with its numbers (``offset_m``, ``coverage``,
    ``n_points``, the tolerance) and what they mean."""
    where = f" on storey {e.storey}" if e.storey else ""
    lines = [f"{e.ifc_class} '{e.name}' (GUID {e.guid}){where}: {e.status.value}."]
    if e.status == ElementStatus.MISSING:
        lines.append(f"{e.passes} of the {e.rays} LiDAR rays that reach it in the model pass "
                     "through it: free space where the model has it.")
    elif e.offset_m is not None:
        if e.offset_xy_m is not None:
            dx, dy = e.offset_xy_m
            what = (f"offset_m = {e.offset_m:.4f} m horizontally (dx = {dx:+.4f} m, "
                    f"dy = {dy:+.4f} m in the IFC's world frame)")
        elif e.ifc_class.startswith("IfcWall"):
            what = (f"offset_m = {e.offset_m:+.4f} m along the wall's normal (positive: towards "
                    "the local +y of its IFC placement)")
        else:
            what = f"offset_m = {e.offset_m:+.4f} m along z"
        lines.append(f"Measured {what}, beyond the tolerance of {tolerance_m:.4f} m.")
        if e.tilt_deg is not None:
            lines.append(f"Tilt: {e.tilt_deg:+.2f} degrees.")
    offset = "none" if e.offset_m is None else f"{e.offset_m:+.4f} m"
    lines.append(f"offset_m = {offset}; coverage = {e.coverage:.2f} (share of its visible faces "
                 f"the scans saw); n_points = {e.n_points} (LiDAR returns on it); tolerance = "
                 f"{tolerance_m:.4f} m.")
    lines.append("Written by bimcap deviations (deviations.json has every element).")
    return "\n".join(lines)


def _candidate_normals(el: Any) -> F64:
    """(K, 3) unit outward normals of the faces a camera may stand in front of (see the
    module doc), largest face first."""
    from bimcap.deviations.analysis import _triangle_normals, wall_normal

    v, f = el.vertices, el.faces
    if el.label == Label.WALL:
        n = wall_normal(v, f, None)
        return np.stack([n, -n])
    if el.label == Label.CEILING:
        return np.array([[0.0, 0.0, -1.0]])
    if el.label == Label.FLOOR:
        return np.array([[0.0, 0.0, 1.0]])
    normals, areas = _triangle_normals(v, f)
    side = np.abs(normals[:, 2]) < 0.3
    if not side.any():
        return np.array([[0.0, 0.0, 1.0]])
    # the vertical faces' normals, grouped by direction (10° bins), by area
    xy = normals[side, :2] / np.maximum(np.linalg.norm(normals[side, :2], axis=1), 1e-12)[:, None]
    bins = np.round(np.degrees(np.arctan2(xy[:, 1], xy[:, 0])) / 10).astype(int) % 36
    area = np.bincount(bins, weights=areas[side], minlength=36)
    out = []
    for b in np.argsort(-area):
        if area[b] <= 0:
            break
        mean = xy[bins == b].mean(axis=0)
        out.append([*(mean / np.linalg.norm(mean)), 0.0])
    return np.asarray(out, dtype=np.float64)


def element_camera(el: Any, scene: Any | None = None, viewers: F64 | None = None
                   ) -> BcfCamera:
    """The viewpoint camera of one model element (a :class:`bimcap.bim.ingest.BimElement`).

    Parameters
    ----------
    el: the element (its ``vertices`` (V, 3) metres, ``faces``, ``label``).
    scene: a :class:`~bimcap.deviations.analysis.LocalScene` of the model (:func:`model_scene`),
        to stop the camera before the next
        element in front of the face; None: no such check.
    viewers: (M, 3) sensor centres of the walk (metres); the face turned towards the nearest
        one is preferred; None: the largest face first (a wall: either side).
    """
    v = np.asarray(el.vertices, dtype=np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = 0.5 * (lo + hi)
    normals = _candidate_normals(el)
    if viewers is not None and len(viewers):
        nearest = viewers[np.argmin(np.linalg.norm(viewers - centre, axis=1))]
        to_viewer = nearest - centre
        if np.linalg.norm(to_viewer) > 1e-6:
            normals = normals[np.argsort(-(normals @ (to_viewer / np.linalg.norm(to_viewer))),
                                         kind="stable")]
    fov = FIELD_OF_VIEW_DEG
    rel = v - centre
    best: tuple[float, F64, float] | None = None  # (distance from the face, n, depth)
    for n in normals:
        # how far the element reaches along n, and how big it is across
        depth = float(np.max(rel @ n))
        across = rel - np.outer(rel @ n, n)
        half_size = float(np.max(np.linalg.norm(across, axis=1)))
        dist = float(np.clip(1.1 * half_size / np.tan(np.radians(fov / 2)), MIN_DISTANCE_M,
                             MAX_DISTANCE_M))
        if scene is not None:
            # from beyond every vertex of the element along n: its own faces are behind
            dist = min(dist, _free_distance(scene, centre + (depth + 1e-3) * n, n))
        if best is None or dist > best[0]:
            best = (dist, n, depth)
        if dist >= MIN_DISTANCE_M:  # the preferred face with room in front of it
            break
    assert best is not None
    dist, n, depth = best
    eye = centre + (depth + dist) * n
    direction = -n
    up = np.array([0.0, 0.0, 1.0]) if abs(direction[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    up = up - (up @ direction) * direction
    up /= np.linalg.norm(up)

    def t3(a: F64) -> tuple[float, float, float]:
        return (float(a[0]), float(a[1]), float(a[2]))

    return BcfCamera(t3(eye), t3(direction), t3(up), fov, t3(centre))


def _free_distance(scene: Any, start: F64, n: F64) -> float:
    """How far the camera may stand from ``start`` (a point just beyond the element's face, (3,)
    metres) along ``n``: the distance to the first element there, less :data:`CLEARANCE_M`, at
    least 5 cm; infinite when there is none. Faces within :data:`FLUSH_M` of ``start`` are passed
    through: a window or door standing in the element's opening, proud of its face by a sill."""
    travelled = 0.0
    for _ in range(8):
        origin = start + travelled * n
        ans = scene.cast_rays(origin.reshape(1, 3), np.asarray(n, np.float64).reshape(1, 3))
        t = float(ans["t_hit"][0])
        if not np.isfinite(t):
            return np.inf
        if travelled + t > FLUSH_M:
            return max(travelled + t - CLEARANCE_M, 0.05)
        travelled += t + 1e-3
    return 0.05


def model_scene(model: Any) -> LocalScene:
    """A raycasting scene of every element of ``model`` (doors and windows included: a viewer
    shows them), for :func:`element_camera`; float64 world metres in and out
    (:class:`~bimcap.deviations.analysis.LocalScene`)."""
    meshes = [e for e in model.elements if len(e.faces)]
    verts = [e.vertices for e in meshes]
    scene = LocalScene(local_origin(np.concatenate(verts) if verts else np.zeros((0, 3))))
    for e in meshes:
        scene.add_triangles(e.vertices, e.faces)
    return scene


def deviation_topics(report: DeviationReport, model: Any, viewers: F64 | None = None
                     ) -> list[BcfTopic]:
    """One :class:`BcfTopic` per ``deviating`` / ``missing`` element of ``report``, in report
    order, with cameras from ``model`` (:class:`bimcap.bim.ingest.BimModel`, the design the
    report was made against) and the walk's sensor centres ``viewers`` (M, 3), if given.

    Raises
    ------
    BcfExportError: a reported element's GUID is not in ``model``.
    """
    reported = [e for e in report.elements if e.status in REPORTED]
    if not reported:
        return []
    by_guid = {e.guid: e for e in model.elements}
    scene = model_scene(model)
    out = []
    for e in reported:
        el = by_guid.get(e.guid)
        if el is None or len(el.vertices) == 0:
            raise BcfExportError(f"element {e.guid} ({e.name}) is not in the model",
                                 field="guid", path=str(getattr(model, "path", "")) or None)
        camera = element_camera(el, scene, viewers)
        out.append(BcfTopic(str(uuid.uuid4()), str(uuid.uuid4()), e.guid, topic_title(e),
                            topic_description(e, report.options.tolerance_m),
                            (e.status.value, e.ifc_class), camera))
    return out


def _xml(root: ET.Element) -> bytes:
    ET.indent(root)
    body: bytes = ET.tostring(root, encoding="utf-8")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + body + b"\n"


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    node = ET.SubElement(parent, tag, attrib)
    if text is not None:
        node.text = text
    return node


def _point(parent: ET.Element, tag: str, xyz: tuple[float, float, float]) -> None:
    node = _sub(parent, tag)
    for axis, value in zip("XYZ", xyz, strict=True):
        _sub(node, axis, f"{value:.6f}")


def markup_xml(topic: BcfTopic, created: str, ifc_filename: str | None = None,
               ifc_project_guid: str | None = None) -> bytes:
    """``markup.bcf`` of ``topic`` (BCF 2.1 ``Markup``: Header, Topic, Viewpoints)."""
    root = ET.Element("Markup")
    if ifc_filename is not None:
        header = _sub(root, "Header")
        attrib = {"isExternal": "true"}
        if ifc_project_guid:
            attrib["IfcProject"] = ifc_project_guid
        file = _sub(header, "File", **attrib)
        _sub(file, "Filename", ifc_filename)
        _sub(file, "Date", created)
    t = _sub(root, "Topic", Guid=topic.guid, TopicType=TOPIC_TYPE, TopicStatus=TOPIC_STATUS)
    _sub(t, "Title", topic.title)
    for label in topic.labels:
        _sub(t, "Labels", label)
    _sub(t, "CreationDate", created)
    _sub(t, "CreationAuthor", AUTHOR)
    _sub(t, "Description", topic.description)
    vp = _sub(root, "Viewpoints", Guid=topic.viewpoint_guid)
    _sub(vp, "Viewpoint", VIEWPOINT_NAME)
    return _xml(root)


def viewpoint_xml(topic: BcfTopic) -> bytes:
    """``viewpoint.bcfv`` of ``topic`` (BCF 2.1 ``VisualizationInfo``: the element selected,
    everything visible, the perspective camera)."""
    root = ET.Element("VisualizationInfo", Guid=topic.viewpoint_guid)
    comps = _sub(root, "Components")
    sel = _sub(comps, "Selection")
    _sub(sel, "Component", IfcGuid=topic.element_guid)
    _sub(comps, "Visibility", DefaultVisibility="true")
    cam = _sub(root, "PerspectiveCamera")
    _point(cam, "CameraViewPoint", topic.camera.eye)
    _point(cam, "CameraDirection", topic.camera.direction)
    _point(cam, "CameraUpVector", topic.camera.up)
    _sub(cam, "FieldOfView", f"{topic.camera.field_of_view_deg:g}")
    return _xml(root)


def version_xml() -> bytes:
    """``bcf.version``."""
    root = ET.Element("Version", VersionId=BCF_VERSION)
    _sub(root, "DetailedVersion", BCF_VERSION)
    return _xml(root)


def ifc_project_guid(ifc_path: str | PathLike[str]) -> str | None:
    """The GlobalId of the IFC's ``IfcProject`` (None when it has none)."""
    import ifcopenshell

    projects = ifcopenshell.open(str(ifc_path)).by_type("IfcProject")
    return str(projects[0].GlobalId) if projects else None


def write_deviation_bcf(path: str | PathLike[str], report: DeviationReport, model: Any,
                        viewers: F64 | None = None, ifc_path: str | PathLike[str] | None = None,
                        created: datetime | None = None) -> list[BcfTopic]:
    """Write ``deviations.bcfzip`` (atomically; see the module doc) and return its topics.

    Parameters
    ----------
    path: the ``.bcfzip`` to write.
    report: the deviations; ``model``: the design they were computed against (the cameras).
    viewers: (M, 3) the walk's sensor centres (metres), to pick the face a camera looks at.
    ifc_path: the design IFC, named in each markup's header with its ``IfcProject`` GUID.
    created: the topics' ``CreationDate`` (default now, UTC).
    """
    topics = deviation_topics(report, model, viewers)
    when = (created or datetime.now(UTC)).astimezone(UTC)
    stamp = when.strftime("%Y-%m-%dT%H:%M:%SZ")
    filename = project = None
    if ifc_path is not None:
        filename, project = Path(ifc_path).name, ifc_project_guid(ifc_path)
    import io

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("bcf.version", version_xml())
        for t in topics:
            z.writestr(f"{t.guid}/{MARKUP_NAME}", markup_xml(t, stamp, filename, project))
            z.writestr(f"{t.guid}/{VIEWPOINT_NAME}", viewpoint_xml(t))
    atomic_write_bytes(path, buf.getvalue())
    return topics
