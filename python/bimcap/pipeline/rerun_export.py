"""A refine run as a Rerun recording (``run.rrd``, https://rerun.io): open it with ``rerun
run.rrd`` (the viewer of ``pip install rerun-sdk``) and scrub through the frames.

Everything is in the BIM frame (the IFC's world: z up, metres; ``world`` carries
``ViewCoordinates.RIGHT_HAND_Z_UP``). Entities (:data:`ENTITIES`):

==============================  ==================================================================
``world/bim/walls``, ``columns``  the floor plan's segments extruded over their z band, as closed
                                  outlines (``LineStrips3D``, static)
``world/trajectories/<name>``    ``initial`` (grey), ``facap`` (orange, when the run has one),
                                  ``refined`` (blue), ``ground_truth`` (white: the viewer's
                                  background is dark; black in the report), ``LineStrips3D``, static
``world/map_refined``            ``map_refined.ply`` downsampled, coloured by class
                                  (``Points3D`` with ``class_ids``; the class names are the
                                  ``world`` annotation context's), static
``world/camera``                 the refined ``world_from_cam`` of each frame (``Transform3D``)
``world/camera/image``           the camera's ``Pinhole`` (the undistorted K, OpenCV axes: x right,
                                  y down, z forward) and, unless skipped, the frame's image,
                                  downscaled, JPEG (the sequence's raw, distorted image)
``errors/position/<name>``       ‖t − t_gt‖ per frame, metres (``Scalars``), with ground truth
``errors/rotation/<name>``       rotation angle of R_estᵀ R_gt per frame, degrees
==============================  ==================================================================

Per-frame data sits on two timelines: ``frame`` (the frame's index, 0-based) and ``time`` (seconds
since the first frame). The recording is written with a recording stream's file sink alone: no
viewer, no network. Rerun (the ``rerun`` extra: ``pip install 'bimcap[rerun]'``) is imported when
a recording is written, behind :func:`bimcap.errors.require`.

Two ways in: :func:`export_run` reads a finished run directory (``bimcap export-rerun RUN``:
``result.json`` names the sequence; the BIM reference is the run's ``bim/``), and
:func:`write_recording` takes the arrays in memory (``bimcap refine --rerun``, at the end of the
run).
"""

from __future__ import annotations

import json
import os
import time
import uuid
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError, require
from bimcap.labels import LABEL_COLORS, Label

F64 = NDArray[np.float64]

#: The entity paths of a recording (``{name}``: a trajectory's name, :data:`TRAJECTORY_COLOURS`).
ENTITIES = {
    "world": "world",
    "walls": "world/bim/walls",
    "columns": "world/bim/columns",
    "trajectory": "world/trajectories/{name}",
    "map": "world/map_refined",
    "camera": "world/camera",
    "image": "world/camera/image",
    "position_error": "errors/position/{name}",
    "rotation_error": "errors/rotation/{name}",
}

#: RGB of each trajectory: the report's palette (bimcap.evaluation.plots.run_colour), but ground
#: truth white, as the viewer's background is dark.
TRAJECTORY_COLOURS: dict[str, tuple[int, int, int]] = {
    "initial": (153, 153, 153),
    "facap": (255, 127, 14),
    "refined": (31, 119, 180),
    "ground_truth": (245, 245, 245),
}

#: What needs the package, for the one-line error of :func:`bimcap.errors.require`.
NEEDED_FOR = "writing a Rerun recording (bimcap export-rerun, refine --rerun)"


def require_rerun() -> Any:
    """The ``rerun`` module, or :class:`bimcap.errors.MissingDependencyError` naming the
    ``rerun`` extra."""
    return require("rerun", "rerun-sdk", "rerun", NEEDED_FOR)


@dataclass(frozen=True)
class RecordingOptions:
    """What a recording holds and how big it gets.

    Attributes
    ----------
    images: log each frame's image (when the sequence is reachable).
    image_scale: the images' size relative to the camera's (0 < s ≤ 1).
    jpeg_quality: JPEG quality of the logged images (1–100).
    max_points: at most this many points of ``map_refined.ply`` (a regular subsample).
    """

    images: bool = True
    image_scale: float = 0.5
    jpeg_quality: int = 80
    max_points: int = 100_000

    def __post_init__(self) -> None:
        if not 0.0 < self.image_scale <= 1.0:
            raise InputError(f"must be in (0, 1], got {self.image_scale}", field="image_scale")
        if not 1 <= self.jpeg_quality <= 100:
            raise InputError(f"must be in [1, 100], got {self.jpeg_quality}",
                             field="jpeg_quality")
        if self.max_points < 0:
            raise InputError(f"must be >= 0, got {self.max_points}", field="max_points")


@dataclass
class RecordingInput:
    """The arrays a recording shows.

    Attributes
    ----------
    timestamps: (N,) seconds of the frames.
    trajectories: name → (N, 7) ``world_from_cam`` TUM-order poses (metres); ``refined`` is the
        camera of the per-frame entities, ``ground_truth`` (when present) the errors' reference.
    segments: (S, 4) floor-plan segments ``x1 y1 x2 y2`` (m). segment_class: (S,) Label ids.
    segment_z: (S, 2) the z band of each segment (m).
    map_points: (P, 3) metres, or None. map_labels: (P,) Label ids, or None.
    camera: the undistorted pinhole camera (``bimcap.geometry.Camera``), or None.
    image_paths: the frames' image files (N), or None when the sequence is not reachable.
    """

    timestamps: F64
    trajectories: dict[str, F64]
    segments: F64 = field(default_factory=lambda: np.zeros((0, 4)))
    segment_class: NDArray[np.int32] = field(default_factory=lambda: np.zeros(0, np.int32))
    segment_z: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    map_points: F64 | None = None
    map_labels: NDArray[np.uint8] | None = None
    camera: Any = None
    image_paths: list[Path] | None = None

    def __post_init__(self) -> None:
        n = len(self.timestamps)
        if "refined" not in self.trajectories:
            raise InputError("no refined trajectory", field="trajectories")
        for name, poses in self.trajectories.items():
            if np.shape(poses) != (n, 7):
                raise InputError(f"expected ({n}, 7) poses, got {np.shape(poses)}",
                                 field=f"trajectories.{name}")
        if self.image_paths is not None and len(self.image_paths) != n:
            raise InputError(f"expected {n} images, got {len(self.image_paths)}",
                             field="image_paths")


@dataclass
class RecordingSummary:
    """What :func:`write_recording` wrote.

    Attributes
    ----------
    path: the ``.rrd`` file. frames: frames on the ``frame`` timeline. images: images logged.
    map_points: points of the refined map logged. bim_segments: floor-plan segments logged.
    trajectories: the trajectories' names. bytes: size of the file. seconds: wall time.
    """

    path: str
    frames: int
    images: int
    map_points: int
    bim_segments: int
    trajectories: list[str]
    bytes: int
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def wall_outlines(segments: F64, segment_z: F64) -> F64:
    """Each floor-plan segment as a closed vertical rectangle: (S, 5, 3) metres, the segment at
    the bottom of its z band, up, back along the top, down, closed."""
    s = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    z = np.asarray(segment_z, dtype=np.float64).reshape(-1, 2)
    out = np.empty((len(s), 5, 3))
    for k, (xi, yi, zi) in enumerate(((0, 1, 0), (2, 3, 0), (2, 3, 1), (0, 1, 1), (0, 1, 0))):
        out[:, k, 0], out[:, k, 1], out[:, k, 2] = s[:, xi], s[:, yi], z[:, zi]
    return out


def frame_errors(est: F64, gt: F64) -> tuple[F64, F64]:
    """Per-frame position error (N,) metres and rotation error (N,) degrees of ``est`` against
    ``gt`` (both (N, 7), no alignment: the BIM frame is shared), as the metrics compute them."""
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics

    fe = trajectory_metrics(est, gt, AlignMode.NONE).frame_errors
    return np.asarray(fe.trans_m, dtype=np.float64), np.asarray(fe.rot_deg, dtype=np.float64)


def _subsample(n: int, k: int) -> NDArray[np.int64]:
    """At most ``k`` indices of ``range(n)``, evenly spread (all of them when n ≤ k)."""
    if n <= k:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def _jpeg(path: Path, scale: float, quality: int) -> tuple[bytes, tuple[int, int]]:
    """The image at ``path`` resized by ``scale``, as JPEG bytes, and its (width, height)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError("cannot decode image", path)
    if scale != 1.0:
        size = (max(1, round(img.shape[1] * scale)), max(1, round(img.shape[0] * scale)))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise InputError("cannot encode image as JPEG", path)
    return buf.tobytes(), (img.shape[1], img.shape[0])


def write_recording(path: str | PathLike[str], inp: RecordingInput,
                    options: RecordingOptions | None = None,
                    application_id: str = "bimcap") -> RecordingSummary:
    """Write ``inp`` as a Rerun recording into ``path`` (atomically: a temporary file beside it,
    then renamed); the entities of :data:`ENTITIES`. Raises
    :class:`bimcap.errors.MissingDependencyError` without the ``rerun`` extra."""
    rr = require_rerun()
    opts = options or RecordingOptions()
    t0 = time.perf_counter()
    out = Path(path)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    rec = rr.RecordingStream(application_id, recording_id=uuid.uuid5(uuid.NAMESPACE_URL,
                                                                     str(out.resolve())),
                             send_properties=False)
    rec.set_log_time_enabled(False)  # no wall-clock timeline: the frame and time timelines only
    rec.set_log_tick_enabled(False)
    images = 0
    try:
        rec.save(tmp)
        _log_static(rr, rec, inp, opts)
        map_n = 0 if inp.map_points is None else len(_subsample(len(inp.map_points),
                                                                opts.max_points))
        images = _log_frames(rr, rec, inp, opts)
        rec.flush()
        rec.disconnect()
        os.replace(tmp, out)
    except BaseException:
        rec.disconnect()
        tmp.unlink(missing_ok=True)
        raise
    return RecordingSummary(str(out), len(inp.timestamps), images, map_n, len(inp.segments),
                            list(inp.trajectories), out.stat().st_size,
                            time.perf_counter() - t0)


def _log_static(rr: Any, rec: Any, inp: RecordingInput, opts: RecordingOptions) -> None:
    """The world's axes and class names, the BIM, the trajectories and the map."""
    rec.log(ENTITIES["world"], rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(ENTITIES["world"], rr.AnnotationContext(
        [(int(lab), lab.name.lower(), tuple(int(c) for c in LABEL_COLORS[int(lab)]))
         for lab in Label]), static=True)
    outlines = wall_outlines(inp.segments, inp.segment_z)
    for key, label in (("walls", Label.WALL), ("columns", Label.COLUMN)):
        sel = np.asarray(inp.segment_class) == int(label)
        if sel.any():
            rec.log(ENTITIES[key], rr.LineStrips3D(outlines[sel], class_ids=int(label),
                                                   radii=0.01), static=True)
    for name, poses in inp.trajectories.items():
        colour = TRAJECTORY_COLOURS.get(name, (44, 160, 44))
        rec.log(ENTITIES["trajectory"].format(name=name),
                rr.LineStrips3D([np.asarray(poses)[:, :3]], colors=colour, radii=0.015,
                                labels=name), static=True)
    if inp.map_points is not None and len(inp.map_points):
        keep = _subsample(len(inp.map_points), opts.max_points)
        labels = (np.zeros(len(keep), np.uint16) if inp.map_labels is None
                  else np.asarray(inp.map_labels)[keep].astype(np.uint16))
        rec.log(ENTITIES["map"], rr.Points3D(np.asarray(inp.map_points)[keep],
                                             class_ids=labels, radii=0.01), static=True)
    for name in inp.trajectories:
        if name == "ground_truth" or "ground_truth" not in inp.trajectories:
            continue
        colour = TRAJECTORY_COLOURS.get(name, (44, 160, 44))
        for kind in ("position_error", "rotation_error"):
            unit = "m" if kind == "position_error" else "deg"
            rec.log(ENTITIES[kind].format(name=name),
                    rr.SeriesLines(colors=colour, names=f"{name} [{unit}]"), static=True)


def _log_frames(rr: Any, rec: Any, inp: RecordingInput, opts: RecordingOptions) -> int:
    """Per frame: the refined camera, its pinhole and image, the errors; returns the number of
    images logged."""
    refined = np.asarray(inp.trajectories["refined"])
    errors: dict[str, tuple[F64, F64]] = {}
    gt = inp.trajectories.get("ground_truth")
    if gt is not None:
        errors = {name: frame_errors(np.asarray(p), np.asarray(gt))
                  for name, p in inp.trajectories.items() if name != "ground_truth"}
    t0 = float(inp.timestamps[0]) if len(inp.timestamps) else 0.0
    images = 0
    pinhole = None
    if inp.camera is not None:
        cam = inp.camera
        s = opts.image_scale if (opts.images and inp.image_paths is not None) else 1.0
        k = np.array([[cam.fx * s, 0.0, (cam.cx + 0.5) * s - 0.5],
                      [0.0, cam.fy * s, (cam.cy + 0.5) * s - 0.5],
                      [0.0, 0.0, 1.0]])
        size = [max(1, round(cam.width * s)), max(1, round(cam.height * s))]
        pinhole = rr.Pinhole(image_from_camera=k, resolution=size,
                             camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3)
    for i, ts in enumerate(inp.timestamps):
        rec.set_time("frame", sequence=i)
        rec.set_time("time", duration=float(ts) - t0)
        pose = refined[i]
        rec.log(ENTITIES["camera"], rr.Transform3D(
            translation=pose[:3], quaternion=rr.Quaternion(xyzw=pose[3:7])))
        if pinhole is not None:
            rec.log(ENTITIES["image"], pinhole)
        if opts.images and inp.image_paths is not None:
            data, _ = _jpeg(inp.image_paths[i], opts.image_scale, opts.jpeg_quality)
            rec.log(ENTITIES["image"], rr.EncodedImage(contents=data, media_type="image/jpeg"))
            images += 1
        for name, (trans_m, rot_deg) in errors.items():
            rec.log(ENTITIES["position_error"].format(name=name), rr.Scalars(trans_m[i]))
            rec.log(ENTITIES["rotation_error"].format(name=name), rr.Scalars(rot_deg[i]))
    return images


# ------------------------------------------------------------------ a finished run directory
def _run_file(run: Path, name: str) -> Path:
    p = run / name
    if not p.is_file():
        raise InputError("missing: not a finished bimcap refine output directory (refine "
                         "writes result.json last)" if name == "result.json" else "missing", p)
    return p


def _sequence_of(run: Path, result: dict[str, Any]) -> Path | None:
    """The run's sequence directory: ``result.json``'s ``inputs.sequence``, else the demo's
    layout (``OUT/sequence`` beside ``OUT/refine``); None when neither has a manifest."""
    from bimcap.dataset.sequence import MANIFEST

    named = (result.get("inputs") or {}).get("sequence")
    for candidate in ([Path(named)] if named else []) + [run.parent / "sequence"]:
        if (candidate / MANIFEST).is_file():
            return candidate
    return None


def recording_input_from_run(run_dir: str | PathLike[str]) -> RecordingInput:
    """What a finished run directory gives a recording: ``refined.tum`` (and
    ``refined_facap.tum``), the BIM reference of ``bim/``, ``map_refined.ply``, and from the
    sequence ``result.json`` names (when it is reachable) the camera, the images, the initial
    trajectory (``inputs.init``, else the sequence's ``poses/init.tum``) and the ground truth
    (``inputs.gt``, else ``poses/gt.tum``). A missing run directory, ``result.json`` or
    ``refined.tum`` raises :class:`InputError` naming it."""
    from bimcap.bim.reference import BimReference
    from bimcap.dataset import read_sequence
    from bimcap.geometry import read_tum
    from bimcap.io.ply import read_labelled_ply

    run = Path(run_dir)
    if not run.is_dir():
        raise InputError("no such run directory", run)
    result_path = _run_file(run, "result.json")
    try:
        result = json.loads(result_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON: {exc}", result_path) from None
    if result.get("status") == "refused":
        raise InputError("the run was refused (no refined trajectory): "
                         f"{result.get('error', '')}", result_path, "status")
    refined = read_tum(_run_file(run, "refined.tum"))
    trajectories: dict[str, F64] = {}
    seq_dir = _sequence_of(run, result)
    seq = read_sequence(seq_dir) if seq_dir is not None else None
    inputs = result.get("inputs") or {}
    for name, key in (("initial", "init"), ("ground_truth", "gt")):
        path = inputs.get(key)
        if path is None and seq is not None and seq.has_trajectory(key):
            path = seq.trajectory_path(key)
        if path is not None and Path(path).is_file():
            traj = read_tum(path)
            if len(traj) == len(refined):
                trajectories[name] = traj.poses
    if (run / "refined_facap.tum").is_file():
        trajectories["facap"] = read_tum(run / "refined_facap.tum").poses
    trajectories["refined"] = refined.poses
    inp = RecordingInput(refined.timestamps, trajectories)
    if (run / "bim" / "reference.npz").is_file():
        ref = BimReference.load(run / "bim")
        inp.segments, inp.segment_class, inp.segment_z = (ref.segments, ref.segment_class,
                                                          ref.segment_z)
    if (run / "map_refined.ply").is_file():
        inp.map_points, inp.map_labels = read_labelled_ply(run / "map_refined.ply")
    if seq is not None and len(seq) == len(refined):
        inp.camera = seq.camera.pinhole()
        inp.image_paths = [seq.root / f.image for f in seq.frames]
    return inp


def export_run(run_dir: str | PathLike[str], out: str | PathLike[str],
               options: RecordingOptions | None = None) -> RecordingSummary:
    """``bimcap export-rerun``: the recording of the finished run in ``run_dir``, into ``out``
    (:func:`recording_input_from_run`, :func:`write_recording`). Rerun is required first, before
    any file is read."""
    require_rerun()
    return write_recording(out, recording_input_from_run(run_dir), options)
