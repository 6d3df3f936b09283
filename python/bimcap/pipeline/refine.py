"""Refine a sequence's initial trajectory against its BIM: the user's path through every stage.

Three steps, kept apart so that experiments can reuse the expensive ones:

1. :func:`prepare` — the BIM reference of the IFC and the front end over the sequence
   (dense depth, labels, matches, semantic samples), both cached on disk.
2. :func:`solve_prepared` — assemble the dense problem (:func:`build_problem`) and solve it with
   Ceres under the configured method, terms and weighting (cheap; run once per ablation).
3. :func:`refine` — 1 + 2, then write the refined TUM trajectory, the solver summary, the
   semantic maps before/after as PLY, metrics against ground truth when there is one, and the
   report. Nothing given by the user is overwritten.
"""

from __future__ import annotations

import copy
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.geometry import Trajectory, read_tum, transform_points, write_tum
from bimcap.io.atomic import atomic_write_json
from bimcap.labels import Label
from bimcap.logs import quieted
from bimcap.methods import CompletionMethod
from bimcap.pipeline.config import (
    ColmapExport,
    GlobalAlignMode,
    LabelSource,
    Method,
    PipelineError,
    RefineConfig,
)
from bimcap.progress import progress

F64 = NDArray[np.float64]


_log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- step 1: prepare
@dataclass
class Prepared:
    """The expensive, cacheable inputs of a solve.

    Attributes
    ----------
    sequence: the sequence (``bimcap.dataset.Sequence``).
    reference: the BIM reference (``bimcap.bim.BimReference``).
    frontend: the front end's observations (``bimcap.frontend.FrontendResult``), in the pinhole
        camera ``sequence.camera.pinhole()``.
    init: the initial trajectory, one pose per frame.
    timings: seconds per step.
    pixel_frontend: the front end before the LiDAR scan's samples were added (None: none were
        added); the semantic maps and their metrics (MME, MPV) use it, so that they compare the
        same points across methods.
    first_frontend: what the schedule solves before the last stage is solved with every scan
        sample (:func:`solve_prepared`): the pixels' samples, and the scan's of the frames no
        feature match links to their neighbours (nothing else would place them). None: the
        ``frontend``.
    scan_samples: how many samples the scan added per class (None: none).
    """

    sequence: Any
    reference: Any
    frontend: Any
    init: Trajectory
    timings: dict[str, float] = field(default_factory=dict)
    pixel_frontend: Any = None
    first_frontend: Any = None
    scan_samples: dict[str, int] | None = None

    @property
    def map_source(self) -> Any:
        """The front end whose samples make the semantic maps (the pixels' own)."""
        return self.frontend if self.pixel_frontend is None else self.pixel_frontend

    def first_stage(self) -> Prepared:
        """This run as the schedule solves it (itself when the scan adds nothing)."""
        if self.first_frontend is None:
            return self
        return replace(self, frontend=self.first_frontend, first_frontend=None)


def make_providers(config: RefineConfig, sequence: Any) -> tuple[Any, Any, Any]:
    """The front end's depth provider, label provider and depth refiner for ``config``."""
    from bimcap.frontend.providers import (
        LidarDepthProvider,
        PlanarDepthRefiner,
        SegmenterLabelProvider,
    )
    from bimcap.frontend.runner import GroundTruthDepthProvider, GroundTruthLabelProvider
    from bimcap.fusion.completion import CompletionOptions

    if config.completion is CompletionMethod.GROUND_TRUTH:
        if not sequence.has_depth:
            raise InputError("completion ground_truth needs a sequence with depth/", sequence.root)
        depth: Any = GroundTruthDepthProvider()
    else:
        onnx_opts = None
        if config.completion.needs_model:
            from bimcap.fusion.onnx_completion import OnnxCompletionOptions

            onnx_opts = OnnxCompletionOptions(model_path=str(config.completion_model))
        method = config.completion
        projection = None
        if config.lidar_nan == "drop":
            from bimcap.fusion import NanPolicy, ProjectionOptions

            projection = ProjectionOptions(nan_policy=NanPolicy.DROP)
        depth = LidarDepthProvider(projection=projection,
                                   completion=CompletionOptions(method=method, onnx=onnx_opts))

    refiner = None
    if config.segmentation is LabelSource.GROUND_TRUTH:
        if not sequence.has_labels:
            raise InputError("segmentation ground_truth needs a sequence with labels/",
                             sequence.root)
        labels: Any = GroundTruthLabelProvider()
    elif config.segmentation is LabelSource.GEOMETRIC:
        from bimcap.segmentation.geometric import GeometricSegmenter

        labels = SegmenterLabelProvider(GeometricSegmenter(geometric_options(config)),
                                        uses_pose=True,
                                        range_noise=True)
    elif config.segmentation is LabelSource.DISK:
        from bimcap.segmentation.disk import DiskLabelProvider, DiskMaskProvider

        d = Path(str(config.labels_dir))
        if not d.is_dir():
            raise InputError("no such label directory", d, "labels_dir")
        has_masks = any(d.glob("*_wall.png"))
        seg: Any = DiskMaskProvider(d, missing_ok=True) if has_masks else DiskLabelProvider(d)
        labels = SegmenterLabelProvider(seg, uses_pose=False)
    else:
        from bimcap.segmentation.onnx_seg import OnnxSegmentationOptions, OnnxSegmentationProvider

        model = OnnxSegmentationOptions(model_path=str(config.segmentation_model))
        seg = OnnxSegmentationProvider(model)
        labels = SegmenterLabelProvider(seg, uses_pose=False)
    if config.completion is not CompletionMethod.GROUND_TRUTH:
        refiner = PlanarDepthRefiner()
    return depth, labels, refiner


def load_initial(sequence: Any, init: str | PathLike[str] | Trajectory | None) -> Trajectory:
    """The initial trajectory: a TUM file, a Trajectory, or the sequence's ``init`` poses; it must
    have one pose per frame with the frame's timestamp (within 1 ms)."""
    if init is None:
        if not sequence.has_trajectory("init"):
            raise InputError("no --init given and the sequence has no poses/init.tum",
                             sequence.root)
        return check_trajectory(sequence, sequence.trajectory("init"),
                                sequence.trajectory_path("init"), "initial")
    if isinstance(init, Trajectory):
        return check_trajectory(sequence, init, None, "initial")
    return check_trajectory(sequence, read_tum(init), init, "initial")


def load_ground_truth(sequence: Any, gt: str | PathLike[str] | None) -> Trajectory | None:
    """The ground truth for the metrics: ``gt`` (a TUM file) or the sequence's ``poses/gt.tum``
    when present (None otherwise); one pose per frame at the frames' timestamps."""
    if gt is not None:
        return check_trajectory(sequence, read_tum(gt), gt, "ground-truth")
    if sequence.has_trajectory("gt"):
        return check_trajectory(sequence, sequence.trajectory("gt"),
                                sequence.trajectory_path("gt"), "ground-truth")
    return None


def check_trajectory(sequence: Any, traj: Trajectory, where: Any, what: str) -> Trajectory:
    """``traj`` if it has one pose per frame of ``sequence`` at the frame's timestamp (within
    1 ms); else an :class:`InputError` naming the file ``where``."""
    ts = sequence.timestamps
    if len(traj) != len(ts):
        raise InputError(f"{len(traj)} {what} poses for {len(ts)} frames of {sequence.root}: "
                         "give one pose per frame", where, "poses")
    worst = float(np.max(np.abs(traj.timestamps - ts))) if len(ts) else 0.0
    if worst > 1e-3:
        raise InputError(f"{what} poses' timestamps differ from the frames' by up to {worst:.4f} s",
                         where, "timestamps")
    return traj


def prepare(
    sequence: str | PathLike[str] | Any,
    ifc: str | PathLike[str] | None,
    init: str | PathLike[str] | Trajectory | None,
    config: RefineConfig,
    work_dir: str | PathLike[str],
    quiet: bool | None = None,
) -> Prepared:
    """Step 1: read the sequence, build (or load) the BIM reference, run (or load) the front end.

    Parameters
    ----------
    sequence: a sequence directory or an already-read ``Sequence``.
    ifc: the BIM; None uses the sequence manifest's ``ifc``.
    init: initial poses (TUM path or Trajectory); None uses the sequence's ``poses/init.tum``.
    config: the run's settings (front-end sources, window).
    work_dir: where the caches live (``bim/``, ``cache/``).
    quiet: deprecated (:func:`bimcap.logs.quieted`): the steps are logged at INFO on this
        module's logger, the front end's progress bar follows it (:mod:`bimcap.progress`).
    """
    with quieted(quiet):
        return _prepare(sequence, ifc, init, config, work_dir)


def _prepare(sequence: str | PathLike[str] | Any, ifc: str | PathLike[str] | None,
             init: str | PathLike[str] | Trajectory | None, config: RefineConfig,
             work_dir: str | PathLike[str]) -> Prepared:
    """:func:`prepare`."""
    from bimcap.bim.cache import ReferenceSource, reference_for
    from bimcap.dataset import read_sequence
    from bimcap.features.pair_chain import PairChainOptions
    from bimcap.features.tracks import MatchFilterOptions
    from bimcap.frontend.runner import FrontendConfig, run_frontend
    from bimcap.frontend.semantic_map import SampleSource, SemanticSamplingOptions

    timings: dict[str, float] = {}
    seq = read_sequence(sequence) if isinstance(sequence, (str, PathLike)) else sequence
    ifc_path = Path(ifc) if ifc is not None else seq.ifc_path
    if ifc_path is None:
        raise InputError("no --ifc given and the sequence manifest names none",
                         seq.manifest_path, "ifc")
    validate_settings(config)
    traj = load_initial(seq, init)
    work = Path(work_dir)

    t0 = time.perf_counter()
    _log.info(f"BIM reference of {ifc_path}")
    ref, source = reference_for(ifc_path, work / "bim", config.max_lost_fraction,
                                config.cache_dir)
    if source is ReferenceSource.SHARED:
        _log.info("BIM reference from the shared cache (bimcap.io.cache)")
    timings["bim"] = time.perf_counter() - t0
    check_map_storey(config, ref.storeys, ifc_path)

    t0 = time.perf_counter()
    executor = executor_options(config)
    where = "" if not executor.is_dask else (
        f", on the Dask cluster at {executor.scheduler}" if executor.scheduler
        else ", on a Dask LocalCluster")
    _log.info(f"front end over {len(seq.frames)} frames (depth {config.completion.value}, "
              f"labels {config.segmentation.value}{where})")
    depth, labels, refiner = make_providers(config, seq)
    fe_seq = seq
    if executor.is_dask and not seq.root.is_absolute():  # Dask workers have another cwd
        from dataclasses import replace

        fe_seq = replace(seq, root=seq.root.resolve())
    fe = run_frontend(
        fe_seq,
        FrontendConfig(window=config.window, sift=sift_options(config),
                       match=match_options(config),
                       filters=MatchFilterOptions(max_initial_distance_m=config.max_match_distance),
                       sampling=SemanticSamplingOptions(source=SampleSource(config.samples)),
                       # FACaP keeps the peers' front end: every verified pair.
                       pair_chain=None if config.method is Method.FACAP else PairChainOptions()),
        traj, depth, labels,
        cache_dir=work / "cache", workers=config.workers,
        progress=_log.isEnabledFor(logging.INFO),
        depth_refiner=refiner, executor=executor,
    )
    timings["frontend"] = time.perf_counter() - t0
    if config.effective_lidar_scan and len(fe.scan_frame):
        from bimcap.frontend.scan_samples import frames_without_matches, with_scan_samples

        with_scan, stats = with_scan_samples(fe, traj.poses)
        unlinked = frames_without_matches(fe)
        first, _ = with_scan_samples(fe, traj.poses, frames=unlinked)
        _log.info(f"LiDAR scan samples outside the camera's view: {stats.wall} wall, "
                  f"{stats.floor} floor, {stats.ceiling} ceiling")
        return Prepared(seq, ref, with_scan, traj, timings, pixel_frontend=fe,
                        first_frontend=first,
                        scan_samples={**stats.to_dict(), "frames_without_matches":
                                      [int(i) for i in unlinked]})
    return Prepared(seq, ref, fe, traj, timings)


# ------------------------------------------------------------------------ step 2: solve
@dataclass
class ProblemStats:
    """What :func:`build_problem` kept and dropped.

    ``floor_without_plane`` / ``ceiling_without_plane`` count every sample dropped for want of
    a plane; ``floor_rejected_height`` / ``ceiling_rejected_height`` the part of them that had a
    plane over their xy but none within the height tolerance (``bimcap.bim.plane_choice``).
    ``plane_choice`` is the choice's summary (per kind counts, frames whose up came from their
    own floor or ceiling, frame offsets).
    """

    frames: int
    matches: int
    floor: int
    ceiling: int
    wall: int
    column: int
    floor_without_plane: int
    ceiling_without_plane: int
    floor_rejected_height: int = 0
    ceiling_rejected_height: int = 0
    plane_choice: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def brief(self) -> dict[str, int]:
        """The counts alone (for log lines)."""
        return {k: v for k, v in self.__dict__.items() if isinstance(v, int)}


def filter_matches_by_distance(arrays: dict[str, Any], poses: F64, camera: Any,
                               max_distance: float) -> int:
    """The peers' filter, in place: drop matches whose two back-projected points lie further
    apart than ``max_distance`` metres in the world under ``poses``. Returns how many went."""
    frames = np.asarray(arrays.get("match_frames", np.zeros((0, 2), np.int32)))
    if len(frames) == 0:
        return 0
    uv, depth = np.asarray(arrays["match_uv"]), np.asarray(arrays["match_depth"])
    p_a = transform_points(poses[frames[:, 0]], camera.backproject(uv[:, :2], depth[:, 0], False))
    p_b = transform_points(poses[frames[:, 1]], camera.backproject(uv[:, 2:], depth[:, 1], False))
    keep = np.linalg.norm(p_a - p_b, axis=1) <= max_distance
    for name in ("match_frames", "match_uv", "match_depth"):
        arrays[name] = np.asarray(arrays[name])[keep]
    return int((~keep).sum())


def build_problem(prepared: Prepared, init_poses: F64 | None = None,
                  max_match_distance: float | None = None,
                  segment_normal: F64 | None = None,
                  plane_options: Any | None = None,
                  planes_chosen: Any | None = None) -> tuple[Any, ProblemStats]:
    """Assemble the solver problem from the front end, the BIM reference and the initial poses.

    Floor (ceiling) samples are given the BIM floor (ceiling) plane they lie on at the initial
    poses, verified with their own height (:func:`bimcap.bim.plane_choice.choose_planes`: per
    frame, the up direction from the frame's own floor, the vertical offset most samples agree
    on, then per sample the nearest plane over its xy within ``plane_options.tolerance_m``);
    samples over no plane or too far from every plane are dropped and counted. Wall and column
    samples are associated with floor-plan segments inside the solver, which re-associates them
    as the poses move; with ``segment_normal`` ((S, 2), from :func:`segment_free_normals`) a
    point is only associated with faces its camera is in front of (the far face of a wall, one
    wall thickness away, is otherwise a local minimum); without it, with the nearest face, as
    the peers' FACaP did. ``planes_chosen`` (from :func:`choose_sample_planes` at ``init_poses``)
    skips the choice.
    """
    from bimcap.bim.plane_choice import Rejection
    from bimcap.optimize import Problem

    fe, ref = prepared.frontend, prepared.reference
    poses = prepared.init.poses if init_poses is None else np.asarray(init_poses, np.float64)
    arrays = dict(fe.to_problem_arrays())
    cam = prepared.sequence.camera.pinhole()
    n = len(poses)
    if max_match_distance is not None:
        filter_matches_by_distance(arrays, poses, cam, max_match_distance)
    kinds = {"floor": Label.FLOOR, "ceiling": Label.CEILING}
    samples = _plane_samples(arrays)
    chosen = planes_chosen or choose_sample_planes(prepared, poses, plane_options, arrays)
    dropped, rejected = {}, {}
    for name, kind in kinds.items():
        frames, p_cam = samples[kind]
        idx = chosen.choices[kind].plane
        keep = idx >= 0
        dropped[name] = int((~keep).sum())
        rejected[name] = int((chosen.choices[kind].rejection == Rejection.HEIGHT).sum())
        arrays[f"{name}_frame"] = frames[keep]
        arrays[f"{name}_p_in_cam"] = p_cam[keep]
        arrays[f"{name}_plane"] = idx[keep].astype(np.int32)
    if segment_normal is not None:
        arrays["segment_normal"] = segment_normal
    arrays.update(
        poses=poses,
        timestamps=prepared.init.timestamps,
        pose_fixed=np.zeros(n, np.int32),
        cameras=cam.intrinsics[None, :],
        frame_camera=np.zeros(n, np.int32),
        planes=ref.planes,
        segments=ref.segments,
        segment_class=ref.segment_class,
        segment_z=ref.segment_z,
    )
    problem = Problem.from_arrays(arrays)
    stats = ProblemStats(
        frames=n,
        matches=len(arrays.get("match_frames", ())),
        floor=len(arrays["floor_frame"]),
        ceiling=len(arrays["ceiling_frame"]),
        wall=len(arrays.get("wall_frame", ())),
        column=len(arrays.get("column_frame", ())),
        floor_without_plane=dropped["floor"],
        ceiling_without_plane=dropped["ceiling"],
        floor_rejected_height=rejected["floor"],
        ceiling_rejected_height=rejected["ceiling"],
        plane_choice=chosen.to_dict(),
    )
    return problem, stats


def _plane_samples(arrays: dict[str, Any], evidence: bool = False
                   ) -> dict[Label, tuple[NDArray[np.int32], F64]]:
    """The floor and ceiling samples (and, with ``evidence``, the wall and column samples)."""
    names = [("floor", Label.FLOOR), ("ceiling", Label.CEILING)]
    if evidence:
        names += [("wall", Label.WALL), ("column", Label.COLUMN)]
    return {
        kind: (np.asarray(arrays.get(f"{name}_frame", np.zeros(0, np.int32)), np.int32),
               np.asarray(arrays.get(f"{name}_p_in_cam", np.zeros((0, 3))), np.float64))
        for name, kind in names
    }


def choose_sample_planes(prepared: Prepared, poses: F64, plane_options: Any | None = None,
                         arrays: dict[str, Any] | None = None) -> Any:
    """The BIM plane of every floor / ceiling sample of the front end at ``poses``
    (:func:`bimcap.bim.plane_choice.choose_planes`); a ``PlaneChoiceResult``."""
    from bimcap.bim.plane_choice import PlaneChoiceOptions, choose_planes

    arrays = arrays if arrays is not None else prepared.frontend.to_problem_arrays()
    ref = prepared.reference
    return choose_planes(ref.plane_info, ref.planes, _plane_samples(arrays, evidence=True), poses,
                         plane_options or PlaneChoiceOptions())


def changed_planes(a: Any, b: Any, planes: F64) -> tuple[int, int]:
    """(samples whose plane differs, samples) between two ``PlaneChoiceResult``; a sample that
    moves to another piece of the same plane (a neighbouring room's floor at the same height,
    ``planes`` (Q, 4) within 1 mm) has not changed."""
    changed = total = 0
    for kind, ca in a.choices.items():
        pa, pb = ca.plane, b.choices[kind].plane
        both = (pa >= 0) & (pb >= 0)
        same = (pa < 0) & (pb < 0)
        same[both] = np.all(np.abs(planes[pa[both]] - planes[pb[both]]) < 1e-3, axis=1)
        changed += int((~same).sum())
        total += len(pa)
    return changed, total


def merge_plane_choices(kept: Any, fresh: Any, frames: list[int],
                        samples: dict[Label, tuple[NDArray[np.int32], F64]]) -> Any:
    """``kept`` (a ``PlaneChoiceResult``) with the samples and per-frame model of ``frames``
    taken from ``fresh`` (another choice over the same samples, e.g. at other poses).

    Parameters
    ----------
    kept, fresh: ``PlaneChoiceResult`` of the same samples (N frames).
    frames: the frames whose choice comes from ``fresh``.
    samples: per kind ``(frame (M,), p_in_cam (M, 3))``, aligned with the choices
        (:func:`_plane_samples`).
    """
    from bimcap.bim.plane_choice import PlaneChoice, PlaneChoiceResult

    pick = np.asarray(sorted(frames), np.int64)
    choices = {}
    for kind, old in kept.choices.items():
        new = fresh.choices[kind]
        take = np.isin(samples[kind][0], pick)
        choices[kind] = PlaneChoice(plane=np.where(take, new.plane, old.plane),
                                    rejection=np.where(take, new.rejection, old.rejection),
                                    height_error_m=np.where(take, new.height_error_m,
                                                            old.height_error_m))
    offset, tilt = kept.frame_offset_m.copy(), kept.frame_tilt.copy()
    measured = kept.tilt_measured.copy()
    offset[pick], tilt[pick] = fresh.frame_offset_m[pick], fresh.frame_tilt[pick]
    measured[pick] = fresh.tilt_measured[pick]
    return PlaneChoiceResult(choices=choices, frame_offset_m=offset, frame_tilt=tilt,
                             tilt_measured=measured)


def plane_checks(problem: Any, poses: F64, limit_m: float = 0.05) -> list[Any]:
    """The F and Ce terms' residual checks at ``poses``
    (:func:`bimcap.bim.plane_choice.plane_residual_check`), one per term with samples."""
    from bimcap.bim.plane_choice import plane_residual_check

    a = problem.arrays()
    out = []
    for term, name in (("F", "floor"), ("Ce", "ceiling")):
        if len(a.get(f"{name}_frame", ())):
            out.append(plane_residual_check(term, a[f"{name}_frame"], a[f"{name}_p_in_cam"],
                                            a[f"{name}_plane"], a["planes"], poses, limit_m))
    return out


def _flat_solver_table(table: dict[str, Any]) -> dict[str, str]:
    """The ``[solver]`` table as flat option text: ``{"wall": {"sigma": 0.03}}`` →
    ``{"wall.sigma": "0.03"}``; enum names upper-cased, booleans as 0/1."""
    flat: dict[str, str] = {}
    for key, value in table.items():
        items = value.items() if isinstance(value, dict) else [(None, value)]
        for sub, v in items:
            name = key if sub is None else f"{key}.{sub}"
            if isinstance(v, str):
                flat[name] = v.upper()
            else:
                flat[name] = str(int(v) if isinstance(v, bool) else v)
    return flat


def solver_options(config: RefineConfig) -> Any:
    """``bimcap.optimize.SolverOptions`` of a run, in this order: the preset named by the
    weighting (``robust`` or ``paper``, :class:`bimcap.optimize.Preset`: every default is
    there), the config's ``geometric_mode`` and ``loss`` (the loss of each of the paper's terms)
    when given, the ``[solver]`` table, then the method: FACaP's point error and a floor plane
    fitted to the scan. Only the configured terms stay on."""
    from bimcap.optimize import SolverOptions
    from bimcap.optimize.options import GeometricMode, PlaneMode, terms

    flat = SolverOptions.preset(config.effective_weighting).to_flat()
    if config.geometric_mode is not None:
        flat["geometric_mode"] = config.geometric_mode.upper()
    if config.loss is not None:
        flat.update({f"{t.key}.loss": config.loss.upper() for t in terms() if t.paper_term})
    flat.update(_flat_solver_table(config.solver))
    opts = SolverOptions.from_flat(flat)
    if config.method is Method.FACAP:
        opts.plane_mode = PlaneMode.FACAP
        opts.geometric_mode = GeometricMode.POINT
    opts = opts.with_terms(config.effective_terms)
    opts.check()
    return opts


@dataclass
class SolveOutcome:
    """The refined trajectory and what the solver reported (one entry per stage)."""

    refined: Trajectory
    summaries: list[Any]
    problem_stats: ProblemStats
    coarse: dict[str, Any] | None
    seconds: float
    plane_checks: list[Any] = field(default_factory=list)
    plane_rounds: list[dict[str, int]] = field(default_factory=list)  # changed, samples, resolved
    observability: Any = None
    repair: dict[str, Any] | None = None
    global_align: dict[str, Any] | None = None
    diverged_frames: list[int] = field(default_factory=list)
    #: the matches' reprojection errors at the initial and the refined poses
    #: (:func:`reprojection_stats`: ``{"before": {...}, "after": {...}}``), None without matches
    reprojection: dict[str, Any] | None = None
    #: where the refined trajectory breaks from the input's relative motion and whether the
    #: matches support it (``registration.odometry.MotionCheck``); None when not checked
    motion_check: Any = None

    @property
    def summary(self) -> Any:
        return self.summaries[-1]

    @property
    def plane_resolves(self) -> int:
        """How often the last stage was solved again because samples changed plane."""
        return max(0, sum(1 for r in self.plane_rounds if r.get("resolved")))

    @property
    def plane_check_failed(self) -> list[str]:
        """The plane terms (``"F"``, ``"Ce"``) whose samples sit far from their planes."""
        return [c.term for c in self.plane_checks if c.failed]

    def to_dict(self) -> dict[str, Any]:
        return {
            "summaries": [json.loads(s.to_json()) for s in self.summaries],
            "problem": self.problem_stats.to_dict(),
            "coarse": self.coarse,
            "seconds": self.seconds,
            "plane_check": {
                "failed": self.plane_check_failed,
                "terms": {c.term: c.to_dict() for c in self.plane_checks},
                "rechoice_rounds": self.plane_rounds,
            },
            "observability": None if self.observability is None else self.observability.to_dict(),
            "repair": self.repair,
            "global_align": self.global_align,
            "diverged_frames": self.diverged_frames,
            "reprojection": self.reprojection,
            "motion_check": None if self.motion_check is None else self.motion_check.to_dict(),
        }


#: A match whose reprojection error is below this counts as an inlier (pixels;
#: :func:`reprojection_stats`).
REPROJECTION_INLIER_PX = 3.0


def reprojection_stats(arrays: dict[str, Any], poses: F64,
                       inlier_px: float = REPROJECTION_INLIER_PX) -> dict[str, Any] | None:
    """The G term's matches under ``poses`` (N, 7), in pixels whatever the G residual is: each
    match's reprojection error both ways (:func:`bimcap.registration.odometry.reprojection_errors`),
    summarised as ``{"n", "behind", "median_px", "p90_px", "rms_px", "inlier_px",
    "inlier_share"}`` (``behind``: observations whose point falls behind the other camera,
    outliers left out of the rms); None without matches with depth."""
    from bimcap.registration.odometry import reprojection_errors

    if "match_frames" not in arrays or not len(arrays["match_frames"]):
        return None
    _, _, err = reprojection_errors(poses, arrays["match_frames"], arrays["match_uv"],
                                    arrays["match_depth"], arrays["cameras"][0])
    if not len(err):
        return None
    front = err < 1e6
    rms = float(np.sqrt(np.mean(err[front] ** 2))) if front.any() else float("nan")
    return {"n": len(err), "behind": int((~front).sum()), "median_px": float(np.median(err)),
            "p90_px": float(np.percentile(err, 90)), "rms_px": rms,
            "inlier_px": inlier_px, "inlier_share": float(np.mean(err < inlier_px))}


#: How far outside the BIM's bounding box a refined camera may lie before its frame counts as
#: diverged (:func:`diverged_frames`), metres.
DIVERGED_MARGIN_M = 10.0


def diverged_frames(poses: F64, reference: Any, margin_m: float = DIVERGED_MARGIN_M
                    ) -> list[int]:
    """Frames whose refined camera is not finite or lies more than ``margin_m`` outside the
    bounding box of the BIM's floor plan (x, y) and its segments' heights (z): a solve that
    diverged there (an unconstrained frame under plain L2, say) gives no usable pose."""
    p = np.asarray(poses, np.float64)[:, :3]
    seg = np.asarray(reference.segments, np.float64).reshape(-1, 4)
    segz = np.asarray(reference.segment_z, np.float64).reshape(-1, 2)
    bad = ~np.isfinite(np.asarray(poses, np.float64)).all(axis=1)
    if len(seg):
        lo = np.array([seg[:, [0, 2]].min(), seg[:, [1, 3]].min(), segz.min()]) - margin_m
        hi = np.array([seg[:, [0, 2]].max(), seg[:, [1, 3]].max(), segz.max()]) + margin_m
        with np.errstate(invalid="ignore"):
            bad |= ((p < lo) | (p > hi)).any(axis=1)
    return [int(i) for i in np.flatnonzero(bad)]


def segment_free_normals(reference: Any) -> F64:
    """(S, 2) free-side unit normal of each floor-plan segment of a ``BimReference``, (0, 0)
    where undecided (``registration.plan_maps.free_normals_by_storey``)."""
    from bimcap.registration.plan_maps import free_normals_by_storey

    return free_normals_by_storey(reference.segments, reference.segment_class,
                                  reference.segment_z)


def schedule_for(config: RefineConfig) -> Any:
    """The :class:`bimcap.registration.Schedule` a config asks for: [coarse →] [BIM terms with
    wide losses (``staged``) →] all terms, the first solver stage preceded by rotation-only and
    translation-only stages with ``rotation_first``."""
    from bimcap.registration import Schedule

    return Schedule.default(coarse=config.effective_coarse, rotation_first=config.rotation_first,
                            staged=config.staged)


def stage_options(base: Any, stage: Any, config: RefineConfig) -> Any | None:
    """Solver options of one schedule stage: the config's terms that the stage allows, its pose
    block, its loss-scale factor and iteration cap; None when no configured term is allowed."""
    from bimcap.optimize.options import RefineMode, terms

    names = [t for t in config.effective_terms.split("+") if t in stage.terms]
    if not names:
        return None
    opts = base.with_terms("+".join(names))  # a copy
    if stage.pose_block is not RefineMode.FULL:
        opts.refine_mode = stage.pose_block
    for t in terms():
        if t.paper_term:
            opts.terms[t.key].loss_scale *= stage.loss_scale_factor
    if stage.max_iterations is not None:
        opts.max_iterations = stage.max_iterations
    opts.check()
    return opts


def _trim_off_face(prepared: Prepared, run: _StageRun) -> NDArray[np.bool_]:
    """The front end's wall samples to keep at the scan's noise scale: the camera pixels'
    samples off their face's in the same frame (:mod:`bimcap.pipeline.face_trim`: frames and
    fittings in front of the wall) are dropped, at ``run``'s refined poses and association; the
    scan's samples are all kept."""
    from bimcap.pipeline.face_trim import off_face_samples

    arrays = run.problem.arrays()
    frame = np.asarray(arrays["wall_frame"])
    n = len(run.result.poses)
    # with_scan_samples keeps each frame's pixel samples first, then its scan's
    pixels = np.bincount(np.asarray(prepared.pixel_frontend.wall_frame, np.int64), minlength=n)
    start = np.searchsorted(frame, np.arange(n))
    rank = np.arange(len(frame)) - start[frame]
    normals = np.asarray(arrays.get("segment_normal", np.zeros((0, 2))), np.float64)
    if len(normals) != len(arrays["segments"]):  # none given: every face seen from both sides
        normals = np.zeros((len(arrays["segments"]), 2))
    trim = off_face_samples(frame, arrays["wall_p_in_cam"], run.result.wall_segment,
                            run.result.poses, arrays["segments"], normals,
                            rank < pixels[frame])
    _log.info(f"{trim.dropped} of the camera's wall samples off their face by more than "
              f"{trim.gate_m * 100:.1f} cm (robust spread {trim.spread_m * 100:.2f} cm): "
              f"dropped at the scan's noise scale")
    keep: NDArray[np.bool_] = trim.keep
    return keep


def scan_stage_options(opts: Any, config: RefineConfig) -> Any:
    """The options of the last solve with the LiDAR scan's samples: ``opts`` with the BIM terms'
    noise scale set to ``config.scan_sigma_m`` (unchanged when None)."""
    if config.scan_sigma_m is None:
        return opts
    out = copy.deepcopy(opts)
    for key in ("wall", "column", "floor", "ceiling"):
        out.terms[key].sigma = float(config.scan_sigma_m)
    out.check()
    return out


#: G's pixel noise scale (the preset's ``pixel_sigma``) is for keypoint depths from a LiDAR of
#: about this range noise (metres); :func:`pixel_sigma_for_noise`.
PIXEL_SIGMA_NOISE_REFERENCE_M = 0.03


def sequence_range_noise(sequence: Any, max_frames: int = 30) -> float | None:
    """The range noise σ (metres) of a sequence's LiDAR: the median of
    :func:`bimcap.segmentation.geometric.scan_range_noise` over up to ``max_frames`` evenly
    spaced frames with a scan; None without scans (or none measurable)."""
    from bimcap.segmentation.geometric import scan_range_noise

    frames = getattr(sequence, "frames", None)
    if frames is None or not hasattr(sequence, "load_lidar"):
        return None
    with_scan = [i for i, f in enumerate(frames) if getattr(f, "lidar", None) is not None]
    if not with_scan:
        return None
    pick = np.unique(np.linspace(0, len(with_scan) - 1, min(max_frames, len(with_scan)))
                     .astype(np.int64))
    sigmas = [scan_range_noise(np.asarray(sequence.load_lidar(with_scan[k]))) for k in pick]
    found = [x for x in sigmas if x is not None and np.isfinite(x)]
    return float(np.median(found)) if found else None


def pixel_sigma_for_noise(opts: Any, config: RefineConfig, range_noise_m: float | None,
                          adapt_above: float = 1.5, max_scale: float = 4.0) -> Any:
    """``opts`` with G's pixel noise scale widened for a noisy LiDAR.

    G's reprojection residual takes each keypoint's depth (from the completed LiDAR depth) as
    exact; its pixel scale covers the keypoint's position and the depth error of a LiDAR of
    about :data:`PIXEL_SIGMA_NOISE_REFERENCE_M`. A depth error δz moves the reprojection by
    f·b·δz/z², in proportion to the range noise, so above ``adapt_above`` × the reference the
    scale grows by σ / reference (at most ``max_scale`` times): at 8 cm, 2 → 5.3 px. Without
    it, on gen-small-s3 hard (8 cm) the frames 56-59 that only their matches link to the walk
    were placed by their keypoints' depth errors (fixed point 1.79 cm / 0.407°, 1.29 / 0.332
    with it). Unchanged when the ``[solver]`` table sets ``pixel_sigma``, when σ is unknown,
    and at the standard worlds' 3 cm."""
    from bimcap.geometry.noise import noise_factor

    k = noise_factor(range_noise_m, PIXEL_SIGMA_NOISE_REFERENCE_M, adapt_above)
    if k is None or "pixel_sigma" in config.solver:
        return opts
    out = copy.deepcopy(opts)
    out.pixel_sigma = opts.pixel_sigma * min(max_scale, k)
    out.check()
    return out


def solve_prepared(prepared: Prepared, config: RefineConfig, quiet: bool | None = None,
                   max_plane_rounds: int = 2, plane_change_tolerance: float = 0.005,
                   plane_check_limit_m: float = 0.05) -> SolveOutcome:
    """Step 2: build the problem and solve it, stage by stage (:func:`schedule_for`).

    With the LiDAR scan's samples, the global alignment, the schedule and its stages see the
    pixels' samples and the scan's of the frames that no match links to their neighbours
    (``prepared.first_frontend``); the last stage is then solved again with every scan sample:
    360° of walls sharpen the optimum but also add local minima one wall or door spacing away,
    which a start 1.4 m off (Exp. 1) falls into (the Duplex: 84 cm where the pixels alone
    converge), while a frame that nothing else places must have its scan from the start (one
    AC20-FZK-Haus frame left at 23° by the pixels alone ends outside the scan's basin).

    Floor and ceiling samples get their planes at the poses each stage starts from. After the
    last stage (BIMCaP) the planes are chosen again at the refined poses, now trusted
    (``PlaneChoiceOptions.frame_model`` off: no per-frame tilt or offset); when more than
    ``plane_change_tolerance`` of the samples change plane, the last stage runs again, at most
    ``max_plane_rounds`` times. Then every plane term is checked
    (:func:`bimcap.bim.plane_choice.plane_residual_check`): a median |residual| above
    ``plane_check_limit_m`` is reported in the outcome and logged, not hidden by the robust loss.

    Every stage is logged at INFO on this module's logger (a failed plane check, an ambiguous
    global alignment, a diverged solve at WARNING); ``quiet`` is deprecated
    (:func:`bimcap.logs.quieted`).
    """
    with quieted(quiet):
        return _solve_prepared(prepared, config, max_plane_rounds, plane_change_tolerance,
                               plane_check_limit_m)


def _solve_prepared(prepared: Prepared, config: RefineConfig, max_plane_rounds: int,
                    plane_change_tolerance: float, plane_check_limit_m: float) -> SolveOutcome:
    """:func:`solve_prepared`."""
    from bimcap.optimize.observability import bim_observability

    t0 = time.perf_counter()
    poses = prepared.init.poses.copy()
    base = solver_options(config)
    noise = sequence_range_noise(getattr(prepared, "sequence", None))
    widened = pixel_sigma_for_noise(base, config, noise)
    if widened is not base:
        _log.info(f"LiDAR range noise {noise * 100:.1f} cm: G's pixel noise scale "
                  f"{base.pixel_sigma:g} → {widened.pixel_sigma:.2g} px")
        base = widened
    facap = config.method is Method.FACAP
    # BIMCaP associates with visible faces only; FACaP with the nearest face, as the peers did.
    solver = _StageSolver(prepared=prepared, config=config,
                          max_dist=config.effective_solve_match_distance,
                          normals=None if facap else segment_free_normals(prepared.reference))
    pixels = prepared.first_stage()
    first = solver if pixels is prepared else replace(solver, prepared=pixels)
    poses, global_info = _global_align(pixels, poses, config)
    run, poses, coarse_info = _run_schedule(first, base, poses)
    if first is not solver:
        _log.info(f"adding the LiDAR scan's samples: solving stage {run.stage.name} again")
        run = solver.run(run.stage, run.options, poses, choose_sample_planes(prepared, poses))
        poses = run.result.poses
        tight = scan_stage_options(run.options, config)
        if tight is not run.options:
            _log.info(f"and once more at the scan's noise scale ({config.scan_sigma_m:g} m)")
            solver.wall_keep = _trim_off_face(prepared, run)
            solver.held = _unanchored(run, poses)
            if solver.held:
                _log.info(f"holding frame(s) {sorted(solver.held)[:10]} where they are: "
                          f"no match links them and the BIM does not observe all their directions")
            run = solver.run(run.stage, tight, poses, choose_sample_planes(prepared, poses))
            poses = run.result.poses
    rounds: list[dict[str, int]] = []
    checks: list[Any] = []
    repair = None
    if not facap:
        run, poses, rounds = _rechoose_planes(solver, run, poses, max_plane_rounds,
                                              plane_change_tolerance)
        run, poses, repair = _repair_run(solver, run, poses)
        run, poses, repair["odometry"] = _odometry_repair_run(solver, run, poses)
        run, poses, repair["block"] = _block_repair_run(solver, run, poses, max_plane_rounds,
                                                        plane_change_tolerance)
        run, poses, repair["unlinked"] = _unlinked_block_run(solver, run, poses,
                                                             max_plane_rounds,
                                                             plane_change_tolerance)
        run, poses, repair["window_shift"] = _window_shift_run(solver, run, poses,
                                                               max_plane_rounds,
                                                               plane_change_tolerance)
        checks = _logged_plane_checks(run.problem, poses, plane_check_limit_m)
    result = run.result
    arrays = run.problem.arrays()
    observability = bim_observability(arrays, poses, run.options,
                                      result.wall_segment, result.column_segment,
                                      planes=result.planes)
    _log.info(observability.summary_line())
    before, after = (reprojection_stats(arrays, p) for p in (prepared.init.poses, poses))
    reprojection = None if before is None or after is None else {"before": before,
                                                                  "after": after}
    motion = _logged_motion_check(arrays, poses, prepared.init.poses)
    diverged = diverged_frames(poses, prepared.reference)
    if diverged:
        _log.warning(f"the {config.method.value} solve diverged: frame(s) {diverged[:10]} "
                     f"lie more than {DIVERGED_MARGIN_M:g} m outside the building")
    return SolveOutcome(
        refined=Trajectory(prepared.init.timestamps, poses),
        summaries=solver.summaries,
        problem_stats=run.stats,
        coarse=coarse_info,
        seconds=time.perf_counter() - t0,
        plane_checks=checks,
        plane_rounds=rounds,
        observability=observability,
        repair=repair,
        global_align=global_info,
        diverged_frames=diverged,
        reprojection=reprojection,
        motion_check=motion,
    )


def _unanchored(run: _StageRun, poses: F64) -> frozenset[int]:
    """The frames of ``run`` at ``poses`` that no match links to another frame and whose
    directions the BIM terms do not all observe
    (:func:`bimcap.optimize.observability.unanchored_frames`, single-frame components only: an
    island of matched frames pools its samples, and the stronger BIM terms pull it nearer the
    truth — gen-small-s3 hard from the ground truth, where frames 56–59 are such an island:
    3.05 cm / 0.66° solved, 5.78 cm / 1.35° held).

    The scan's noise-scale solve makes the BIM terms several times stronger than G and the pose
    prior, to sharpen frames that are already placed. Such a frame has directions that only its
    own samples decide there; at the stronger weight their noise and wrong labels pull it (on
    gen-small-s3 hard Exp 3: frame 55, one wall from close range, 8° → 16°), so that solve
    and the ones after it hold it where the previous solve put it."""
    from bimcap.optimize.observability import bim_observability, unanchored_frames

    arrays = run.problem.arrays()
    obs = bim_observability(arrays, poses, run.options, run.result.wall_segment,
                            run.result.column_segment, planes=run.result.planes)
    pairs = arrays.get("match_frames")
    if (pairs is None or not len(pairs)) and len(arrays.get("track_obs_frame", ())):
        # LANDMARK: frames that see the same track point are linked.
        point, frame = (np.asarray(arrays[k], np.int64)
                        for k in ("track_obs_point", "track_obs_frame"))
        order = np.lexsort((frame, point))
        same = point[order][1:] == point[order][:-1]
        pairs = np.stack([frame[order][:-1][same], frame[order][1:][same]], axis=1)
    linked = set() if pairs is None else set(np.asarray(pairs, np.int64).ravel().tolist())
    return frozenset(i for i in unanchored_frames(pairs, obs) if i not in linked)


@dataclass
class _StageRun:
    """One solved stage of :func:`solve_prepared`.

    Attributes
    ----------
    stage: the schedule stage (``bimcap.registration.Stage``).
    options: its solver options.
    chosen: the floor / ceiling planes chosen for the samples (:func:`choose_sample_planes`).
    problem: the problem it solved. stats: that problem's :class:`ProblemStats`.
    result: the solver's result (after a repair: the repaired solve's).
    """

    stage: Any
    options: Any
    chosen: Any
    problem: Any
    stats: ProblemStats
    result: Any


@dataclass
class _StageSolver:
    """Builds and solves the stages of one :func:`solve_prepared` call; keeps their summaries.

    Attributes
    ----------
    max_dist: the solve-time filter on matches (m, :func:`filter_matches_by_distance`), or None.
    normals: (S, 2) free-side normals of the segments (visible-face association), or None.
    summaries: every solve's summary, in order.
    held: frames held fixed in every problem built.
    wall_keep: (W,) the front end's wall samples kept in every problem built (None: all;
        :func:`_trim_off_face`).
    """

    prepared: Prepared
    config: RefineConfig
    max_dist: float | None
    normals: F64 | None
    summaries: list[Any] = field(default_factory=list)
    held: frozenset[int] = frozenset()
    wall_keep: NDArray[np.bool_] | None = None

    def run(self, stage: Any, opts: Any, poses: F64, chosen: Any) -> _StageRun:
        """Build the problem at ``poses`` with the planes ``chosen`` and solve ``stage``."""
        from bimcap.optimize import solve

        problem, stats = self._build(poses, chosen)
        _log.info(f"solving {self.config.method.value} stage {stage.name} "
                  f"({opts.refine_mode.value.lower()}, {self.config.effective_weighting}): "
                  f"{stats.brief()}")
        result = solve(problem, opts, check=False)
        self.summaries.append(result.summary)
        if not result.summary.success:
            raise PipelineError(f"the solve failed ({stage.name}): {result.summary.termination}: "
                                f"{result.summary.message}")
        return _StageRun(stage=stage, options=opts, chosen=chosen, problem=problem, stats=stats,
                         result=result)

    def moved(self, run: _StageRun, moved: F64, frames: list[int]) -> _StageRun:
        """``run``'s problem (and planes) from ``moved``, the poses after a repair re-placed
        ``frames``, not yet solved (``result`` is still ``run``'s).

        The floor and ceiling samples of ``frames`` get their planes again at the moved poses
        (:func:`choose_sample_planes`, each frame's own offset and tilt estimated: the moved
        pose is a prediction), every other sample keeps ``run``'s plane. The planes a frame's
        samples were given where the repair found it are those of another room or storey:
        AC20-FZK-Haus Exp 1 frame 30, moved 2.7 m by the odometry repair, kept 12 floor samples
        on the upper storey's floor (2.7 m up) and no others, and they pulled it 24 cm up."""
        fresh = choose_sample_planes(self.prepared, moved)
        chosen = merge_plane_choices(run.chosen, fresh, frames,
                                     _plane_samples(self.prepared.frontend.to_problem_arrays()))
        problem, stats = self._build(moved, chosen)
        return replace(run, chosen=chosen, problem=problem, stats=stats)

    def _build(self, poses: F64, chosen: Any) -> tuple[Any, ProblemStats]:
        """:func:`build_problem` at ``poses`` with the planes ``chosen``, the ``held`` frames
        fixed."""
        problem, stats = build_problem(self.prepared, poses, self.max_dist, self.normals,
                                       planes_chosen=chosen)
        if self.wall_keep is not None:
            arrays = problem.arrays()
            problem = problem.replace(wall_frame=arrays["wall_frame"][self.wall_keep],
                                      wall_p_in_cam=arrays["wall_p_in_cam"][self.wall_keep])
            stats = replace(stats, wall=int(self.wall_keep.sum()))
        if self.held:
            fixed = np.asarray(problem.pose_fixed, np.int32).copy()
            fixed[sorted(self.held)] = 1
            problem = problem.replace(pose_fixed=fixed)
        return problem, stats


def _run_schedule(solver: _StageSolver, base: Any,
                  poses: F64) -> tuple[_StageRun, F64, dict[str, Any] | None]:
    """Every stage of :func:`schedule_for` from ``poses``: the last solver stage, the poses after
    the schedule (N, 7) and the coarse registration's record (None without one)."""
    from bimcap.registration import StageKind

    prepared, config = solver.prepared, solver.config
    coarse_info = None
    last: _StageRun | None = None
    for stage in progress(schedule_for(config).stages, desc="solve", unit="stage"):
        if stage.kind is StageKind.COARSE:
            poses, coarse_info = _coarse(prepared, poses, coarse_options(config))
            continue
        opts = stage_options(base, stage, config)
        if opts is None:
            continue
        last = solver.run(stage, opts, poses, choose_sample_planes(prepared, poses))
        poses = last.result.poses
    if last is None:
        raise PipelineError("the schedule has no solver stage for the configured terms")
    return last, poses, coarse_info


def _rechoose_planes(solver: _StageSolver, run: _StageRun, poses: F64, max_rounds: int,
                     tolerance: float) -> tuple[_StageRun, F64, list[dict[str, int]]]:
    """Choose the samples' planes again at the refined ``poses`` and solve the last stage again
    while more than ``tolerance`` of them change plane (at most ``max_rounds`` times)."""
    from bimcap.bim.plane_choice import PlaneChoiceOptions

    prepared = solver.prepared
    converged = PlaneChoiceOptions(frame_model=False)
    rounds: list[dict[str, int]] = []
    for _ in range(max_rounds):
        again = choose_sample_planes(prepared, poses, converged)
        changed, total = changed_planes(run.chosen, again, prepared.reference.planes)
        resolve = changed > tolerance * max(total, 1)
        rounds.append({"changed": changed, "samples": total, "resolved": int(resolve)})
        if not resolve:
            break
        _log.info(f"{changed}/{total} floor/ceiling samples changed plane at the refined "
                  f"poses: solving stage {run.stage.name} again")
        run = solver.run(run.stage, run.options, poses, again)
        poses = run.result.poses
    return run, poses, rounds


def _repair_run(solver: _StageSolver,
                run: _StageRun, poses: F64) -> tuple[_StageRun, F64, dict[str, Any]]:
    """:func:`_repair` of the last stage's result, the repaired frames' planes chosen again
    (:meth:`_StageSolver.moved`): the run and poses after it, and its record."""
    moved: list[_StageRun] = []

    def replan(poses_moved: F64, frames: list[int]) -> Any:
        moved.append(solver.moved(run, poses_moved, frames))
        return moved[-1].problem

    repair, redo = _repair(run.problem, run.options, run.result, replan)
    if redo is None:
        return run, poses, repair
    solver.summaries.append(redo.summary)
    return replace(moved[-1], result=redo), redo.poses, repair


def _odometry_repair_run(solver: _StageSolver, run: _StageRun, poses: F64,
                         suspect_k: float = 4.0, min_gain: float = 0.1
                         ) -> tuple[_StageRun, F64, dict[str, Any]]:
    """Frames the solve left far from where their neighbours and the input's relative motion put
    them (``registration.odometry.odometry_outliers``, with the limits of ``odometry_limits``:
    far outside how well the input's motion fits the other frames, and never looser than 3 σ of
    the odometry term), moved there, their planes chosen again (:meth:`_StageSolver.moved`),
    and solved again (:func:`_solve_moved`: kept only when the BIM agrees). Each outlier starts
    from the candidate of ``registration.odometry.odometry_candidates`` (each neighbour's
    prediction, with its rotation or the frame's own) that agrees best with the BIM after a solve
    of the outliers alone (:func:`_best_candidates`).

    The moved frames are solved free, also those the scan's noise-scale solve holds
    (``_StageSolver.held``: a hold keeps a frame where the last solve put it, and a repair
    re-places it): AC20-FZK-Haus Exp 1 frame 30, held 92 cm off, was "solved" from its
    neighbours' prediction without moving, scored there (0.58 of its samples within 5 cm, against
    0.82 where it was) and the repair rejected; solved free from it, it lands 0.9 cm from the
    truth (0.82). After the repair they are held again where it put them.

    Suspects, frames past the looser limits of ``odometry_limits`` with ``k = suspect_k`` but
    within the outliers', get the same candidates, and are moved only where their best candidate
    agrees with the BIM by at least ``min_gain`` more than their solved pose: a gap the input's
    motion alone cannot call (Exp 1's drift turns each frame by several degrees, so a
    neighbour's prediction lies decimetres off) but the BIM can. Office_A Exp 1 frame 59, the
    last, 0.63 m from its neighbour's prediction (outlier limit 0.65 m) and 81 cm from the truth
    at 0.85 agreement: its candidate ends 0.2 cm from it at 0.98.

    Returns the run and poses after it and its record (``odometry_outliers``' with the
    ``suspects``, their limits and ``moved``)."""
    from bimcap.registration.odometry import (
        bim_agreement,
        odometry_candidates,
        odometry_limits,
        odometry_outliers,
    )

    odo = run.options.terms["odometry"]
    if not odo.enabled:
        return run, poses, {"outliers": []}
    init = solver.prepared.init.poses
    loose_m, loose_deg = 3.0 * odo.sigma, 3.0 * odo.params["sigma_r_deg"]
    max_m, max_deg = odometry_limits(poses, init, loose_m, loose_deg)
    check = odometry_outliers(poses, init, max_m, max_deg)
    soft_m, soft_deg = odometry_limits(poses, init, loose_m, loose_deg, k=suspect_k)
    suspects = [f for f in odometry_outliers(poses, init, soft_m, soft_deg).outliers
                if f not in check.outliers]
    record: dict[str, Any] = {**check.to_dict(), "suspects": suspects,
                              "suspect_max_distance_m": soft_m,
                              "suspect_max_angle_deg": soft_deg}
    if not check.outliers and not suspects:
        return run, poses, record
    frames = sorted(check.outliers + suspects)
    candidates = odometry_candidates(poses, init, frames)
    if not candidates:  # no frame has a neighbour outside ``frames``
        return run, poses, record
    free = replace(solver, held=solver.held - frozenset(frames))
    start, best, agreement = _best_candidates(free, run, candidates, frames)
    record["candidate_agreement"] = agreement
    now = bim_agreement(run.problem.arrays(), poses, frames)
    kept = [f for f, b, c in zip(frames, best, now, strict=True)
            if f in suspects and not b >= c + min_gain]
    moved_frames = [f for f in frames if f not in kept]
    start[kept] = poses[kept]
    record["moved"] = moved_frames
    if not moved_frames:
        return run, poses, record
    _log.info(f"{len(moved_frames)} frame(s) lay far from where their neighbours and the input's "
              f"motion put them (outliers past {max_m:.2f} m or {max_deg:.1f}°: "
              f"{check.outliers}; suspects past {soft_m:.2f} m or {soft_deg:.1f}° that the BIM "
              f"agrees with better there: {[f for f in moved_frames if f in suspects]}) and were "
              f"moved there")
    moved = free.moved(run, start, moved_frames)
    verdict, redo = _solve_moved(run.problem, run.options, poses, start, moved_frames,
                                 "odometry repair", moved_problem=moved.problem)
    record.update(verdict)
    if redo is None:
        return run, poses, record
    solver.summaries.append(redo.summary)
    fixed = np.asarray(moved.problem.pose_fixed, np.int32).copy()
    fixed[sorted(solver.held)] = 1
    return replace(moved, problem=moved.problem.replace(pose_fixed=fixed), result=redo), \
        redo.poses, record


def _best_candidates(solver: _StageSolver, run: _StageRun, candidates: list[F64],
                     frames: list[int]) -> tuple[F64, F64, list[list[float | None]]]:
    """Each of ``frames`` solved from every candidate (``(N, 7)`` poses, e.g.
    ``registration.odometry.odometry_candidates``) with every other frame held, its planes
    chosen at the candidate (:meth:`_StageSolver.moved`); per frame the solved pose that agrees
    best with the BIM (``registration.odometry.bim_agreement``; the first on a tie). Returns the
    poses (the first candidate's elsewhere), each frame's best agreement (``(len(frames),)``,
    -inf where no solve succeeded or the frame has no BIM sample) and each candidate's agreements
    (candidate × frame, None: no BIM sample)."""
    from bimcap.optimize import solve
    from bimcap.registration.odometry import bim_agreement

    best = np.array(candidates[0], np.float64, copy=True)
    score = np.full(len(frames), -np.inf)
    table: list[list[float | None]] = []
    for cand in candidates:
        moved = solver.moved(run, cand, frames)
        fixed = np.ones(len(cand), np.int32)
        fixed[frames] = 0
        fixed[sorted(solver.held)] = 1
        solved = solve(moved.problem.replace(pose_fixed=fixed), run.options, check=False)
        agree = bim_agreement(moved.problem.arrays(), solved.poses, frames)
        table.append([None if np.isnan(v) else float(v) for v in agree])
        if not solved.summary.success:
            continue
        for i, f in enumerate(frames):
            if agree[i] > score[i]:
                score[i], best[f] = agree[i], solved.poses[f]
    return best, score, table


def _block_repair_run(solver: _StageSolver, run: _StageRun, poses: F64, max_plane_rounds: int,
                      plane_change_tolerance: float) -> tuple[_StageRun, F64, dict[str, Any]]:
    """Blocks of frames the solve placed apart from the rest (the motion check fails: the
    trajectory breaks from the input's relative motion where no match supports it), moved
    rigidly back onto the others by the matches across the break
    (``registration.odometry.block_moves``), their planes chosen again
    (:meth:`_StageSolver.moved`), solved again (:func:`_solve_moved`: kept only when the BIM
    agrees) and the planes chosen again. gen-small-s19 Exp 1: frames 0-13 sat 1.3 m along the
    corridor, out of the window shift's range, with 152 matches to frame 14 at 225 px;
    gen-twostorey-s90 Exp 1: frames 57-59 on the storey above, no match across (moved by the
    input's relative motion). Returns the run and poses after it and its record (``check``: the
    motion check before, ``moves``, and the verdict)."""
    from bimcap.registration.odometry import BlockMoveSource, block_moves

    a = run.problem.arrays()
    mf, cams = a.get("match_frames"), a.get("cameras")
    if mf is None or not len(mf) or cams is None or not len(cams):
        return run, poses, {"moves": []}
    blocks = block_moves(poses, solver.prepared.init.poses, mf, a["match_uv"], a["match_depth"],
                         np.asarray(cams)[0])
    if not blocks.check.failed:
        return run, poses, {"moves": []}
    record: dict[str, Any] = blocks.to_dict()
    if not blocks.moves:
        return run, poses, record
    run, poses, done, verdict = _block_try(solver, run, poses, blocks, max_plane_rounds,
                                           plane_change_tolerance)
    record.update(verdict)
    if done or all(m.source is BlockMoveSource.MOTION for m in blocks.moves):
        return run, poses, record
    # the matches across a break can be look-alikes (a repeated texture) that move the block
    # away; the input's relative motion is the other witness (gen-demo-s41 hard Exp 2)
    motion = block_moves(poses, solver.prepared.init.poses, mf, a["match_uv"], a["match_depth"],
                         np.asarray(cams)[0], use_matches=False)
    if not motion.moves:
        return run, poses, record
    run, poses, _, verdict = _block_try(solver, run, poses, motion, max_plane_rounds,
                                        plane_change_tolerance)
    record["by_motion"] = {**motion.to_dict(), **verdict}
    return run, poses, record


def _block_try(solver: _StageSolver, run: _StageRun, poses: F64, blocks: Any,
               max_plane_rounds: int, plane_change_tolerance: float
               ) -> tuple[_StageRun, F64, bool, dict[str, Any]]:
    """One try of :func:`_block_repair_run`: ``blocks`` (a ``BlockRepair``) moved, their planes
    chosen again, solved again and judged by the BIM. Returns the run and poses after it
    (unchanged when refused), whether it was kept, and the verdict."""
    from bimcap.registration.odometry import BlockMoveSource

    _log.info("block(s) of frames broken off the rest were moved back onto them: " + ", ".join(
        f"{m.start}-{m.stop - 1} by {m.distance_m:.2f} m / {m.angle_deg:.1f}° ("
        + (f"{m.inliers}/{m.matches} PnP inliers at frame {m.frame})"
           if m.source is BlockMoveSource.MATCHES else
           f"frame {m.frame} to the input's motion from its neighbour)")
        for m in blocks.moves))
    moved = solver.moved(run, blocks.poses, blocks.moved)
    verdict, redo = _solve_moved(run.problem, run.options, poses, blocks.poses, blocks.moved,
                                 "block repair", moved_problem=moved.problem)
    if redo is None:
        return run, poses, False, verdict
    solver.summaries.append(redo.summary)
    run, poses = replace(moved, result=redo), redo.poses
    run, poses, _ = _rechoose_planes(solver, run, poses, max_plane_rounds, plane_change_tolerance)
    return run, poses, True, verdict


def _unlinked_block_run(solver: _StageSolver, run: _StageRun, poses: F64, max_plane_rounds: int,
                        plane_change_tolerance: float, min_gain: float = 0.1
                        ) -> tuple[_StageRun, F64, dict[str, Any]]:
    """Blocks of frames that no match links to the rest (``registration.odometry.unlinked_blocks``,
    two frames or more), tried at the input's motion from their neighbour across the gap even
    when the motion check passes, and moved only where the BIM agrees clearly better there: the
    blocks' counterpart of the odometry repair's suspects (:func:`_odometry_repair_run`).

    Only the BIM and the input's motion place such a block; where the solve leaves it in the
    wrong place with its rotation near the input's, no step breaks the motion check and the
    block repair (:func:`_block_repair_run`) does not run. gen-small-s3 hard Exp 1 with OpenCV's
    SIFT: frames 56-59, matched only among themselves, 0.6-0.9 m off, largest step gap 0.74 m
    against the check's 1.52 m. Each block has two candidates (``_block_prediction``): the
    block moved as the block repair moves it (its end frame next to the gap to its prediction,
    the rotations kept unless the block is turned away) and every frame at its own prediction
    (the input's rotations). Each is solved with every other frame held, its planes chosen there
    (:func:`_best_candidates`); the candidate whose frames agree best with the BIM on average
    (``bim_agreement``) is taken when that mean exceeds the block's where it is by at least
    ``min_gain`` (the suspects' bar), then solved with the rest and judged as the block repair's
    moves are (:func:`_block_try`). A block the BIM agrees with as well where it is stays.

    Returns the run and poses after it and its record (``blocks``: every unlinked block with the
    BIM's agreement where it is, the best candidate's, and whether it was moved; the moved
    blocks' verdict)."""
    from bimcap.registration.odometry import (
        BlockRepair,
        _block_prediction,
        bim_agreement,
        motion_check,
        unlinked_blocks,
    )

    init = solver.prepared.init.poses
    record: dict[str, Any] = {"blocks": []}
    for start, stop in unlinked_blocks(run.problem.arrays().get("match_frames"), len(poses)):
        frames = list(range(start, stop))
        now = bim_agreement(run.problem.arrays(), poses, frames)
        seen = np.isfinite(now)  # frames with BIM samples
        moves = [m for m in (_block_prediction(poses, init, start, stop),
                             _block_prediction(poses, init, start, stop, turn_deg=0.0))
                 if m is not None]
        if not seen.any() or not moves:
            continue
        # a block of two frames or more is linked, so none of its frames is held
        tries = [(_best_candidates(solver, run, [cand], frames), move) for move, cand in moves]
        (start_poses, score, _), move = max(tries, key=lambda t: float(t[0][1][seen].mean()))
        entry: dict[str, Any] = {"start": start, "stop": stop,
                                 "bim_agreement": float(now[seen].mean()),
                                 "candidate_agreement": float(score[seen].mean())}
        entry["moved"] = bool(entry["candidate_agreement"] >= entry["bim_agreement"] + min_gain)
        record["blocks"].append(entry)
        if not entry["moved"]:
            continue
        _log.info(f"frames {start}-{stop - 1}, which no match links to the rest, agree better "
                  f"with the BIM where the input's motion puts them ({entry['bim_agreement']:.2f}"
                  f" -> {entry['candidate_agreement']:.2f} of their samples within 5 cm)")
        a = run.problem.arrays()
        check = motion_check(poses, init, a.get("match_frames"), a.get("match_uv"),
                             a.get("match_depth"), np.asarray(a["cameras"])[0])
        run, poses, _, verdict = _block_try(solver, run, poses,
                                            BlockRepair(start_poses, check, [move]),
                                            max_plane_rounds, plane_change_tolerance)
        entry.update(verdict)
    return run, poses, record


def _window_shift_run(solver: _StageSolver, run: _StageRun, poses: F64, max_plane_rounds: int,
                      plane_change_tolerance: float, max_rounds: int = 2
                      ) -> tuple[_StageRun, F64, dict[str, Any]]:
    """Windows of frames the solve left off the plan by a rigid shift
    (``registration.window_shift.window_shifts``: the planar translation of a window's wall and
    column samples that fits the plan clearly better), moved by it and solved again
    (:func:`_solve_moved`: kept only when the BIM agrees), then the planes chosen again; at
    most ``max_rounds`` times (a window that held frames on both sides of the stretch is moved
    only once its neighbours have pulled them). Returns the run and poses after it and its
    record (``rounds``: each round's moved windows and verdict)."""
    from bimcap.registration.window_shift import window_shifts

    rounds: list[dict[str, Any]] = []
    for _ in range(max_rounds):
        shifts = window_shifts(run.problem.arrays(), poses)
        if not shifts.moved:
            break
        _log.info(f"{len(shifts.moved)} frame(s) fit the plan clearly better shifted, window by "
                  f"window, and were moved: "
                  + ", ".join(f"{w.start}-{w.stop - 1} by ({w.shift_m[0] * 100:.0f}, "
                              f"{w.shift_m[1] * 100:.0f}) cm" for w in shifts.windows if w.moved))
        verdict, redo = _solve_moved(run.problem, run.options, poses, shifts.poses,
                                     shifts.moved, "window shift")
        rounds.append({**shifts.to_dict(), **verdict})
        if redo is None:
            break
        solver.summaries.append(redo.summary)
        run, poses = replace(run, result=redo), redo.poses
        run, poses, _ = _rechoose_planes(solver, run, poses, max_plane_rounds,
                                         plane_change_tolerance)
    return run, poses, {"rounds": rounds}


def _logged_plane_checks(problem: Any, poses: F64, limit_m: float) -> list[Any]:
    """:func:`plane_checks` of ``problem`` at ``poses``, each logged (a failed one as a warning)."""
    checks = plane_checks(problem, poses, limit_m)
    for c in checks:
        _log.log(logging.WARNING if c.failed else logging.INFO, c.message())
    return checks


def _logged_motion_check(arrays: dict[str, Any], poses: F64, input_poses: F64) -> Any:
    """``registration.odometry.motion_check`` of the refined ``poses`` against the input's
    relative motion, judged by the problem's matches, logged (a failed one as a warning): a
    block of frames placed in an alias converges, passes the plane checks and is observed
    like any other; only its break from the input's motion, which no match supports, shows."""
    from bimcap.registration.odometry import motion_check

    cams = arrays.get("cameras")
    check = motion_check(poses, input_poses, arrays.get("match_frames"), arrays.get("match_uv"),
                         arrays.get("match_depth"),
                         None if cams is None or not len(cams) else np.asarray(cams)[0])
    _log.log(logging.WARNING if check.failed else logging.INFO, check.message())
    return check


def _repair(problem: Any, opts: Any, result: Any,
            replan: Callable[[F64, list[int]], Any] | None = None
            ) -> tuple[dict[str, Any], Any]:
    """Frames the solve left inconsistent with their neighbours' matches, re-placed from them by
    PnP (``registration.odometry``) and solved again (:func:`_solve_moved`: kept only when the
    BIM agrees). ``replan(moved_poses, repaired_frames)`` gives the problem to solve from the
    repaired poses (None: ``problem`` itself). Returns the repair's record and the new solve's
    result (None when no frame needed it or the repair was rejected)."""
    from bimcap.registration.odometry import repair_inconsistent_frames

    a = problem.arrays()
    rep = repair_inconsistent_frames(result.poses, a["match_frames"], a["match_uv"],
                                     a["match_depth"], a["cameras"][0])
    if not rep.repaired:
        return rep.to_dict(), None
    _log.info(f"{len(rep.repaired)} frame(s) disagreed with their neighbours' matches "
              f"(median reprojection error > 10 px) and were re-placed from them: "
              f"{rep.repaired}")
    verdict, redo = _solve_moved(problem, opts, result.poses, rep.poses, rep.repaired, "repair",
                                 moved_problem=None if replan is None else
                                 replan(rep.poses, rep.repaired))
    return {**rep.to_dict(), **verdict}, redo


def _solve_moved(problem: Any, opts: Any, poses: F64, moved: F64, frames: list[int], what: str,
                 max_agreement_loss: float = 0.05,
                 moved_problem: Any = None) -> tuple[dict[str, Any], Any]:
    """Solve ``problem`` again from ``moved`` (``poses`` with ``frames`` re-placed by a repair)
    and keep the result only when no moved frame agrees less with the BIM than at ``poses``
    (:func:`bim_agreement`, by more than ``max_agreement_loss``). A repair is a proposal to leave
    a local minimum and the BIM is its judge: the look-alike matches of a repeated texture cannot
    fool it, and the solve's cost cannot judge (the association gate drops the samples of a frame
    moved far off). ``moved_problem``: the problem built at ``moved`` (the moved frames' planes
    chosen there, :meth:`_StageSolver.moved`), solved and judged in place of ``problem``; each
    pose is judged with the planes chosen for it. Returns the verdict (``accepted``,
    ``bim_agreement_before`` / ``_after``) and the new solve's result, or None when rejected."""
    from bimcap.optimize import solve
    from bimcap.registration.odometry import bim_agreement

    start = problem.replace(poses=moved) if moved_problem is None else moved_problem
    redo = solve(start, opts, check=False)
    before = bim_agreement(problem.arrays(), poses, frames)
    after = bim_agreement(start.arrays(), redo.poses, frames)
    verdict: dict[str, Any] = {
        "bim_agreement_before": [None if np.isnan(v) else float(v) for v in before],
        "bim_agreement_after": [None if np.isnan(v) else float(v) for v in after]}
    worse = [f for f, b, c in zip(frames, before, after, strict=True)
             if np.isfinite(b) and not c >= b - max_agreement_loss]
    verdict["accepted"] = bool(redo.summary.success and not worse)
    if verdict["accepted"]:
        return verdict, redo
    _log.info(f"the {what} is rejected: frame(s) {worse} agree less with the BIM after it "
              f"({', '.join(f'{b:.2f} -> {c:.2f}' for b, c in zip(before, after, strict=True))}"
              " of their samples within 5 cm)" if worse else
              f"the {what} is rejected: the solve after it failed ({redo.summary.termination})")
    return verdict, None


def g_unit(config: RefineConfig) -> str:
    """The unit of the G term's residual under ``config``: "m" for FACaP's point error, "px"
    for the reprojection / landmark errors (the report's solver table)."""
    from bimcap.optimize.options import GeometricMode

    return "m" if solver_options(config).geometric_mode is GeometricMode.POINT else "px"


def effective_settings(config: RefineConfig) -> dict[str, Any]:
    """Every setting a run with ``config`` uses, as nested plain values: the config's fields
    with the method's defaults filled in, ``solver`` (every ``SolverOptions`` field after the
    preset and the overrides, terms as sub-tables) and ``registration`` (every
    ``CoarseOptions`` field). ``bimcap refine --print-config`` writes it as TOML; the file reads
    back (``--config``) to the same run."""
    from dataclasses import asdict

    from bimcap.optimize.core import core

    opts = solver_options(config)
    kinds = {spec["key"]: spec["kind"] for spec in core().option_specs()}
    parse = {"float": float, "int": int, "bool": lambda t: t in ("1", "true", "True"),
             "enum": str}
    solver: dict[str, Any] = {}
    for key, text in opts.to_flat().items():
        head, _, sub = key.partition(".")
        typed = parse[kinds.get(key, "float")](text)
        if sub:
            solver.setdefault(head, {})[sub] = typed
        else:
            solver[key] = typed
    out = {k: v for k, v in config.to_dict().items()
           if k not in ("solver", "registration", "features", "matching", "geometric")
           and not k.startswith("effective_")}
    out.update(terms=config.effective_terms, weighting=config.effective_weighting,
               coarse=config.effective_coarse, lidar_scan=config.effective_lidar_scan,
               solve_match_distance=config.effective_solve_match_distance or 0.0,
               geometric_mode=opts.geometric_mode.value.lower(),
               loss=opts.geometric.loss.value.lower())
    out["solver"] = solver
    out["registration"] = asdict(coarse_options(config))
    # every setting, those left out of the cache keys when they are the defaults too
    sift = sift_options(config)
    out["features"] = {**sift.to_dict(), "opencv_octave_layers": sift.opencv_octave_layers}
    matching = match_options(config)
    out["matching"] = {**matching.to_dict(), "product": matching.product.value,
                       "sampson_refinement": matching.sampson_refinement}
    out["geometric"] = asdict(geometric_options(config))
    return out


def coarse_options(config: RefineConfig) -> Any:
    """``bimcap.registration.CoarseOptions`` with the config's ``[registration]`` table applied;
    a key that is not a field or a value of the wrong type or range raises ConfigError naming
    ``registration.<key>``."""
    from bimcap.pipeline.config import options_from_table
    from bimcap.registration import CoarseOptions, RegistrationInputError

    return options_from_table(CoarseOptions, config.registration, "registration",
                              RegistrationInputError)


def sift_options(config: RefineConfig) -> Any:
    """``bimcap.features.SiftOptions`` with the config's ``[features]`` table applied (errors
    name ``features.<key>``)."""
    from bimcap.features.sift import FeatureError, SiftOptions
    from bimcap.pipeline.config import options_from_table

    return options_from_table(SiftOptions, config.features, "features", FeatureError)


def match_options(config: RefineConfig) -> Any:
    """``bimcap.features.MatchOptions`` with the config's ``[matching]`` table applied (errors
    name ``matching.<key>``)."""
    from bimcap.features.matching import MatchOptions
    from bimcap.features.sift import FeatureError
    from bimcap.pipeline.config import options_from_table

    return options_from_table(MatchOptions, config.matching, "matching", FeatureError)


def geometric_options(config: RefineConfig) -> Any:
    """``bimcap.segmentation.geometric.GeometricOptions`` with the config's ``[geometric]`` table
    applied (errors name ``geometric.<key>``)."""
    from bimcap.pipeline.config import options_from_table
    from bimcap.segmentation.errors import SegmentationInputError
    from bimcap.segmentation.geometric import GeometricOptions

    return options_from_table(GeometricOptions, config.geometric, "geometric",
                              SegmentationInputError)


def _coarse(prepared: Prepared, poses: F64, options: Any = None) -> tuple[F64, dict[str, Any]]:
    """Coarse registration of the initial poses to the BIM (``bimcap.registration``, settings
    ``options``: :func:`coarse_options`): per frame, tilt from the floor and yaw + translation
    tracked against the floor plan; then per window of frames, levelling on the floor/ceiling,
    a correlative x-y-yaw search of the wall and column points against the floor plan,
    trajectory continuity (Viterbi), point-to-segment ICP."""
    from bimcap.registration import CoarseOptions, coarse_register

    samples, plan = _semantic_samples(prepared), _floor_plan(prepared.reference)
    t0 = time.perf_counter()
    res = coarse_register(poses, samples, plan, options or CoarseOptions())
    info = res.to_dict()
    info["seconds"] = time.perf_counter() - t0
    fl = res.frame_level
    drift = res.near_probe_drift_m if fl is None else fl.drift_m
    if drift is not None and not res.accepted.any() and np.array_equal(res.poses, poses):
        how = "" if fl is not None else f" ({res.options.near_probe_frames} frames)"
        _log.info(f"coarse registration: tracked drift{how} {drift:.2f} m is within the "
                  f"bundle adjustment's reach; poses unchanged ({info['seconds']:.1f} s)")
    else:
        _log.info(f"coarse registration: {int(res.accepted.sum())}/{len(res.accepted)} "
                  f"frames accepted by the window search ({info['seconds']:.1f} s)")
    return np.asarray(res.poses, np.float64), info


def _semantic_samples(prepared: Prepared) -> Any:
    """The front end's semantic samples as the registration stages take them
    (``bimcap.registration.SemanticSamples``)."""
    from bimcap.registration import SemanticSamples

    arrays = prepared.frontend.to_problem_arrays()
    names = [f"{c}_{s}" for c in ("wall", "column", "floor", "ceiling")
             for s in ("frame", "p_in_cam")]
    return SemanticSamples.from_arrays(**{k: arrays.get(k) for k in names})


def _floor_plan(ref: Any) -> Any:
    """The ``bimcap.registration.FloorPlan`` of a ``BimReference``."""
    from bimcap.registration import FloorPlan

    return FloorPlan.from_planes(ref.segments, ref.segment_class, ref.segment_z, ref.planes,
                                 ref.plane_kind)


#: ``global_align = "auto"`` aligns when fewer initial cameras than this lie in free space (a
#: SLAM frame moved by tens of metres: 0 %; the Exp 1 drift of a trajectory in the BIM frame
#: still leaves about 67 % on the tiny world, Exp 2 97 %).
AUTO_GLOBAL_ALIGN_FREE_FRACTION = 0.3


def _align_without_missing_wall(poses: F64, samples: Any, plan: Any, refusal: Any,
                                options: Any, maps_cache: dict[bytes, Any] | None = None
                                ) -> tuple[Any, Any] | None:
    """A refused global alignment tried again without the one BIM wall its best placement was
    seen through (``bimcap.registration.missing_wall``: a wall missing as built), with a
    warning naming the wall; None when that does not apply or does not place it."""
    from bimcap.registration.missing_wall import align_without_missing_wall

    found = align_without_missing_wall(poses, samples, plan, refusal, options, maps_cache)
    if found is not None:
        _log.warning(f"global alignment: {found[1].describe()}: placed without that wall")
    return found


def _global_align(prepared: Prepared, poses: F64, config: RefineConfig
                  ) -> tuple[F64, dict[str, Any] | None]:
    """Place an initial trajectory given in its own (SLAM) frame in the BIM
    (``bimcap.registration.global_align``) when ``config.global_align`` is on, or when it is
    auto and fewer than :data:`AUTO_GLOBAL_ALIGN_FREE_FRACTION` of the initial cameras lie in
    the building's free space. Returns the poses (N, 7) the schedule starts from and the
    alignment's record (None when it did not run). Raises ``AmbiguousAlignmentError`` /
    ``GlobalAlignmentError`` (which carry the ranked placements) when it refuses."""
    from bimcap.registration import GlobalAlignOptions, global_align, initial_free_fraction
    from bimcap.registration.errors import AmbiguousAlignmentError, GlobalAlignmentError

    mode = config.global_align
    if mode is GlobalAlignMode.OFF:
        return poses, None
    plan = _floor_plan(prepared.reference)
    free = initial_free_fraction(poses, plan)
    if mode is GlobalAlignMode.AUTO:
        if free >= AUTO_GLOBAL_ALIGN_FREE_FRACTION:
            return poses, None
        _log.info(f"global alignment: only {free:.0%} of the initial cameras lie in the "
                  "building's free space (a trajectory in its own SLAM frame?): placing it in "
                  "the BIM first (--no-global-align / global_align = \"off\" to skip)")
    t0 = time.perf_counter()
    samples = _semantic_samples(prepared)
    # the search's threads follow the front end's processes: --workers N caps both (None: every
    # core); the placements are the same with any number (GlobalAlignOptions.num_threads)
    options = GlobalAlignOptions(accept_ambiguous=config.accept_ambiguous,
                                 num_threads=config.workers or 0)
    missing = None
    maps_cache: dict[bytes, Any] = {}  # the storeys' maps, kept for the missing-wall retry
    try:
        try:
            res = global_align(poses, samples, plan, options, maps_cache)
        except GlobalAlignmentError as exc:
            found = _align_without_missing_wall(poses, samples, plan, exc, options, maps_cache)
            if found is None:
                raise
            res, missing = found
    except GlobalAlignmentError as exc:
        if mode is not GlobalAlignMode.AUTO or isinstance(exc, AmbiguousAlignmentError):
            raise
        # Auto mode guessed a SLAM frame from where the cameras stand; no placement fits, so
        # the guess was wrong (a drifted trajectory 1–2 m off in a small building looks alike):
        # go on from the input, as with global_align = "off", and say so.
        _log.warning(f"global alignment (auto) found no placement that fits ({exc}); going on "
                     "from the initial poses as given (global_align = \"on\" makes this an "
                     "error)")
        return poses, {"mode": mode.value, "initial_free_fraction": free, "fallback": str(exc),
                       "seconds": time.perf_counter() - t0,
                       "placements": None if exc.result is None else exc.result.to_dict()}
    best = res.hypotheses[0]
    _log.info(f"global alignment: yaw {best.yaw_deg:.1f} deg, floor "
              f"{'-' if best.floor_z is None else f'{best.floor_z:.2f} m'}, score "
              f"{best.score:.3f}, second-best at {res.ratio:.0%} of it "
              f"({time.perf_counter() - t0:.1f} s)")
    if res.accepted_ambiguous:
        _log.warning("global alignment is ambiguous; the best placement was taken because "
                     "--accept-ambiguous is set:\n" + res.describe())
    info = res.to_dict()
    info.update(mode=mode.value, initial_free_fraction=free,
                seconds=time.perf_counter() - t0,
                missing_wall=None if missing is None else missing.to_dict())
    return np.asarray(res.poses, np.float64), info


# ------------------------------------------------------------------------ step 3: the whole run
def _to_dict_or_none(value: Any) -> Any:
    """``value.to_dict()``, or None for None."""
    return None if value is None else value.to_dict()


@dataclass
class RefineResult:
    """Everything one ``bimcap refine`` run produced (paths relative to ``out_dir``)."""

    out_dir: Path
    config: RefineConfig
    init: Trajectory
    refined: Trajectory
    outcome: SolveOutcome
    metrics_before: Any = None
    metrics_after: Any = None
    map_before: Any = None
    map_after: Any = None
    map_refined: dict[str, Any] | None = None
    deviations: dict[str, Any] | None = None
    inputs: dict[str, str] = field(default_factory=dict)
    deviation_run: Any = None  #: bimcap.deviations.outputs.DeviationRun (not in result.json)
    timings: dict[str, float] = field(default_factory=dict)
    files: dict[str, str] = field(default_factory=dict)
    command: str = ""
    colmap: dict[str, Any] | None = None
    scan_samples: dict[str, int] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "command": self.command,
            "config": self.config.to_dict(),
            "solve": self.outcome.to_dict(),
            "metrics_before": _to_dict_or_none(self.metrics_before),
            "metrics_after": _to_dict_or_none(self.metrics_after),
            "map_before": _to_dict_or_none(self.map_before),
            "map_after": _to_dict_or_none(self.map_after),
            "map_refined": self.map_refined,
            "deviations": self.deviations,
            "inputs": self.inputs,
            "timings": self.timings,
            "files": self.files,
            "colmap": self.colmap,
            "scan_samples": self.scan_samples,
        }


def evaluate_run(
    prepared: Prepared, est: Trajectory, gt: Trajectory, radius: float = 0.2,
    min_neighbours: int = 5, nnd_cutoff: float = 0.3,
) -> tuple[Any, Any]:
    """Trajectory metrics of ``est`` against ``gt`` and map metrics of the semantic map built with
    ``est`` (MME/MPV with ``radius``, NND against the map built with the ground truth)."""
    from bimcap.evaluation.map_metrics import map_metrics_with_reference
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics
    from bimcap.frontend.semantic_map import semantic_points

    tm = trajectory_metrics(est.poses, gt.poses, AlignMode.NONE)
    pts, _ = semantic_points(prepared.map_source, est.poses)
    ref_pts, _ = semantic_points(prepared.map_source, gt.poses)
    mm = None
    if len(pts) > 10:
        mm = map_metrics_with_reference(
            pts, ref_pts, "map with ground-truth poses", radius=radius,
            min_neighbours=min_neighbours, cutoff=nnd_cutoff,
        )
    return tm, mm


#: Every file a refine run may write into its output directory (``figures/``: the report's PNGs;
#: ``colmap/``: the COLMAP workspace); ``result.json`` lists the ones a run wrote, with their
#: SHA-256 (``bimcap.io.outputs``).
REFINE_OUTPUTS = ("refined.tum", "summary.json", "map_before.ply", "map_after.ply",
                  "map_refined.ply", "report.html", "figures/", "colmap/", "deviations.json",
                  "deviations.csv", "deviations.ply", "deviations.png", "deviations.ifc",
                  "deviations.bcfzip", "run.rrd")


@dataclass
class RunPlan:
    """What :func:`validate_run` checked, ready for the run (nothing expensive was done).

    Attributes
    ----------
    sequence: the read sequence. ifc: the IFC file. init: the initial trajectory (one pose per
    frame). gt: the ground truth or None. options: the base solver options. outputs: the output
    set (checked, not yet opened).
    """

    sequence: Any
    ifc: Path
    init: Trajectory
    gt: Trajectory | None
    options: Any
    outputs: Any


def validate_settings(config: RefineConfig) -> Any:
    """Every setting of ``config`` that can be checked without data: the terms, the solver
    overrides, each schedule stage's options, the front-end sources' files. Returns the base
    ``SolverOptions``; raises :class:`bimcap.errors.InputError` naming the setting."""
    from bimcap.pipeline.config import ConfigError
    from bimcap.registration import StageKind

    base = solver_options(config)
    coarse_options(config)
    sift_options(config)
    match_options(config)
    geometric_options(config)
    solver_stages = [stage_options(base, stage, config) for stage in schedule_for(config).stages
                     if stage.kind is not StageKind.COARSE]
    if all(o is None for o in solver_stages):
        raise ConfigError(f"no solver stage runs any of the terms {config.effective_terms}",
                          field="terms")
    for name, value in (("completion_model", config.completion_model),
                        ("segmentation_model", config.segmentation_model)):
        if value is not None and config_uses(config, name) and not Path(value).is_file():
            raise ConfigError("no such model file", value, name)
    if config.segmentation is LabelSource.DISK and not Path(str(config.labels_dir)).is_dir():
        raise ConfigError("no such label directory", config.labels_dir, "labels_dir")
    if config.rerun:  # the rerun extra, before any expensive stage
        from bimcap.pipeline.rerun_export import require_rerun

        require_rerun()
    executor = executor_options(config)
    if executor.is_dask:  # before any expensive stage: the package, the scheduler's address
        from bimcap.frontend.executor import check_scheduler, require_distributed

        require_distributed()
        if executor.scheduler is not None:
            check_scheduler(executor.scheduler, executor.connect_timeout_s)
    return base


def executor_options(config: RefineConfig) -> Any:
    """``bimcap.frontend.ExecutorOptions`` of ``config``'s ``executor`` and ``[dask]`` table; a
    bad key or value raises :class:`ConfigError` naming ``dask.<key>``."""
    from bimcap.frontend.errors import FrontendInputError
    from bimcap.frontend.executor import ExecutorOptions
    from bimcap.methods import ExecutorKind
    from bimcap.pipeline.config import ConfigError

    if config.executor is not ExecutorKind.DASK and config.dask.get("scheduler") is not None:
        raise ConfigError("a Dask scheduler is set but executor is local; set "
                          "executor = \"dask\" (or pass --dask)", field="dask.scheduler")
    try:
        return ExecutorOptions.from_table(config.executor, config.dask)
    except FrontendInputError as exc:
        raise ConfigError(exc.message, exc.path, exc.field) from None


def config_uses(config: RefineConfig, name: str) -> bool:
    """Whether ``config`` uses the setting ``name`` (completion_model / segmentation_model)."""
    if name == "completion_model":
        return config.completion.needs_model
    return config.segmentation is LabelSource.ONNX


def validate_run(
    sequence: str | PathLike[str] | Any,
    out_dir: str | PathLike[str],
    config: RefineConfig,
    ifc: str | PathLike[str] | None = None,
    init: str | PathLike[str] | Trajectory | None = None,
    gt: str | PathLike[str] | None = None,
    overwrite: bool = False,
) -> RunPlan:
    """One validation pass before any expensive stage of :func:`refine`: the settings
    (:func:`validate_settings`), the sequence, the IFC (present and a complete STEP file), the
    initial poses and the ground truth (one pose per frame, at the frames' timestamps; errors name
    the file), the front-end sources the sequence must provide, and the output directory
    (:class:`bimcap.io.outputs.OutputSet`: nothing the user wrote is replaced without
    ``overwrite``)."""
    from bimcap.bim.ingest import check_ifc_file
    from bimcap.dataset import read_sequence
    from bimcap.io.outputs import OutputSet

    base = validate_settings(config)
    seq = read_sequence(sequence) if isinstance(sequence, (str, PathLike)) else sequence
    ifc_path = Path(ifc) if ifc is not None else seq.ifc_path
    if ifc_path is None:
        raise InputError("no --ifc given and the sequence manifest names none",
                         seq.manifest_path, "ifc")
    check_ifc_file(ifc_path)
    traj = load_initial(seq, init)
    gt_traj = load_ground_truth(seq, gt)
    make_providers(config, seq)  # ground-truth depth / labels need them in the sequence
    inputs = [seq.manifest_path, ifc_path,
              *(p for p in (init, gt) if isinstance(p, (str, PathLike)))]
    inputs += [seq.trajectory_path(name) for name in seq.poses]
    outputs = OutputSet(out_dir, REFINE_OUTPUTS, overwrite=overwrite, inputs=inputs)
    outputs.check()
    return RunPlan(seq, ifc_path, traj, gt_traj, base, outputs)


@dataclass
class DatumPlan:
    """A datum checked before the run: the spec and the design model it was resolved in."""

    spec: Any  #: bimcap.deviations.datum.DatumSpec
    model: Any  #: bimcap.bim.ingest.BimModel (furniture included, as the deviations load it)


def validate_datum(config: RefineConfig, ifc: Path, deviations: bool) -> DatumPlan | None:
    """The config's datum resolved in ``ifc`` and checked (x, y and yaw constrained) before any
    expensive stage; None without one. A datum without ``deviations`` is not used (a warning)."""
    from bimcap.deviations.datum import DatumSpec, check_datum

    spec = DatumSpec.parse(config.datum, "--datum / datum", config.datum_fit)
    if spec is None:
        return None
    if not deviations:
        _log.warning("datum %s given without --deviations: not used", list(spec.selectors))
        return None
    from bimcap.deviations.analysis import load_design

    model = load_design(ifc)
    free = check_datum(model, spec.resolve(model), spec.source, ifc)
    if free:
        _log.warning("the datum leaves %s free: the refined poses' %s is kept", ", ".join(free),
                    ", ".join(free))
    return DatumPlan(spec, model)


def check_map_storey(config: RefineConfig, storeys: list[Any], ifc: Path) -> None:
    """Raise :class:`ConfigError` (field ``map_storey``, naming the IFC's storeys) when
    ``config.map_storey`` is not a storey of ``storeys`` (the BIM reference's)."""
    from bimcap.deviations.refined_map import RefinedMapError, storey_z_range
    from bimcap.pipeline.config import ConfigError

    if config.map_storey is None:
        return
    try:
        storey_z_range(storeys, config.map_storey)
    except RefinedMapError as exc:
        raise ConfigError(f"{exc.message} ({ifc})", field="map_storey") from None


def write_map_refined(path: Path, sequence: Any, world_from_cam: F64, label_points: F64,
                      label_values: Any, storeys: list[Any] | None = None,
                      storey: str | None = None) -> Any:
    """Write ``map_refined.ply``: every LiDAR scan of ``sequence`` through ``world_from_cam``
    (N, 7) and the sequence's ``cam_from_lidar``, voxel-downsampled, labelled from the front end's
    samples (``label_points`` (K, 3), ``label_values`` (K,)), cropped to ``storey`` of
    ``storeys`` when given (:func:`bimcap.deviations.refined_map.storey_z_range`); returns the
    :class:`bimcap.deviations.refined_map.RefinedMap`."""
    from bimcap.deviations.refined_map import (
        storey_z_range,
        stream_refined_map,
        write_refined_map,
    )

    z_range = (storey_z_range(sorted(storeys or [], key=lambda s: s.elevation_m), storey)
               if storey is not None else None)
    refined_map = stream_refined_map(sequence, world_from_cam, label_points=label_points,
                                     label_values=label_values, z_range=z_range)
    write_refined_map(path, refined_map)
    return refined_map


def write_run_outputs(
    stage: Path,
    prepared: Prepared,
    outcome: SolveOutcome,
    config: RefineConfig,
    gt: Trajectory | None,
    command: str = "",
    report: bool = True,
    extra_rows: list[Any] | None = None,
    deviations_ifc: Path | None = None,
    datum: Any = None,
) -> RefineResult:
    """Write one run's outputs into ``stage`` (an open output set's staging directory):
    ``refined.tum``, ``summary.json``, ``map_before.ply`` / ``map_after.ply``, the LiDAR map
    ``map_refined.ply``, the COLMAP workspace ``colmap/`` (``config.colmap``: ``sparse/0`` and the
    undistorted ``images/``, :mod:`bimcap.pipeline.colmap_export`) and, with ``report``,
    ``report.html`` and its ``figures/`` (``extra_rows``: more runs shown beside, e.g. FACaP),
    and with ``config.rerun`` the Rerun recording ``run.rrd`` (:func:`write_run_recording`).
    With ``deviations_ifc``, the scan-vs-BIM deviations against that IFC under the refined poses
    (``deviations.*``, and a report section), relative to ``datum`` (a resolved
    :class:`DatumPlan`) when given. With ``gt`` the result carries the metrics before
    and after. The result's
    ``out_dir`` is ``stage``; the caller points it at the final directory before committing."""
    header = f"bimcap {config.method.value} {config.effective_terms} refined world_from_cam"
    write_tum(stage / "refined.tum", outcome.refined, header=header)
    atomic_write_json(stage / "summary.json", outcome.to_dict())
    prepared.map_source.write_semantic_map(stage / "map_before.ply", prepared.init.poses)
    smap = prepared.map_source.write_semantic_map(stage / "map_after.ply", outcome.refined.poses)
    refined_map = write_map_refined(stage / "map_refined.ply", prepared.sequence,
                                    outcome.refined.poses, smap.points, smap.labels,
                                    prepared.reference.storeys, config.map_storey)
    result = RefineResult(out_dir=stage, config=config, init=prepared.init,
                          refined=outcome.refined, outcome=outcome,
                          timings={**prepared.timings, "solve": outcome.seconds},
                          command=command, scan_samples=prepared.scan_samples)
    if gt is not None:
        result.metrics_before, result.map_before = evaluate_run(prepared, prepared.init, gt)
        result.metrics_after, result.map_after = evaluate_run(prepared, outcome.refined, gt)
    result.files = {"refined": "refined.tum", "summary": "summary.json",
                    "map_before": "map_before.ply", "map_after": "map_after.ply",
                    "map_refined": "map_refined.ply"}
    result.map_refined = refined_map.to_dict()
    if deviations_ifc is not None:
        from bimcap.deviations.outputs import run_deviations

        dev = run_deviations(prepared.sequence, outcome.refined.poses, deviations_ifc, stage,
                             map_points=refined_map.points,
                             datum=None if datum is None else datum.spec,
                             model=None if datum is None else datum.model)
        result.deviation_run = dev
        result.deviations = {"counts": dev.report.counts(), "clusters": len(dev.report.clusters),
                             "seconds": dev.seconds, "datum": dev.report.datum}
        result.files.update({p.stem + p.suffix.replace(".", "_"): p.name
                             for p in dev.files.values()})
        result.timings["deviations"] = dev.seconds
    if config.colmap is not ColmapExport.OFF:
        from bimcap.pipeline.colmap_export import export_colmap

        colmap = export_colmap(stage / "colmap", prepared.sequence, prepared.frontend,
                               outcome.refined.poses, config.colmap)
        result.colmap = colmap.to_dict()
        result.files["colmap"] = f"colmap/{colmap.model}"
        result.timings["colmap"] = colmap.seconds
    if report:
        from bimcap.pipeline.report import write_refine_report

        result.files["report"] = write_refine_report(result, prepared, gt, extra_rows,
                                                     g_unit=g_unit(config)).name
    if config.rerun:
        rec = write_run_recording(stage / "run.rrd", prepared, outcome, gt, refined_map,
                                  extra_rows)
        result.files["rerun"] = "run.rrd"
        result.timings["rerun"] = rec.seconds
    return result


def write_run_recording(path: Path, prepared: Prepared, outcome: SolveOutcome,
                        gt: Trajectory | None, refined_map: Any,
                        extra_rows: list[Any] | None = None) -> Any:
    """The run as a Rerun recording in ``path`` (``refine --rerun``,
    :mod:`bimcap.pipeline.rerun_export`): the BIM reference's floor plan, the initial, refined
    (and ``extra_rows``', e.g. FACaP's) and ground-truth trajectories, the refined cameras with
    the sequence's images, the refined LiDAR map and the per-frame errors."""
    from bimcap.pipeline.rerun_export import RecordingInput, write_recording

    seq, ref = prepared.sequence, prepared.reference
    trajectories = {"initial": prepared.init.poses}
    if gt is not None:
        trajectories["ground_truth"] = gt.poses
    for row in extra_rows or []:
        trajectories[row.name.split()[0].lower()] = row.poses
    trajectories["refined"] = outcome.refined.poses
    inp = RecordingInput(
        outcome.refined.timestamps, trajectories, ref.segments, ref.segment_class,
        ref.segment_z, refined_map.points, refined_map.labels, seq.camera.pinhole(),
        [Path(seq.root) / f.image for f in seq.frames])
    return write_recording(path, inp)


def refine(
    sequence: str | PathLike[str],
    out_dir: str | PathLike[str],
    config: RefineConfig | None = None,
    ifc: str | PathLike[str] | None = None,
    init: str | PathLike[str] | None = None,
    gt: str | PathLike[str] | None = None,
    report: bool = True,
    quiet: bool | None = None,
    command: str = "",
    overwrite: bool = False,
    deviations: bool = False,
) -> RefineResult:
    """Refine a sequence's trajectory against its BIM and write every output into ``out_dir``.

    Outputs: ``refined.tum``, ``summary.json`` (solver), ``map_before.ply`` / ``map_after.ply``
    (semantic maps), ``colmap/`` (the COLMAP model of the refined reconstruction),
    ``report.html`` and its ``figures/``, and ``result.json`` (settings, metrics, timings, and
    every file of the run with its SHA-256), written as one set
    (:class:`bimcap.io.outputs.OutputSet`: staged, then moved into place, ``result.json`` last);
    caches in ``bim/`` and ``cache/``. Ground truth: ``gt`` or the sequence's ``poses/gt.tum``
    when present. Everything is validated first (:func:`validate_run`); a file in ``out_dir``
    that bimcap did not write is replaced only with ``overwrite``; a failed run leaves no staging
    directory and, when it created ``out_dir``, no empty ``out_dir``. With ``deviations``, also
    the scan-vs-BIM deviations under the refined poses (``deviations.json`` / ``.csv`` /
    ``.ply``, :func:`bimcap.deviations.outputs.run_deviations`). The steps are logged
    (:func:`prepare`, :func:`solve_prepared`); ``quiet`` is deprecated
    (:func:`bimcap.logs.quieted`).
    """
    with quieted(quiet):
        return _refine(sequence, out_dir, config, ifc, init, gt, report, command, overwrite,
                       deviations)


def _refine(sequence: str | PathLike[str], out_dir: str | PathLike[str],
            config: RefineConfig | None, ifc: str | PathLike[str] | None,
            init: str | PathLike[str] | None, gt: str | PathLike[str] | None, report: bool,
            command: str, overwrite: bool, deviations: bool) -> RefineResult:
    """:func:`refine`."""
    from bimcap.registration.errors import GlobalAlignmentError

    cfg = config or RefineConfig()
    out = Path(out_dir)
    plan = validate_run(sequence, out, cfg, ifc, init, gt, overwrite)
    datum = validate_datum(cfg, plan.ifc, deviations)
    stage = plan.outputs.open()
    try:
        t_start = time.perf_counter()
        prepared = prepare(plan.sequence, plan.ifc, plan.init, cfg, out)
        outcome = solve_prepared(prepared, cfg)
        if outcome.diverged_frames:
            refused = refused_auto_alignment(outcome)
            if refused is not None:
                raise refused
            raise PipelineError(
                f"the solve diverged: frame(s) {outcome.diverged_frames[:10]} of "
                f"{outcome.refined.poses.shape[0]} lie more than {DIVERGED_MARGIN_M:g} m outside "
                "the building; the refined trajectory is unusable and was not written (FACaP's "
                "plain least squares has no prior: try --method bimcap, or more overlap)")
        result = write_run_outputs(stage, prepared, outcome, cfg, plan.gt, command, report,
                                   deviations_ifc=plan.ifc if deviations else None,
                                   datum=datum)
        result.inputs = run_inputs(plan.sequence, plan.ifc, init, gt)
        result.timings["total"] = time.perf_counter() - t_start
        result.out_dir = out
        plan.outputs.commit(result.to_dict())
    except GlobalAlignmentError as exc:
        _commit_refusal(plan.outputs, exc, cfg, command)
        raise
    except BaseException:
        plan.outputs.abort()
        raise
    return result


def run_inputs(sequence: Any, ifc: str | PathLike[str], init: Any = None,
               gt: str | PathLike[str] | None = None) -> dict[str, str]:
    """``result.json``'s ``inputs``: the absolute paths of the sequence, the IFC, the initial
    trajectory (``init`` when a file, else the sequence's) and the ground truth (``gt``, else the
    sequence's when it has one), so that a tool reading the run finds them
    (``bimcap export-rerun``)."""
    out = {"sequence": str(Path(sequence.root).resolve()), "ifc": str(Path(ifc).resolve())}
    for key, given in (("init", init), ("gt", gt)):
        if isinstance(given, (str, PathLike)):
            out[key] = str(Path(given).resolve())
        elif given is None and sequence.has_trajectory(key):
            out[key] = str(Path(sequence.trajectory_path(key)).resolve())
    return out


@dataclass(frozen=True)
class _RecordedPlacements:
    """The ranked placements of a refused auto alignment as ``result.json`` records them
    (``to_dict`` like a ``GlobalAlignResult``'s)."""

    record: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return self.record


def refused_auto_alignment(outcome: SolveOutcome) -> Any:
    """The error of a run whose automatic global alignment refused and whose solve, from the
    initial poses as given, then diverged: the refusal is the cause (the trajectory is in a
    frame of its own that no placement fits), not the divergence. A ``GlobalAlignmentError``
    (exit status 3; ``result.json`` keeps the ranked placements), or None when the alignment
    did not run in auto mode or did not refuse."""
    from bimcap.registration.errors import GlobalAlignmentError

    ga = outcome.global_align
    if not ga or "fallback" not in ga:
        return None
    n = outcome.refined.poses.shape[0]
    frames = outcome.diverged_frames
    placements = ga.get("placements")
    return GlobalAlignmentError(
        f"only {ga['initial_free_fraction']:.0%} of the initial cameras lie in the building's "
        f"free space (a trajectory in its own SLAM frame?) and the global alignment (auto) "
        f"refused: {ga['fallback']}\nGoing on from the initial poses as given, the solve "
        f"diverged (frame(s) {frames[:10]} of {n} lie more than {DIVERGED_MARGIN_M:g} m outside "
        "the building), so no trajectory was written: check the BIM, or place the trajectory "
        "in the BIM's frame by hand",
        None if placements is None else _RecordedPlacements(placements))


def _commit_refusal(outputs: Any, exc: Any, config: RefineConfig, command: str) -> None:
    """A refused global alignment: ``result.json`` alone, with the ranked placements and the
    reason (``status: "refused"``), so that the user sees every hypothesis; no trajectory."""
    if exc.result is None:
        outputs.abort()
        return
    try:
        outputs.commit({"command": command, "config": config.to_dict(), "status": "refused",
                        "error": str(exc), "solve": {"global_align": exc.result.to_dict()}})
    except BaseException:
        outputs.abort()
        raise


def summary_table(rows: dict[str, Any]) -> str:
    """A before/after table of trajectory metrics (name → TrajectoryMetrics)."""
    lines = [f"{'':<10}{'ATE_pos [m]':>13}{'ATE_rot [deg]':>15}{'yaw':>8}{'pitch':>8}{'roll':>8}"]
    for name, tm in rows.items():
        lines.append(
            f"{name:<10}{tm.ate_pos_m.rmse:>13.4f}{tm.ate_rot_deg.rmse:>15.3f}"
            f"{tm.yaw_rmse_deg:>8.3f}{tm.pitch_rmse_deg:>8.3f}{tm.roll_rmse_deg:>8.3f}"
        )
    return "\n".join(lines)
