"""The sensor simulator: a handheld camera + VLP-16 rig walking through an (as-built) building.

``simulate(ifc, out_dir, config, seed)`` loads the building's meshes (the as-built IFC if given),
plans a handheld walk through its free space (:mod:`bimcap.sim.walk`), adds clutter the BIM does
not have off the walking path (:mod:`bimcap.sim.clutter`), and ray-casts, per frame, a raw RGB
image with procedural texture, its ground-truth label image and z-depth (:mod:`bimcap.sim.render`)
and one LiDAR sweep at ConSLAM's LiDAR→camera extrinsic (:mod:`bimcap.sim.lidar`). It writes a
sequence directory (docs/architecture.md): ``manifest.json``, ``images/``, ``labels/``,
``depth/``, ``lidar/`` and ``poses/gt.tum`` (``world_from_cam``). With label noise
(:mod:`bimcap.sim.label_noise`) ``labels/`` holds the corrupted labels a segmenter might give
and ``labels_gt/`` the true ones.

Realism settings (all in :class:`SimulatorConfig`, all recorded in the manifest's ``source``):
the camera (its field of view through its focal length, :func:`with_focal_scale`), the walk's
pitch and its glances up (:class:`~bimcap.sim.walk.WalkConfig`), the LiDAR's range noise and
dropouts (:class:`~bimcap.sim.lidar.LidarConfig`), the amount of clutter and the label noise.

Rig: ``world_from_lidar = world_from_cam ∘ cam_from_lidar``. With ConSLAM's extrinsic the LiDAR's
z axis is the camera's −y axis (up when the camera is level) and its x axis the camera's z axis
(forward), so the VLP-16's ±15° fan is centred on the horizon.

Determinism: everything random derives from ``seed`` through ``numpy.random.default_rng`` with a
fixed key per use (walk, clutter, element texture offsets, frame ``i`` image noise, frame ``i``
LiDAR noise, frame ``i`` label noise; the texture tiles come from ``config.texture_seed``), so the
same seed and configuration give byte-identical files whatever the number of worker processes.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.dataset import MANIFEST, FrameInfo, LidarInfo, SequenceWriter, write_frame
from bimcap.dataset import Sequence as SequenceDir
from bimcap.dataset.conslam import (
    CONSLAM_CAM_FROM_LIDAR,
    CONSLAM_CAM_FROM_LIDAR_MATRIX,
    CONSLAM_CAMERA,
)
from bimcap.geometry.camera import Camera
from bimcap.geometry.poses import compose
from bimcap.geometry.trajectory import Trajectory
from bimcap.io.atomic import check_not_input
from bimcap.labels import Label
from bimcap.progress import progress
from bimcap.sim.clutter import ClutterObject, box_mesh, place_clutter
from bimcap.sim.label_noise import LabelNoiseConfig, corrupt_labels
from bimcap.sim.lidar import LidarConfig, LidarSimulator
from bimcap.sim.render import MeshPart, Renderer, ShadingConfig, SimConfigError, SimError, World
from bimcap.sim.texture import TextureBank
from bimcap.sim.walk import FreeSpace, Walk, WalkConfig, plan_walk
from bimcap.sim.walkable import Level, WalkableOptions, choose_free_space, door_footprints

F64 = NDArray[np.float64]
_log = logging.getLogger(__name__)

__all__ = [
    "CONSLAM_CAMERA",
    "CONSLAM_CAM_FROM_LIDAR",
    "SimError",
    "SimulationResult",
    "SimulatorConfig",
    "corridor_building",
    "focal_scale_for_hfov",
    "simulate",
    "simulate_world",
    "with_focal_scale",
]

#: ConSLAM's calibration, defined once in the importer: the RGB camera at full
#: resolution, the LiDAR→camera extrinsic as published (3×4) and as a TUM-order pose.
CONSLAM_CAM_FROM_LIDAR_3X4 = CONSLAM_CAM_FROM_LIDAR_MATRIX


@dataclass(frozen=True)
class SimulatorConfig:
    """Everything that shapes a simulated sequence (the seed is passed separately).

    Attributes
    ----------
    camera: the raw camera (size, K, plumb_bob); default ConSLAM's scaled by 0.5 → 1032×772.
    frames: number of frames.
    fps: camera frame rate (Hz); at ~1 m/s, 3 Hz gives ~70 % overlap between neighbours.
    lidar: LiDAR model, or None for no LiDAR.
    cam_from_lidar: (7,) TUM-order extrinsic (default ConSLAM's).
    walk: the walking model.
    shading: the photometric model.
    clutter_density_per_m2: clutter objects per m² of free floor (when clutter is on).
    label_noise: wrong labels written to ``labels/`` (the truth then goes to ``labels_gt/``).
    remove_doors: drop door leaves (IfcDoor meshes) so that doorways can be walked through.
    z_floor: floor height to walk on; None = a storey (``storey``, or the one with the largest
        connected walkable area, :func:`bimcap.sim.walkable.choose_free_space`).
    storey: name of the storey to walk (ignored when ``z_floor`` is given); None = choose.
    write_labels, write_depth: write the ground-truth label and depth images.
    png_compression: zlib level of the PNG files (0–9; 1 is fast).
    texture_seed: seed of the baked surface textures (element texture offsets follow ``seed``).
    workers: render processes (1 = in this process; 0 = one per CPU).
    threads_per_worker: ray-casting threads per process (0 = Open3D's default).
    """

    camera: Camera = field(default_factory=lambda: CONSLAM_CAMERA.scaled(0.5))
    frames: int = 200
    fps: float = 3.0
    lidar: LidarConfig | None = field(default_factory=LidarConfig)
    cam_from_lidar: tuple[float, ...] = tuple(float(x) for x in CONSLAM_CAM_FROM_LIDAR)
    walk: WalkConfig = field(default_factory=WalkConfig)
    shading: ShadingConfig = field(default_factory=ShadingConfig)
    clutter_density_per_m2: float = 0.08
    label_noise: LabelNoiseConfig = field(default_factory=LabelNoiseConfig)
    remove_doors: bool = True
    z_floor: float | None = None
    storey: str | None = None
    write_labels: bool = True
    write_depth: bool = True
    png_compression: int = 1
    texture_seed: int = 0
    workers: int = 2
    threads_per_worker: int = 1

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise SimError(f"frames must be >= 1, got {self.frames}")
        if not (self.fps > 0):
            raise SimError(f"fps must be > 0, got {self.fps}")
        if len(self.cam_from_lidar) != 7:
            raise SimError("cam_from_lidar must have 7 numbers (TUM order)")
        if not 0 <= self.png_compression <= 9:
            raise SimError("png_compression must be in 0..9")
        if self.workers < 0:
            raise SimError("workers must be >= 0")
        if not (np.isfinite(self.clutter_density_per_m2) and self.clutter_density_per_m2 >= 0):
            raise SimConfigError(f"must be finite and >= 0 (got {self.clutter_density_per_m2!r})",
                                 None, "clutter_density_per_m2")
        if self.label_noise.enabled and not self.write_labels:
            raise SimConfigError("label noise needs write_labels", None, "label_noise")

    @classmethod
    def small(cls, **overrides: Any) -> SimulatorConfig:
        """A fast configuration for tests: 320×239 ConSLAM-like camera, 6 frames, 1 process."""
        base: dict[str, Any] = {
            "camera": CONSLAM_CAMERA.scaled(320 / 2064), "frames": 6, "fps": 3.0, "workers": 1,
            "threads_per_worker": 0,
        }
        base.update(overrides)
        return cls(**base)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["camera"] = self.camera.to_dict()
        d["lidar"] = None if self.lidar is None else self.lidar.to_dict()
        d["cam_from_lidar"] = list(self.cam_from_lidar)
        d["walk"] = self.walk.to_dict()
        d["label_noise"] = self.label_noise.to_dict()
        d.pop("workers")
        d.pop("threads_per_worker")
        return d


@dataclass
class SimulationResult:
    """What :func:`simulate_world` produced.

    Attributes
    ----------
    sequence: the written sequence, read back and validated by :func:`bimcap.dataset.read_sequence`.
    world_from_cam: (N, 7) ground-truth camera poses, TUM order.
    timestamps: (N,) seconds.
    clutter: the placed clutter objects.
    world_triangles: triangles in the rendered world (as-built meshes + clutter).
    timings: seconds per stage (not written to disk, which stays deterministic): wall clock of
        the main stages, ``sum_*`` wall seconds summed over render workers, ``cpu_*`` CPU seconds
        (``time.process_time``) summed over render workers (``image``, ``lidar``, ``write``).
    """

    sequence: SequenceDir
    world_from_cam: F64
    timestamps: F64
    clutter: list[ClutterObject]
    world_triangles: int
    timings: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            "out_dir": str(self.sequence.root),
            "frames": len(self.timestamps),
            "clutter": [c.to_dict() for c in self.clutter],
            "timings": self.timings,
        }


# --------------------------------------------------------------------------------- world input
def corridor_building(
    rooms_per_side: int = 2,
    room_size_m: tuple[float, float] = (4.0, 4.0),
    corridor_width_m: float = 2.2,
    height_m: float = 2.8,
    wall_m: float = 0.2,
    door_width_m: float = 1.0,
    door_height_m: float = 2.1,
) -> tuple[list[MeshPart], list[F64], F64]:
    """A one-storey corridor with rooms on both sides, as meshes (no IFC needed).

    The corridor runs along +x at y ∈ [−w/2, w/2]; rooms of ``room_size_m`` (x, y) open onto it
    through doors centred on each room; every room has a corner column and a window panel on its
    outer wall. Floor top at z = 0, ceiling at ``height_m``.

    Returns
    -------
    parts: mesh parts with labels (walls, floor and ceiling slabs, columns, windows).
    polygons: free-space rectangles (4, 2) — the corridor and the rooms.
    doors_xy: (D, 2) door centres (on the corridor walls' centre lines).
    """
    rw, rd = room_size_m
    cw, t, hz = corridor_width_m, wall_m, height_m
    length = rooms_per_side * rw
    y_in = cw / 2 + t / 2  # corridor wall centre lines
    y_out = cw / 2 + t + rd + t / 2  # outer wall centre lines
    parts: list[MeshPart] = []
    k = 0

    def add(label: Label, lo: Sequence[float], hi: Sequence[float]) -> None:
        nonlocal k
        v, f = box_mesh(np.asarray(lo, float), np.asarray(hi, float))
        parts.append(MeshPart(f"{label.name.lower()}-{k:03d}", label, v, f))
        k += 1

    x0, x1 = -t / 2, length + t / 2
    add(Label.FLOOR, (x0, -y_out - t / 2, -0.25), (x1, y_out + t / 2, 0.0))
    add(Label.CEILING, (x0, -y_out - t / 2, hz), (x1, y_out + t / 2, hz + 0.25))
    doors = []
    for side in (-1.0, 1.0):
        # corridor wall with door gaps and lintels
        y_lo, y_hi = sorted((side * (y_in - t / 2), side * (y_in + t / 2)))
        xs = [x0]
        for i in range(rooms_per_side):
            xc = (i + 0.5) * rw
            doors.append((xc, side * y_in))
            xs += [xc - door_width_m / 2, xc + door_width_m / 2]
            add(Label.WALL, (xc - door_width_m / 2, y_lo, door_height_m),
                (xc + door_width_m / 2, y_hi, hz))
        xs.append(x1)
        for a, b in zip(xs[0::2], xs[1::2], strict=False):
            add(Label.WALL, (a, y_lo, 0.0), (b, y_hi, hz))
        # outer wall
        y_lo, y_hi = sorted((side * (y_out - t / 2), side * (y_out + t / 2)))
        add(Label.WALL, (x0, y_lo, 0.0), (x1, y_hi, hz))
        # partitions between rooms (and the end walls on this side)
        yr_lo, yr_hi = sorted((side * (y_in + t / 2), side * (y_out - t / 2)))
        for i in range(rooms_per_side + 1):
            xw = i * rw
            add(Label.WALL, (xw - t / 2, yr_lo, 0.0), (xw + t / 2, yr_hi, hz))
        for i in range(rooms_per_side):
            # a column in the room corner by the outer wall, a window panel on the outer wall
            cx = i * rw + t / 2
            cy_lo = yr_lo if side > 0 else yr_hi - 0.35
            add(Label.COLUMN, (cx, cy_lo, 0.0),
                (cx + 0.35, (cy_lo + 0.35), hz))
            xc = (i + 0.5) * rw
            face = side * (y_out - t / 2)
            add(Label.WINDOW, (xc - 0.7, min(face, face - side * 0.02), 0.9),
                (xc + 0.7, max(face, face - side * 0.02), 2.1))
    # end walls of the corridor
    add(Label.WALL, (x0, -y_in, 0.0), (t / 2, y_in, hz))
    add(Label.WALL, (length - t / 2, -y_in, 0.0), (x1, y_in, hz))
    rect = lambda a, b, c, d: np.array([[a, c], [b, c], [b, d], [a, d]], float)  # noqa: E731
    polygons = [rect(t / 2, length - t / 2, -cw / 2, cw / 2)]
    for side in (-1.0, 1.0):
        y_a, y_b = sorted((side * (y_in + t / 2), side * (y_out - t / 2)))
        for i in range(rooms_per_side):
            polygons.append(rect(i * rw + t / 2, (i + 1) * rw - t / 2, y_a, y_b))
    return parts, polygons, np.asarray(doors, float)


def load_ifc_parts(path: str | PathLike[str]) -> list[MeshPart]:
    """Mesh parts of every element of an IFC (world metres, labels of bimcap.labels).

    Tessellation and classification are :func:`bimcap.bim.load_model`'s; parts are sorted by
    GUID so that the world (and hence every output byte) does not depend on thread scheduling.
    """
    from bimcap.bim import load_model

    return model_parts(load_model(Path(path)))


def model_parts(model: Any) -> list[MeshPart]:
    """Mesh parts of every element of a :class:`bimcap.bim.BimModel`, sorted by GUID."""
    parts = [
        MeshPart(e.guid, Label(e.label), np.asarray(e.vertices, np.float64),
                 np.asarray(e.faces, np.int32))
        for e in model.elements
    ]
    parts.sort(key=lambda q: q.name)
    return parts


def missing_floor_parts(model: Any, thickness_m: float = 0.1, close_m: float = 0.35,
                        min_area_m2: float = 4.0) -> tuple[list[MeshPart], list[str]]:
    """Floor slabs for the storeys a model leaves without one (Office_A has no floor IfcSlab).

    The floors are the model's own reference floors (:func:`bimcap.bim.planes.extract_planes`,
    source ``"space"``: the bottoms of the storey's IfcSpace volumes), so the BIM reference and
    the rendered world agree. Per storey and height the space outlines are united and closed by
    ``close_m`` (the sills of the doors between two spaces lie under no space), triangulated and
    given ``thickness_m``; where a slab or covering already lies at that height (a roof storey's
    space on the roof slab) no floor is laid, nor in pieces under ``min_area_m2``.

    Returns
    -------
    (parts, notes): FLOOR mesh parts named ``synthetic-floor-…`` and one note per storey.
    """
    import warnings

    import shapely

    from bimcap.bim.planes import extract_planes, union_xy

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the missing floors are exactly what is handled here
        planes = extract_planes(model)
    groups: dict[tuple[str | None, float], list[Any]] = {}
    for p in planes:
        if p.kind == Label.FLOOR and p.source == "space":
            groups.setdefault((p.storey, round(p.height, 3)), []).append(p.shape())
    parts: list[MeshPart] = []
    notes: list[str] = []
    for k, ((storey, z), polys) in enumerate(sorted(groups.items(), key=lambda kv: kv[0][1])):
        geom = shapely.union_all(polys).buffer(close_m, join_style="mitre").buffer(
            -close_m, join_style="mitre")
        # where a slab or covering already bounds the space from below (a roof storey's space
        # on the roof slab), the model is not missing a floor there
        near = [e for e in model.elements
                if e.label in (Label.FLOOR, Label.CEILING) or e.ifc_class in ("IfcSlab", "IfcRoof")]
        near = [e for e in near if e.zmin <= z + 0.05 and e.zmax >= z - 0.3]
        if near:
            geom = geom.difference(union_xy(np.concatenate([e.vertices[e.faces] for e in near])))
            geom = geom.buffer(-0.25, join_style="mitre").buffer(0.25, join_style="mitre")
        geom = shapely.union_all([g for g in getattr(geom, "geoms", [geom])
                                  if g.area >= min_area_m2])
        if geom.is_empty:
            continue
        tris = shapely.constrained_delaunay_triangles(geom)
        xy = np.array([np.asarray(t.exterior.coords)[:3] for t in tris.geoms], np.float64)
        if len(xy) == 0:
            continue
        m = len(xy)
        top = np.concatenate([xy, np.full((m, 3, 1), z)], axis=2)
        bottom = np.concatenate([xy, np.full((m, 3, 1), z - thickness_m)], axis=2)
        # top faces wound counter-clockwise seen from above (normal up), bottoms the other way
        ccw = ((xy[:, 1, 0] - xy[:, 0, 0]) * (xy[:, 2, 1] - xy[:, 0, 1])
               - (xy[:, 2, 0] - xy[:, 0, 0]) * (xy[:, 1, 1] - xy[:, 0, 1])) > 0
        top[~ccw] = top[~ccw][:, ::-1]
        bottom[ccw] = bottom[ccw][:, ::-1]
        v = np.concatenate([top, bottom]).reshape(-1, 3)
        f = np.arange(len(v), dtype=np.int32).reshape(-1, 3)
        parts.append(MeshPart(f"synthetic-floor-{k:02d}", Label.FLOOR, v, f))
        notes.append(f"storey {storey!r} has no floor slab: laid a floor at z {z:+.3f} m "
                     f"({geom.area:.0f} m²) from its IfcSpace bottoms")
    return parts, notes


def sidecar_free_space(ifc: str | PathLike[str], storey: int = 0
                       ) -> tuple[list[F64], float] | None:
    """Free-space polygons and floor height of ``storey`` from a generated building's sidecar.

    Reads ``NAME.truth.json`` next to ``NAME.ifc`` (:func:`bimcap.sim.building.truth_path_for`);
    returns None when there is none. The polygons are the storey's walkable regions (rooms,
    corridor, door passages, removed walls), each (4, 2) world xy.
    """
    from bimcap.sim.building import truth_path_for
    from bimcap.sim.building_truth import load_building_truth

    path = truth_path_for(ifc)
    if not path.is_file():
        return None
    truth = load_building_truth(path)
    for fs in truth.free_space:
        if fs.storey == storey:
            return [r.polygon() for r in fs.regions], float(fs.floor_z)
    raise SimError(f"{path}: no free space for storey {storey}")


# ------------------------------------------------------------------------------- frame writing
def _finish_sequence(out: Path, cfg: SimulatorConfig, frames: list[FrameInfo],
                     world_from_cam: F64, ifc_ref: str | None,
                     source: dict[str, Any]) -> SequenceDir:
    """Register the frames (written by the render workers with :func:`bimcap.dataset.write_frame`)
    with a :class:`bimcap.dataset.SequenceWriter`, which writes ``poses/gt.tum`` and the manifest
    last, and returns the sequence read back."""
    lidar = LidarInfo.from_dict((cfg.lidar or LidarConfig()).to_dict())
    writer = SequenceWriter(out, cfg.camera, np.asarray(cfg.cam_from_lidar), lidar=lidar,
                            ifc=ifc_ref, source=source, overwrite=True)
    for info in frames:
        writer.register_frame(info)
    timestamps = np.array([f.timestamp for f in frames])
    writer.add_trajectory("gt", Trajectory(timestamps, world_from_cam))
    return writer.close()


# ----------------------------------------------------------------------------- frame rendering
@dataclass
class _RenderJob:
    world: World
    textures: TextureBank
    config: SimulatorConfig
    out_dir: Path
    seed: int


#: What one frame gives back: its info, wall and CPU seconds per stage, label-noise statistics.
_FrameResult = tuple[FrameInfo, dict[str, float], dict[str, float]]


class _FrameRenderer:
    """Renders, scans and writes the frames of one job (one per process: made once)."""

    def __init__(self, job: _RenderJob) -> None:
        self.job = job
        self.renderer = Renderer(job.world, job.config.camera, job.textures, job.config.shading)
        self.lidar = (
            None if job.config.lidar is None else LidarSimulator(job.world, job.config.lidar)
        )

    def __call__(self, args: tuple[int, float, F64]) -> _FrameResult:
        """Render, scan and write frame ``i``; returns its info, wall and CPU seconds per stage,
        and the label-noise statistics (empty without label noise)."""
        i, timestamp, world_from_cam = args
        job = self.job
        cfg = job.config
        timings: dict[str, float] = {}
        c0 = time.process_time()
        frame = self.renderer.render(
            world_from_cam, np.random.default_rng([job.seed, 101, i]), cfg.threads_per_worker,
            timings,
        )
        c1 = time.process_time()
        scan = np.zeros((0, 4), np.float32)  # no LiDAR: the format still wants a (0, 4) scan
        t0 = time.perf_counter()
        if self.lidar is not None:
            world_from_lidar = compose(world_from_cam, np.asarray(cfg.cam_from_lidar))
            scan = self.lidar.scan(
                world_from_lidar, np.random.default_rng([job.seed, 202, i]), cfg.threads_per_worker
            )
        t1 = time.perf_counter()
        c2 = time.process_time()
        labels, labels_gt, noise_stats = frame.labels, None, {}
        if cfg.write_labels and cfg.label_noise.enabled:
            labels, noise_stats = corrupt_labels(
                frame.labels, cfg.label_noise, np.random.default_rng([job.seed, 303, i])
            )
            labels_gt = frame.labels
        info = write_frame(
            job.out_dir, i, timestamp, cfg.camera, frame.rgb, scan,
            labels if cfg.write_labels else None,
            frame.depth if cfg.write_depth else None,
            png_compression=cfg.png_compression,
            labels_gt=labels_gt,
        )
        c3 = time.process_time()
        timings["lidar"] = t1 - t0
        timings["write"] = time.perf_counter() - t1
        timings["cpu_image"] = c1 - c0
        timings["cpu_lidar"] = c2 - c1
        timings["cpu_write"] = c3 - c2
        return info, timings, noise_stats


#: Inside a render worker process only: its renderer, made once by the pool initializer
#: (:func:`_init_worker`). The main process renders inline with its own renderer and never
#: sets this.
_WORKER: dict[str, _FrameRenderer] = {}


def _init_worker(job: _RenderJob) -> None:
    _WORKER["renderer"] = _FrameRenderer(job)


def _render_one(args: tuple[int, float, F64]) -> _FrameResult:
    """Frame ``args[0]`` with this worker process's renderer (see :class:`_FrameRenderer`)."""
    return _WORKER["renderer"](args)


# ---------------------------------------------------------------------------------- simulation
@dataclass
class _WalkedWorld:
    """The world to render (door leaves removed if asked) and the free space walked in it."""

    parts: list[MeshPart]
    world: World
    free: FreeSpace
    walkable: dict[str, Any] | None  # the mesh-derived free space's survey; None for polygons


def simulate_world(
    parts: Sequence[MeshPart],
    out_dir: str | PathLike[str],
    config: SimulatorConfig | None = None,
    seed: int = 0,
    free_polygons: Sequence[F64] | None = None,
    doors_xy: F64 | None = None,
    clutter: bool = True,
    ifc_path: str | PathLike[str] | None = None,
    overwrite: bool = False,
    source: dict[str, Any] | None = None,
    levels: Sequence[Level] | None = None,
    model_name: str = "the world",
) -> SimulationResult:
    """Simulate a sequence in a world given as mesh parts (see :func:`simulate` for IFC input).

    Parameters
    ----------
    parts: the as-built world's elements.
    out_dir: the sequence directory to write (created; refused if it holds a manifest unless
        ``overwrite``).
    config: simulator settings (default :class:`SimulatorConfig`).
    seed: the seed of every random choice.
    free_polygons, doors_xy: free-space polygons (each (K, 2) world xy) and door centres (D, 2);
        None = derive the free space from the meshes: survey ``levels`` (the model's storeys)
        and walk ``config.storey``, ``config.z_floor`` or the level with the largest connected
        walkable area (:func:`bimcap.sim.walkable.choose_free_space`, door leaves' footprints
        are passages).
    clutter: add clutter objects off the walking path.
    ifc_path: the BIM the manifest refers to (the design model).
    source: extra provenance merged into the manifest's ``source`` block.
    levels: candidate storeys for the mesh-derived free space (default: floor heights found in
        the world).
    model_name: named in error messages (the IFC file).
    """
    cfg = config or SimulatorConfig()
    out = Path(out_dir)
    if (out / MANIFEST).exists() and not overwrite:
        raise SimError(f"{out}: already holds a sequence (manifest.json); choose another folder")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    scene = _walked_world(parts, cfg, seed, free_polygons, doors_xy, levels, model_name)
    timings["free_space"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    timestamps = np.arange(cfg.frames) / cfg.fps
    walk: Walk = plan_walk(scene.free, float(timestamps[-1]) + 1e-6,
                           np.random.default_rng([seed, 11]), cfg.walk)
    world_from_cam = walk.poses(timestamps)
    timings["walk"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    placed, world = _with_clutter(scene, walk.path_xy, cfg, seed, clutter)
    textures = TextureBank.bake(cfg.texture_seed)
    timings["world"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    results = _render_frames(_RenderJob(world, textures, cfg, out, seed), timestamps,
                             world_from_cam)
    stage = _sum_worker_timings(results)
    timings["render_wall"] = time.perf_counter() - t0
    # summed over workers: "sum_<stage>" wall seconds inside workers, "cpu_<stage>" CPU seconds
    timings.update({k if k.startswith("cpu_") else f"sum_{k}": v for k, v in stage.items()})

    t0 = time.perf_counter()
    ifc_ref = None
    if ifc_path is not None:
        ifc_ref = os.path.relpath(Path(ifc_path).resolve(), out.resolve())
    manifest_source = _manifest_source(
        cfg, seed, scene, placed, results, clutter=clutter,
        from_polygons=free_polygons is not None, extra=source,
    )
    sequence = _finish_sequence(out, cfg, [info for info, _, _ in results], world_from_cam,
                                ifc_ref, manifest_source)
    timings["manifest"] = time.perf_counter() - t0
    _log.debug("simulation timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
    return SimulationResult(sequence=sequence, world_from_cam=world_from_cam,
                            timestamps=timestamps, clutter=placed,
                            world_triangles=world.n_triangles, timings=timings)


def _walked_world(parts: Sequence[MeshPart], cfg: SimulatorConfig, seed: int,
                  free_polygons: Sequence[F64] | None, doors_xy: F64 | None,
                  levels: Sequence[Level] | None, model_name: str) -> _WalkedWorld:
    """The world of ``parts`` (without door leaves if ``cfg.remove_doors``) and its free space:
    from ``free_polygons`` if given, else surveyed from the meshes."""
    parts = list(parts)
    doors = door_footprints([p for p in parts if p.label == Label.DOOR])
    if cfg.remove_doors:
        parts = [p for p in parts if p.label != Label.DOOR]
    world = World.from_parts(parts, seed=seed)
    z_floor = cfg.z_floor
    walkable: dict[str, Any] | None = None
    if free_polygons is not None:
        if z_floor is None:
            from bimcap.sim.walk import detect_floor_height

            z_floor = detect_floor_height(world)
        free = FreeSpace.from_polygons(world, free_polygons, z_floor, doors_xy,
                                       resolution=cfg.walk.grid_m)
    else:
        choice = choose_free_space(
            world, list(levels or []), cfg.storey, z_floor, doors if cfg.remove_doors else (),
            cfg.walk, WalkableOptions(resolution_m=cfg.walk.grid_m), model_name,
        )
        free = choice.free
        walkable = choice.to_dict()
    return _WalkedWorld(parts=parts, world=world, free=free, walkable=walkable)


def _with_clutter(scene: _WalkedWorld, path_xy: F64, cfg: SimulatorConfig, seed: int,
                  clutter: bool) -> tuple[list[ClutterObject], World]:
    """Clutter placed off the walked path ``path_xy`` (P, 2) and the world that holds it (the
    scene's own world when there is none)."""
    if not (clutter and cfg.clutter_density_per_m2 > 0):
        return [], scene.world
    placed = place_clutter(scene.free, path_xy, np.random.default_rng([seed, 12]),
                           cfg.clutter_density_per_m2)
    return placed, World.from_parts(scene.parts + [c.part for c in placed], seed=seed)


def _render_frames(job: _RenderJob, timestamps: F64, world_from_cam: F64) -> list[_FrameResult]:
    """Render every frame (timestamps (N,) s, poses (N, 7)): inline for one worker, else in
    ``spawn`` processes; results in frame order."""
    cfg = job.config
    tasks = [(i, float(timestamps[i]), world_from_cam[i]) for i in range(cfg.frames)]
    workers = cfg.workers or (os.cpu_count() or 1)
    workers = min(workers, cfg.frames)
    _log.info(f"rendering {cfg.frames} frames ({cfg.camera.width}x{cfg.camera.height}) on "
              f"{max(workers, 1)} process(es)")
    if workers <= 1:
        render = _FrameRenderer(job)
        return [render(t) for t in progress(tasks, desc="render", unit="frame")]
    import multiprocessing as mp

    # spawn, not fork: Open3D's thread pools do not survive a fork
    with ProcessPoolExecutor(workers, mp.get_context("spawn"), _init_worker, (job,)) as pool:
        chunk = max(1, cfg.frames // (4 * workers))
        return list(progress(pool.map(_render_one, tasks, chunksize=chunk), total=len(tasks),
                             desc="render", unit="frame"))


def _sum_worker_timings(results: list[_FrameResult]) -> dict[str, float]:
    """Seconds per stage summed over the frames."""
    stage: dict[str, float] = {}
    for _, r, _ in results:
        for k, v in r.items():
            stage[k] = stage.get(k, 0.0) + v
    return stage


def _manifest_source(cfg: SimulatorConfig, seed: int, scene: _WalkedWorld,
                     placed: list[ClutterObject], results: list[_FrameResult], *, clutter: bool,
                     from_polygons: bool, extra: dict[str, Any] | None) -> dict[str, Any]:
    """The manifest's ``source`` block: generator, seed, settings, clutter, label noise
    measured, the walked floor and free space, then the caller's ``extra`` provenance."""
    return {
        "generator": "bimcap simulate",
        "seed": seed,
        "config": cfg.to_dict(),
        "clutter_enabled": bool(clutter),
        "label_noise_measured": _label_noise_measured(results),
        "clutter": [c.to_dict() for c in placed],
        "z_floor": scene.free.z_floor,
        "storey": scene.free.storey,
        "free_space": "polygons" if from_polygons else "meshes",
        **({"walkable": scene.walkable} if scene.walkable is not None else {}),
        **(extra or {}),
    }


def _label_noise_measured(results: list[_FrameResult]) -> dict[str, Any] | None:
    """The label noise measured over the frames (None without label noise)."""
    noise = [n for _, _, n in results if n]
    if not noise:
        return None
    wrong = np.array([n["wrong_fraction"] for n in noise])
    return {"wrong_fraction_mean": float(wrong.mean()),
            "wrong_fraction_min": float(wrong.min()),
            "wrong_fraction_max": float(wrong.max()),
            "boundary_fraction_mean": float(np.mean([n["boundary_fraction"] for n in noise])),
            "true_labels": "labels_gt/"}


def simulate(
    ifc_path: str | PathLike[str],
    out_dir: str | PathLike[str],
    config: SimulatorConfig | None = None,
    seed: int = 0,
    as_built_ifc: str | PathLike[str] | None = None,
    clutter: bool = True,
    overwrite: bool = False,
    source: dict[str, Any] | None = None,
) -> SequenceDir:
    """Simulate a sequence directory for the building ``ifc_path``.

    The sensors see ``as_built_ifc`` if given (the generator's as-built variant), else the design
    model itself; the manifest's ``ifc`` always names the design model. The walk uses the free
    space of the generator's JSON sidecar when one sits next to the rendered IFC, else free space
    derived from the meshes. ``source`` is extra provenance for the manifest (e.g. the command
    line). Returns the written sequence (validated; ``.root`` is ``out_dir``).
    """
    from bimcap.bim import load_model

    ifc = Path(ifc_path)
    seen = Path(as_built_ifc) if as_built_ifc is not None else ifc
    out = Path(out_dir)
    check_not_input(out / "manifest.json", [ifc, seen])
    if (out / MANIFEST).exists() and not overwrite:
        raise SimError(f"{out}: already holds a sequence (manifest.json); choose another folder")
    model = load_model(seen)
    parts = model_parts(model)
    cfg = config or SimulatorConfig()
    storey_index = 0
    if cfg.storey is not None:
        names = [s.name for s in model.storeys]
        if cfg.storey not in names:
            raise SimError(f"{seen}: no storey named {cfg.storey!r} (storeys: "
                           f"{', '.join(repr(n) for n in names) or 'none'})")
        storey_index = names.index(cfg.storey)
    sidecar = sidecar_free_space(seen, storey_index) or sidecar_free_space(ifc, storey_index)
    polygons = None
    extra: dict[str, Any] = {"as_built_ifc": None if as_built_ifc is None else str(as_built_ifc)}
    if sidecar is not None:
        polygons, z_floor = sidecar
        if cfg.z_floor is None:
            cfg = replace(cfg, z_floor=z_floor)
    else:
        floors, notes = missing_floor_parts(model)
        parts += floors
        if notes:
            extra["synthetic_floors"] = notes
    levels = [Level(s.name, s.elevation_m) for s in model.storeys]
    result = simulate_world(
        parts, out, cfg, seed, polygons, None, clutter, ifc, overwrite,
        source={**extra, **(source or {})}, levels=levels, model_name=str(seen),
    )
    return result.sequence


def with_focal_scale(camera: Camera, factor: float) -> Camera:
    """``camera`` with its focal lengths multiplied by ``factor`` (same image size, principal
    point and distortion): ``factor`` > 1 narrows the field of view (a longer lens)."""
    if not (np.isfinite(factor) and 0.2 <= factor <= 5.0):
        raise SimConfigError(f"must be in [0.2, 5] (got {factor!r})", None, "focal_scale")
    return replace(camera, fx=camera.fx * factor, fy=camera.fy * factor)


def focal_scale_for_hfov(camera: Camera, hfov_deg: float) -> float:
    """The focal scale that gives ``camera`` a horizontal field of view of ``hfov_deg`` degrees
    (pinhole model across the image width: ``hfov = 2·atan(W / (2·fx))``; the lens distortion
    changes the raw image's field of view slightly)."""
    if not (np.isfinite(hfov_deg) and 5.0 <= hfov_deg <= 170.0):
        raise SimConfigError(f"must be in [5, 170] degrees (got {hfov_deg!r})", None, "hfov_deg")
    fx = camera.width / 2.0 / np.tan(np.deg2rad(hfov_deg) / 2.0)
    return float(fx / camera.fx)


def with_frames(config: SimulatorConfig, frames: int) -> SimulatorConfig:
    """``config`` with another frame count (convenience for the CLI and benchmarks)."""
    return replace(config, frames=frames)
