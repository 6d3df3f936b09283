"""End-to-end: the demo pipeline on a tiny world, the refine outputs, and the config file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bimcap.geometry import read_tum
from bimcap.pipeline.config import ConfigError, DepthSource, LabelSource, Method, RefineConfig

pytest.importorskip("bimcap._core", reason="the C++ core is not built")


@pytest.fixture(scope="module")
def tiny_demo(tmp_path_factory: pytest.TempPathFactory):
    """The demo on the tiny building: 12 frames at 1/8 ConSLAM resolution, exp2 drift."""
    from bimcap.pipeline.demo import DemoOptions, run_demo

    out = tmp_path_factory.mktemp("demo")
    cfg = RefineConfig(workers=1)
    opts = DemoOptions(preset="tiny", frames=12, scale=0.125, fps=2.0, config=cfg)
    return run_demo(out, opts, quiet=True)


@pytest.mark.slow
def test_demo_writes_every_artefact(tiny_demo) -> None:
    out = tiny_demo.out_dir
    for rel in ("world/building.ifc", "world/building_as_built.ifc", "sequence/manifest.json",
                "sequence/poses/gt.tum", "sequence/poses/init.tum", "refine/refined.tum",
                "refine/refined_facap.tum", "refine/report.html", "demo.json",
                "refine/bim/floorplan.json", "refine/summary.json", "refine/map_before.ply",
                "refine/map_after.ply", "refine/result.json"):
        assert (out / rel).is_file(), rel
    # the demo's refine directory is what `bimcap refine` writes: result.json lists every file
    listed = json.loads((out / "refine" / "result.json").read_text())
    assert {"refined", "summary", "map_before", "map_after", "report",
            "refined_facap"} <= set(listed["files"])
    assert {"refined.tum", "refined_facap.tum", "summary.json", "map_before.ply",
            "map_after.ply", "report.html"} <= set(listed["outputs"])
    before, after = (listed[k]["ate_pos_m"]["rmse"] for k in ("metrics_before", "metrics_after"))
    assert after < before
    html = (out / "refine" / "report.html").read_text()
    assert "data:image/png;base64," in html and "ATE" in html
    figures = sorted(p.name for p in (out / "refine" / "figures").glob("*.png"))
    assert "trajectories.png" in figures and any(f.startswith("side_") for f in figures)


@pytest.mark.slow
def test_demo_refinement_reduces_the_rotation_error(tiny_demo) -> None:
    """Regression bound on a tiny world (the accuracy targets are measured by bench/)."""
    res = tiny_demo.results
    before = res["initial"]["metrics"]["ate_rot_deg"]["rmse"]
    after = res["bimcap"]["metrics"]["ate_rot_deg"]["rmse"]
    assert before == pytest.approx(8.82, abs=0.01)  # the exp2 preset's calibrated drift
    assert after < 0.2 * before  # at least 80 % of the rotation error removed
    assert after < res["facap"]["metrics"]["ate_rot_deg"]["rmse"]
    # Tight bounds (measured: 1.58 cm / 0.118° at this 1/8 resolution with the LiDAR scan's
    # samples, 2.2 cm / 0.17° without): a regression to the centimetres of the drift fails here.
    assert after < 0.25
    assert res["bimcap"]["metrics"]["ate_pos_m"]["rmse"] < 0.025
    gt = read_tum(tiny_demo.out_dir / "sequence" / "poses" / "gt.tum")
    refined = read_tum(tiny_demo.out_dir / "refine" / "refined.tum")
    np.testing.assert_array_equal(refined.timestamps, gt.timestamps)


@pytest.mark.slow
def test_refine_from_the_truth_stays_there(tiny_demo, tmp_path: Path) -> None:
    """The fixed point: started from the ground truth, with the as-built IFC as the reference (the
    BIM equals the simulated world), the refined poses stay there (measured: 0.23 cm / 0.050° at
    this 1/8 resolution, 0.88 cm / 0.199° without the LiDAR scan's samples outside the camera's
    view; bench/bench_generalization.py measures it on full-size worlds). The result also says,
    per frame, what the BIM observed, and how many samples the scan gave."""
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics
    from bimcap.pipeline.refine import prepare, solve_prepared

    out = tiny_demo.out_dir
    gt = read_tum(out / "sequence" / "poses" / "gt.tum")
    cfg = RefineConfig(workers=1)
    prepared = prepare(out / "sequence", out / "world" / "building_as_built.ifc", gt, cfg,
                       tmp_path, quiet=True)
    outcome = solve_prepared(prepared, cfg, quiet=True)
    tm = trajectory_metrics(outcome.refined.poses, gt.poses, AlignMode.NONE)
    assert tm.ate_pos_m.rmse < 0.005 and tm.ate_rot_deg.rmse < 0.1
    assert prepared.scan_samples is not None and prepared.scan_samples["wall"] > 0
    obs = outcome.to_dict()["observability"]
    assert len(obs["frames"]) == len(gt) and obs["dof"][-1] == "yaw"
    assert 0 < obs["fully_observed_frames"] <= len(gt)
    # the refined trajectory follows the input's motion: the motion check finds no block
    motion = outcome.to_dict()["motion_check"]
    assert motion["failed"] is False and motion["breaks"] == []
    assert motion["segments"] == [[0, len(gt)]]
    # and no window of it fits the plan clearly better shifted (the window shift moves none)
    assert outcome.to_dict()["repair"]["window_shift"] == {"rounds": []}
    assert outcome.to_dict()["repair"]["block"] == {"moves": []}  # nor the block repair


@pytest.mark.slow
def test_demo_rerun_reuses_its_caches(tiny_demo) -> None:
    from bimcap.pipeline.demo import DemoOptions, run_demo

    opts = DemoOptions(preset="tiny", frames=12, scale=0.125, fps=2.0,
                       config=RefineConfig(workers=1), facap=False)
    again = run_demo(tiny_demo.out_dir, opts, quiet=True)
    assert again.seconds < tiny_demo.seconds
    first = tiny_demo.results["bimcap"]["metrics"]["ate_rot_deg"]["rmse"]
    assert (again.results["bimcap"]["metrics"]["ate_rot_deg"]["rmse"]
            == pytest.approx(first, rel=1e-6))


@pytest.mark.slow
def test_refine_cli_outputs_and_never_overwrites(tiny_demo, tmp_path: Path) -> None:
    from bimcap.cli import main

    seq = tiny_demo.out_dir / "sequence"
    gt_before = (seq / "poses" / "gt.tum").read_bytes()
    out = tmp_path / "run"
    rc = main(["refine", str(seq), "-o", str(out), "--terms", "F+W+Co+Ce", "--no-report", "-q",
               "--workers", "1"])
    assert rc == 0
    result = json.loads((out / "result.json").read_text())
    assert result["config"]["effective_terms"] == "F+W+Co+Ce"
    # the plane terms are checked after the solve and the check is in result.json
    check = result["solve"]["plane_check"]
    assert check["failed"] == [] and set(check["terms"]) <= {"F", "Ce"}
    assert check["terms"]["F"]["samples"] > 0 and check["terms"]["F"]["median_abs_m"] < 0.05
    assert result["solve"]["problem"]["plane_choice"]["floor"]["assigned"] > 0
    assert result["solve"]["motion_check"]["failed"] is False  # and so is the motion check
    for name in ("refined.tum", "summary.json", "map_before.ply", "map_after.ply"):
        assert (out / name).is_file()
    assert (seq / "poses" / "gt.tum").read_bytes() == gt_before
    # an output that would replace an input is refused before anything is written
    clash = tmp_path / "clash"
    clash.mkdir()
    init_copy = clash / "refined.tum"
    init_copy.write_bytes((seq / "poses" / "init.tum").read_bytes())
    before = init_copy.read_bytes()
    rc = main(["refine", str(seq), "-o", str(clash), "--init", str(init_copy), "-q"])
    assert rc == 2
    assert init_copy.read_bytes() == before
    assert sorted(p.name for p in clash.iterdir()) == ["refined.tum"]


def test_config_from_toml_and_errors(tmp_path: Path) -> None:
    f = tmp_path / "run.toml"
    f.write_text('method = "facap"\ncompletion = "linear"\n[solver]\nassociation_gate = 0.3\n'
                 '[solver.wall]\nsigma = 0.02\n')
    cfg = RefineConfig.from_toml(f, terms="G+F")
    assert cfg.method is Method.FACAP and cfg.completion is DepthSource.LINEAR
    assert cfg.effective_terms == "G+F" and cfg.effective_weighting == "paper"
    assert cfg.solver == {"association_gate": 0.3, "wall": {"sigma": 0.02}}
    from bimcap.pipeline.refine import solver_options

    opts = solver_options(cfg)
    assert opts.association_gate == 0.3 and opts.wall.sigma == 0.02
    assert opts.floor.enabled and not opts.wall.enabled

    bad = tmp_path / "bad.toml"
    bad.write_text("methd = 'facap'\n")
    with pytest.raises(ConfigError, match="unknown key") as info:
        RefineConfig.from_toml(bad)
    assert str(bad) in str(info.value)
    bad.write_text("method = [\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        RefineConfig.from_toml(bad)
    with pytest.raises(ConfigError, match="completion_model"):
        RefineConfig(completion=DepthSource.HYBRID)
    with pytest.raises(ConfigError, match="labels_dir"):
        RefineConfig(segmentation=LabelSource.DISK)


def test_schedule_for_maps_config_onto_stages() -> None:
    from bimcap.optimize.options import RefineMode
    from bimcap.pipeline.refine import schedule_for, solver_options, stage_options

    def names(c: RefineConfig) -> list[str]:
        return [s.name for s in schedule_for(c).stages]

    assert names(RefineConfig()) == ["coarse", "all"]
    assert names(RefineConfig(coarse=False)) == ["all"]
    assert names(RefineConfig(method=Method.FACAP)) == ["all"]  # the peers' method: no coarse
    assert names(RefineConfig(method=Method.FACAP, coarse=True)) == ["coarse", "all"]
    assert names(RefineConfig(staged=True)) == ["coarse", "bim", "all"]
    assert names(RefineConfig(coarse=False, rotation_first=True)) == ["all_rotation",
                                                                      "all_translation", "all"]
    assert names(RefineConfig(staged=True, rotation_first=True)) == [
        "coarse", "bim_rotation", "bim_translation", "bim", "all"]
    cfg = RefineConfig(staged=True, terms="G+F+W")
    base = solver_options(cfg)
    bim, full = [s for s in schedule_for(cfg).stages if s.name != "coarse"]
    o = stage_options(base, bim, cfg)
    assert o is not None
    assert (o.geometric.enabled, o.floor.enabled, o.wall.enabled, o.column.enabled) == (
        False, True, True, False)  # the BIM terms of the configured ones only
    assert o.wall.loss_scale == pytest.approx(4 * base.wall.loss_scale)
    assert base.wall.loss_scale == pytest.approx(stage_options(base, full, cfg).wall.loss_scale)
    rot = schedule_for(RefineConfig(coarse=False, rotation_first=True)).stages[0]
    assert stage_options(base, rot, cfg).refine_mode is RefineMode.ROTATION
    # A BIM-only stage with no BIM term configured is skipped, not an error.
    g_only = RefineConfig(staged=True, terms="G")
    assert stage_options(solver_options(g_only), bim, g_only) is None


@pytest.mark.slow
def test_staged_and_rotation_first_runs(tiny_demo) -> None:
    """The issue-7 schedule end to end: coarse → BIM terms with wide losses → all terms, each
    stage rotation first; every stage reports and the rotation error still falls."""
    from bimcap.dataset import read_sequence
    from bimcap.evaluation.metrics import AlignMode, trajectory_metrics
    from bimcap.pipeline.refine import prepare, solve_prepared

    out = tiny_demo.out_dir
    seq = read_sequence(out / "sequence")
    cfg = RefineConfig(workers=1, staged=True, rotation_first=True)
    prep = prepare(seq, None, None, cfg, out / "refine", quiet=True)
    res = solve_prepared(prep, cfg, quiet=True)
    # bim_rotation, bim_translation, bim, all, all again with every LiDAR scan sample, and once
    # more at the scan's noise scale (+ the re-solves after samples changed plane, + a kept
    # repair)
    assert prep.first_frontend is not None
    kept = sum(bool(r and r.get("accepted")) for r in (res.repair, (res.repair or {}).get(
        "odometry")))
    assert len(res.summaries) == 6 + res.plane_resolves + kept
    gt = seq.trajectory("gt").poses
    before = trajectory_metrics(prep.init.poses, gt, AlignMode.NONE).ate_rot_deg.rmse
    after = trajectory_metrics(res.refined.poses, gt, AlignMode.NONE).ate_rot_deg.rmse
    assert after < 0.3 * before


@pytest.mark.slow
def test_experiment_tables_on_a_tiny_world(tmp_path: Path) -> None:
    """``bimcap experiment`` end to end on the tiny world: one preset, one seed, two rows."""
    import csv

    from bimcap.pipeline.experiment import ExperimentOptions, run_experiment

    opts = ExperimentOptions(experiments=("exp2",), seeds=(1,),
                             ablations=((Method.BIMCAP, "G+F+W+Co+Ce"), (Method.FACAP, "G+F+W")),
                             preset="tiny", frames=12, scale=0.125,
                             config=RefineConfig(workers=1))
    records = run_experiment(tmp_path, opts, quiet=True)
    assert [(r.method, r.terms) for r in records] == [
        ("initial", "-"), ("bimcap", "G+F+W+Co+Ce"), ("facap", "G+F+W")]
    assert all(r.ok for r in records), [r.message for r in records]
    init, bimcap, facap = records
    assert init.values["ate_rot_deg"] == pytest.approx(8.82, abs=0.01)
    assert bimcap.values["ate_rot_deg"] < 0.3 * init.values["ate_rot_deg"]
    assert 0.0 < bimcap.coarse_seconds < bimcap.seconds  # BIMCaP rows run the coarse stage
    assert facap.coarse_seconds == 0.0  # FACaP rows are the peers' method
    with (tmp_path / "results.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 and float(rows[1]["coarse_seconds"]) == pytest.approx(
        bimcap.coarse_seconds)
    t1 = (tmp_path / "table1.md").read_text()
    t2 = (tmp_path / "table2.md").read_text()
    assert "## exp2" in t1
    assert "| bimcap | ✓ | ✓ | ✓ | ✓ | ✓ |" in t1 and "| facap | ✓ | ✓ | ✓ | – | – |" in t1
    assert "| exp2 | bimcap |" in t2 and "| exp2 | initial | 30.30 [30.30] |" in t2
    assert (tmp_path / "ate.png").stat().st_size > 1000


def test_schedule_flags_reach_the_config(tmp_path: Path) -> None:
    import argparse

    from bimcap.cli.refine import add_config_arguments, config_from_args

    p = argparse.ArgumentParser()
    add_config_arguments(p)
    cfg = config_from_args(p.parse_args(["--staged", "--rotation-first", "--no-coarse"]))
    assert (cfg.staged, cfg.rotation_first, cfg.coarse, cfg.effective_coarse) == (
        True, True, False, False)
    assert config_from_args(p.parse_args([])).effective_coarse  # BIMCaP: on by default
    toml = tmp_path / "run.toml"
    toml.write_text('method = "facap"\nstaged = true\n')
    cfg = config_from_args(p.parse_args(["--config", str(toml)]))
    assert cfg.staged and not cfg.effective_coarse  # FACaP: off unless asked
    assert cfg.to_dict()["effective_coarse"] is False


def test_lidar_scan_setting(tmp_path: Path) -> None:
    """On for BIMCaP, off for FACaP (the peers sample the image alone), settable both ways."""
    assert RefineConfig().effective_lidar_scan
    assert not RefineConfig(method=Method.FACAP).effective_lidar_scan
    assert RefineConfig(method=Method.FACAP, lidar_scan=True).effective_lidar_scan
    f = tmp_path / "run.toml"
    f.write_text("lidar_scan = false\n")
    assert not RefineConfig.from_toml(f).effective_lidar_scan
    f.write_text('lidar_scan = "yes"\n')
    with pytest.raises(ConfigError, match="lidar_scan"):
        RefineConfig.from_toml(f)


def test_scan_sigma_setting(tmp_path: Path) -> None:
    """The last solve with the scan's samples weighs the BIM terms at ``scan_sigma_m`` (2 cm by
    default), the other terms as the preset does; None keeps the preset; bad values are named."""
    from bimcap.pipeline.refine import scan_stage_options, solver_options

    cfg = RefineConfig()
    base = solver_options(cfg)
    opts = scan_stage_options(base, cfg)
    for key in ("wall", "column", "floor", "ceiling"):
        assert opts.terms[key].sigma == pytest.approx(0.02)
        assert base.terms[key].sigma == pytest.approx(0.05)  # a copy: the schedule's unchanged
    assert opts.terms["geometric"].sigma == base.terms["geometric"].sigma
    none = RefineConfig(scan_sigma_m=None)
    assert scan_stage_options(base, none).terms["wall"].sigma == pytest.approx(0.05)
    f = tmp_path / "run.toml"
    f.write_text("scan_sigma_m = 0.03\n")
    assert RefineConfig.from_toml(f).scan_sigma_m == pytest.approx(0.03)
    for bad in (0.0, -0.01, 2.0, True, "2cm"):
        with pytest.raises(ConfigError, match="scan_sigma_m"):
            RefineConfig(scan_sigma_m=bad)  # type: ignore[arg-type]


def test_diverged_frames_are_named() -> None:
    """A camera far outside the building (or not finite) is a diverged frame, not a result."""
    from types import SimpleNamespace

    from bimcap.pipeline.refine import diverged_frames

    ref = SimpleNamespace(segments=np.array([[0.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 8.0]]),
                          segment_z=np.array([[0.0, 3.0], [0.0, 3.0]]))
    poses = np.tile([5.0, 4.0, 1.5, 0.0, 0.0, 0.0, 1.0], (5, 1))
    poses[1, 0] = 25.0          # 15 m east of the plan: diverged
    poses[2, 1] = -9.0          # 9 m south: within the 10 m margin
    poses[3, 2] = -5.5e8        # FACaP's plain L2 on an unconstrained frame
    poses[4, 3] = np.nan
    assert diverged_frames(poses, ref) == [1, 3, 4]
    assert diverged_frames(poses, ref, margin_m=5.0) == [1, 2, 3, 4]


@pytest.mark.slow
def test_refine_refuses_a_diverged_solve(tiny_demo, tmp_path: Path, monkeypatch) -> None:
    """A solve that leaves frames far outside the building is an error (exit 3 from the CLI),
    with nothing written: never exit 0 with an unusable trajectory."""
    from dataclasses import replace

    from bimcap.cli import main
    from bimcap.pipeline import refine as refine_module

    real = refine_module.solve_prepared

    def diverging(*args, **kwargs):
        return replace(real(*args, **kwargs), diverged_frames=[3])

    monkeypatch.setattr(refine_module, "solve_prepared", diverging)
    out = tmp_path / "run"
    rc = main(["refine", str(tiny_demo.out_dir / "sequence"), "-o", str(out), "--no-report",
               "-q", "--workers", "1", "--colmap", "off"])
    assert rc == 3
    assert not (out / "refined.tum").exists() and not (out / "result.json").exists()


def test_auto_global_alignment_that_fits_nothing_goes_on_from_the_input(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """Auto mode guesses a SLAM frame from where the cameras stand; when no placement then fits
    (a drifted 250-frame walk 1.4 m off in a small house: fewer than 30 % of its cameras in free
    space), the run goes on from the input with a warning instead of failing. Asked for
    explicitly, or ambiguous, the alignment still refuses."""
    import logging
    from types import SimpleNamespace

    import bimcap.pipeline.refine as refine
    import bimcap.registration as registration
    from bimcap.pipeline.config import GlobalAlignMode
    from bimcap.registration.errors import AmbiguousAlignmentError, GlobalAlignmentError

    poses = np.tile([1.0, 2.0, 1.5, 0.0, 0.0, 0.0, 1.0], (4, 1))
    raised: list[Exception] = []

    def fake_align(*args: Any, **kwargs: Any) -> Any:
        raise raised[0]

    monkeypatch.setattr(registration, "global_align", fake_align)
    monkeypatch.setattr(registration, "initial_free_fraction", lambda p, plan: 0.1)
    monkeypatch.setattr(refine, "_floor_plan", lambda ref: None)
    monkeypatch.setattr(refine, "_semantic_samples", lambda prepared: None)
    prepared = SimpleNamespace(reference=None)
    raised.append(GlobalAlignmentError("the best placement fits badly"))
    with caplog.at_level(logging.WARNING, logger="bimcap"):
        out, info = refine._global_align(prepared, poses, RefineConfig())  # type: ignore[arg-type]
    np.testing.assert_array_equal(out, poses)
    assert info is not None and info["mode"] == "auto" and "fits badly" in info["fallback"]
    assert any("going on from the initial poses" in r.message for r in caplog.records)
    with pytest.raises(GlobalAlignmentError):
        refine._global_align(prepared, poses,  # type: ignore[arg-type]
                             RefineConfig(global_align=GlobalAlignMode.ON))
    raised[0] = AmbiguousAlignmentError("two placements score alike")
    with pytest.raises(AmbiguousAlignmentError):
        refine._global_align(prepared, poses, RefineConfig())  # type: ignore[arg-type]


def test_the_global_alignment_takes_as_many_threads_as_the_front_end_has_workers(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``--workers N`` caps the global alignment's threads too (``num_threads = N``); without it
    the alignment takes every core (0)."""
    from types import SimpleNamespace

    import bimcap.pipeline.refine as refine
    import bimcap.registration as registration
    from bimcap.pipeline.config import GlobalAlignMode

    seen: list[int] = []

    def fake_align(poses: Any, samples: Any, plan: Any, options: Any, *args: Any) -> Any:
        seen.append(options.num_threads)
        raise registration.GlobalAlignmentError("stop here")

    monkeypatch.setattr(registration, "global_align", fake_align)
    monkeypatch.setattr(registration, "initial_free_fraction", lambda p, plan: 0.1)
    monkeypatch.setattr(refine, "_floor_plan", lambda ref: None)
    monkeypatch.setattr(refine, "_semantic_samples", lambda prepared: None)
    monkeypatch.setattr(refine, "_align_without_missing_wall", lambda *a, **k: None)
    prepared = SimpleNamespace(reference=None)
    poses = np.tile([1.0, 2.0, 1.5, 0.0, 0.0, 0.0, 1.0], (4, 1))
    for workers, expected in ((1, 1), (3, 3), (None, 0)):
        with pytest.raises(registration.GlobalAlignmentError):
            refine._global_align(prepared, poses,  # type: ignore[arg-type]
                                 RefineConfig(global_align=GlobalAlignMode.ON, workers=workers))
        assert seen[-1] == expected


def test_a_refused_auto_alignment_is_the_error_of_a_diverged_run() -> None:
    """Auto mode, the alignment refused, the run went on from the poses as given and diverged:
    the error is the refusal (a ``GlobalAlignmentError`` keeping the ranked placements for
    ``result.json``), not the divergence (pipeline seed 3 of bench/bench_global.py)."""
    from types import SimpleNamespace

    import bimcap.pipeline.refine as refine
    from bimcap.registration.errors import GlobalAlignmentError

    ga = {"mode": "auto", "initial_free_fraction": 0.0, "seconds": 1.0,
          "fallback": "global alignment: the best placement fits badly (...)",
          "placements": {"hypotheses": [{"score": 0.04}]}}
    outcome = SimpleNamespace(global_align=ga, diverged_frames=[0, 1, 2],
                              refined=SimpleNamespace(poses=np.zeros((60, 7))))
    exc = refine.refused_auto_alignment(outcome)  # type: ignore[arg-type]
    assert isinstance(exc, GlobalAlignmentError)
    assert "refused: global alignment: the best placement fits badly" in str(exc)
    assert "diverged" in str(exc) and "0%" in str(exc)
    assert exc.result.to_dict() == ga["placements"]
    for other in (None, {"mode": "on", "hypotheses": []}):
        outcome.global_align = other
        assert refine.refused_auto_alignment(outcome) is None  # type: ignore[arg-type]
