"""``bimcap demo``: the whole product on the embedded synthetic world, in one command.

Generate a building (design IFC + as-built variant) → simulate a camera + LiDAR sequence in the
as-built world → apply the paper's ``exp2`` drift → BIM reference → front end with the
no-weights paths (LiDAR + linear interpolation, geometric segmenter) → FACaP and BIMCaP solves →
metrics → before/after table and an HTML report.
"""

from __future__ import annotations

import contextlib
import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from bimcap.errors import InputError
from bimcap.io.atomic import atomic_write_json
from bimcap.logs import quieted
from bimcap.pipeline.config import Method, RefineConfig
from bimcap.pipeline.refine import REFINE_OUTPUTS
from bimcap.sim.walk import DEFAULT_PITCH_DEG

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DemoOptions:
    """What the demo world looks like and how it is processed.

    Attributes
    ----------
    preset: building preset of ``bimcap.sim.building`` (``demo``, ``tiny``, ``tower``).
    seed: seed of the building, the as-built deviations, the walk and the drift.
    frames: number of simulated frames.
    scale: image size relative to ConSLAM's 2064×1544.
    fps: camera frame rate (Hz).
    pitch_deg: mean camera pitch of the handheld walk (negative looks down; ConSLAM's narrow field
        of view sees the floor only when the camera looks a little down); the walk's default,
        :data:`bimcap.sim.walk.DEFAULT_PITCH_DEG`, which ``bimcap simulate`` uses too. The walk
        glances up now and then (``WalkConfig.pitch_amplitude_deg``), which shows the ceiling.
    drift: drift preset (``exp1``, ``exp2``, ``exp3``).
    config: the BIMCaP run's settings (FACaP runs with ``method=facap`` on the same front end).
    facap: also solve with FACaP, for the side-by-side table.
    """

    preset: str = "demo"
    seed: int = 0
    frames: int = 60
    scale: float = 0.25
    fps: float = 2.0
    pitch_deg: float = DEFAULT_PITCH_DEG
    drift: str = "exp2"
    config: RefineConfig = field(default_factory=RefineConfig)
    facap: bool = True

    def to_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in ("preset", "seed", "frames", "scale", "fps", "pitch_deg",
                                           "drift", "facap")}
        d["config"] = self.config.to_dict()
        return d


def make_world(out: Path, opts: DemoOptions, quiet: bool | None = None) -> tuple[Path, Path]:
    """Write the design and as-built IFC of the demo building; return their paths. ``quiet``:
    deprecated (:func:`bimcap.logs.quieted`)."""
    with quieted(quiet):
        return _make_world(out, opts)


def _make_world(out: Path, opts: DemoOptions) -> tuple[Path, Path]:
    """:func:`make_world`."""
    from bimcap.sim.building import PRESETS, as_built, generate_building

    world = out / "world"
    design_path, built_path = world / "building.ifc", world / "building_as_built.ifc"
    if design_path.is_file() and built_path.is_file():
        return design_path, built_path
    world.mkdir(parents=True, exist_ok=True)
    _log.info(f"generating the '{opts.preset}' building (seed {opts.seed})")
    if opts.preset not in PRESETS:
        raise InputError(f"unknown building preset {opts.preset!r}; use one of {sorted(PRESETS)}",
                         field="preset")
    spec = PRESETS[opts.preset]
    design = generate_building(spec, seed=opts.seed, ifc_path=design_path)
    as_built(design, seed=opts.seed + 1, ifc_path=built_path)
    return design_path, built_path


def make_sequence(out: Path, design: Path, built: Path, opts: DemoOptions,
                  quiet: bool | None = None) -> Path:
    """Simulate the sequence in the as-built world and write the drifted ``init.tum``.
    ``quiet``: deprecated (:func:`bimcap.logs.quieted`)."""
    with quieted(quiet):
        return _make_sequence(out, design, built, opts)


def _make_sequence(out: Path, design: Path, built: Path, opts: DemoOptions) -> Path:
    """:func:`make_sequence`."""
    from bimcap.dataset import add_trajectory, read_sequence
    from bimcap.sim.drift import DriftParams, apply_drift
    from bimcap.sim.simulator import CONSLAM_CAMERA, SimulatorConfig, simulate
    from bimcap.sim.walk import WalkConfig

    seq_dir = out / "sequence"
    if not (seq_dir / "manifest.json").is_file():
        _log.info(f"simulating {opts.frames} frames at {opts.scale:g}x ConSLAM resolution")
        cfg = SimulatorConfig(
            camera=CONSLAM_CAMERA.scaled(opts.scale), frames=opts.frames, fps=opts.fps,
            walk=WalkConfig(pitch_deg=opts.pitch_deg), workers=0,
        )
        simulate(design, seq_dir, cfg, seed=opts.seed, as_built_ifc=built)
    seq = read_sequence(seq_dir)
    if not seq.has_trajectory("init"):
        params = DriftParams.from_preset(opts.drift, seed=opts.seed + 1)
        drift = apply_drift(seq.trajectory("gt"), params)
        _log.info(f"drift {opts.drift}: ATE {drift.ate_pos:.3f} m / {drift.ate_rot:.2f} deg")
        add_trajectory(seq, "init", drift.init, header=f"bimcap drift {opts.drift}")
        atomic_write_json(seq_dir / "poses" / "init.drift.json", drift.to_dict())
    return seq_dir


@dataclass
class DemoResult:
    out_dir: Path
    report: Path
    table: str
    seconds: float
    results: dict[str, Any]


#: The files the demo's refine step writes into ``OUT/refine`` (as a set with ``result.json``):
#: those of ``bimcap refine`` and FACaP's trajectory.
DEMO_OUTPUTS = (*REFINE_OUTPUTS, "refined_facap.tum")


def validate_demo(opts: DemoOptions) -> None:
    """Every setting of the demo, before anything is generated: the building and drift presets,
    frame count and scale, and the BIMCaP and FACaP solver settings."""
    from bimcap.pipeline.refine import validate_settings
    from bimcap.sim.building import PRESETS
    from bimcap.sim.drift import PRESETS as DRIFT_PRESETS

    if opts.preset not in PRESETS:
        raise InputError(f"unknown building preset {opts.preset!r}; use one of {sorted(PRESETS)}",
                         field="preset")
    if opts.drift not in DRIFT_PRESETS:
        raise InputError(f"unknown drift preset {opts.drift!r}; use one of "
                         f"{sorted(DRIFT_PRESETS)}", field="drift")
    if opts.frames < 2:
        raise InputError(f"need at least 2 frames, got {opts.frames}", field="frames")
    if not opts.scale > 0 or not opts.fps > 0:
        raise InputError(f"scale and fps must be > 0, got {opts.scale} and {opts.fps}",
                         field="scale/fps")
    validate_settings(opts.config)
    if opts.facap:
        validate_settings(facap_config(opts.config))


def facap_config(config: RefineConfig) -> RefineConfig:
    """The FACaP run beside BIMCaP: the same front end, FACaP's objective and schedule."""
    return replace(config, method=Method.FACAP, terms=None, weighting=None, coarse=False)


def run_demo(out_dir: str | Path, opts: DemoOptions | None = None, quiet: bool | None = None,
             overwrite: bool = False) -> DemoResult:
    """Run the demo into ``out_dir`` (re-running reuses what is already there).

    Settings are checked first (:func:`validate_demo`) and so is ``OUT/refine``: a file there
    that bimcap did not write is replaced only with ``overwrite``. ``OUT/refine`` holds what
    ``bimcap refine`` writes (:func:`bimcap.pipeline.refine.write_run_outputs`: ``refined.tum``,
    ``summary.json``, the semantic maps, ``report.html`` and ``figures/``) plus
    ``refined_facap.tum``, as one set with ``OUT/refine/result.json``
    (:class:`bimcap.io.outputs.OutputSet`). Every step is logged (this module's logger and
    :mod:`bimcap.pipeline.refine`'s); ``quiet`` is deprecated (:func:`bimcap.logs.quieted`).
    """
    with quieted(quiet):
        return _run_demo(out_dir, opts, overwrite)


def _run_demo(out_dir: str | Path, opts: DemoOptions | None, overwrite: bool) -> DemoResult:
    """:func:`run_demo`."""
    from bimcap.io.outputs import OutputSet

    o = opts or DemoOptions()
    validate_demo(o)
    out = Path(out_dir)
    run_dir = out / "refine"
    # A demo directory of a bimcap before output sets (demo.json, no refine/result.json): its
    # refine files are the demo's own.
    legacy = (out / "demo.json").is_file() and not (run_dir / "result.json").exists()
    outputs = OutputSet(run_dir, DEMO_OUTPUTS, overwrite=overwrite or legacy)
    outputs.check()
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        t0 = time.perf_counter()
        design, built = make_world(out, o)
        seq_dir = make_sequence(out, design, built, o)
        result, results, table = _refine_step(out, seq_dir, design, o, outputs)
        seconds = time.perf_counter() - t0
        results.update(seconds=seconds)
        atomic_write_json(out / "demo.json", results)
    except BaseException:
        outputs.abort()
        if created:
            with contextlib.suppress(OSError):
                out.rmdir()  # only when the failed run left it empty
        raise
    return DemoResult(out, run_dir / result.files["report"], table, seconds, results)


def _refine_step(out: Path, seq_dir: Path, design: Path, o: DemoOptions,
                 outputs: Any) -> tuple[Any, dict[str, Any], str]:
    """FACaP (with ``o.facap``) and BIMCaP on one front end, written into the open ``outputs``
    as ``bimcap refine`` writes them; returns the committed refine result, ``demo.json``'s
    content (without the time) and the before/after table."""
    from bimcap.geometry import write_tum
    from bimcap.pipeline.refine import (
        evaluate_run,
        g_unit,
        prepare,
        run_inputs,
        solve_prepared,
        summary_table,
        write_run_outputs,
    )
    from bimcap.pipeline.report import RunRow

    run_dir = out / "refine"
    prepared = prepare(seq_dir, design, None, o.config, run_dir)
    gt = prepared.sequence.trajectory("gt")
    stage = outputs.open()
    results: dict[str, Any] = {"options": o.to_dict()}
    extra = []
    facap_metrics = None
    if o.facap:
        fcfg = facap_config(o.config)
        facap = solve_prepared(prepared, fcfg)
        facap_metrics, mm = evaluate_run(prepared, facap.refined, gt)
        extra.append(RunRow(f"facap {fcfg.effective_terms}", facap.refined.poses, facap_metrics,
                            mm, facap.summary, facap.seconds, outcome=facap,
                            terms=fcfg.effective_terms, g_unit=g_unit(fcfg)))
        write_tum(stage / "refined_facap.tum", facap.refined, header="FACaP refined world_from_cam")
        results["facap"] = {"metrics": facap_metrics.to_dict(),
                            "map": None if mm is None else mm.to_dict()}
    outcome = solve_prepared(prepared, o.config)
    command = (f"bimcap demo -o {out} --building {o.preset} --seed {o.seed} --frames {o.frames} "
               f"--scale {o.scale} --drift {o.drift}")
    result = write_run_outputs(stage, prepared, outcome, o.config, gt, command,
                               extra_rows=extra)
    if o.facap:
        result.files["refined_facap"] = "refined_facap.tum"
    result.inputs = run_inputs(prepared.sequence, design)
    result.out_dir = run_dir
    outputs.commit(result.to_dict())
    metrics = {"initial": result.metrics_before}
    if facap_metrics is not None:
        metrics["FACaP"] = facap_metrics
    metrics["BIMCaP"] = result.metrics_after
    results.update(initial={"metrics": result.metrics_before.to_dict()},
                   bimcap={"metrics": result.metrics_after.to_dict(),
                           "map": None if result.map_after is None else result.map_after.to_dict(),
                           "summary": outcome.to_dict()})
    return result, results, summary_table(metrics)
