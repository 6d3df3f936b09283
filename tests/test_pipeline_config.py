"""Run settings: solver presets, the [solver], [registration] and [features] tables, --print-config.

Every solver default comes from the C++ presets (``SolverOptions::Preset``); the refine pipeline
adds nothing silently. ``bimcap refine --print-config`` prints every setting, and the printed
file read back with ``--config`` gives the same solver and registration options.
"""

from __future__ import annotations

import contextlib
import io
import itertools
from dataclasses import asdict
from pathlib import Path

import pytest

from bimcap.cli import main
from bimcap.optimize import GeometricMode, Loss, PlaneMode, Preset, SolverOptions, Weighting
from bimcap.optimize.errors import SolverInputError
from bimcap.pipeline.config import GEOMETRIC_MODES, LOSSES, ConfigError, RefineConfig
from bimcap.pipeline.refine import (
    coarse_options,
    geometric_options,
    make_providers,
    match_options,
    sift_options,
    solver_options,
    validate_settings,
)
from bimcap.registration import CoarseOptions


def test_config_choices_are_the_solver_enums() -> None:
    assert set(LOSSES) == {loss.value.lower() for loss in Loss}
    assert set(GEOMETRIC_MODES) == {mode.value.lower() for mode in GeometricMode}


def test_presets_come_from_the_core() -> None:
    robust = SolverOptions.preset(Preset.ROBUST)
    assert robust.weighting is Weighting.ROBUST
    assert robust.geometric_mode is GeometricMode.REPROJECTION
    assert robust.pixel_sigma == 2.0 and robust.floor.sigma == 0.05 and robust.depth.sigma == 0.02
    assert all(robust.terms[k].loss is Loss.CAUCHY
               for k in ("geometric", "floor", "ceiling", "wall", "column"))
    assert robust.prior.loss is SolverOptions().prior.loss  # not a paper term: its own
    paper = SolverOptions.preset("paper")
    assert paper.weighting is Weighting.PAPER and paper.geometric_mode is GeometricMode.POINT
    assert SolverOptions.paper(max_iterations=3).to_flat() == \
        SolverOptions.preset("paper", max_iterations=3).to_flat()
    with pytest.raises(SolverInputError, match="preset") as info:
        SolverOptions.preset("fast")
    assert info.value.field == "preset"


def test_refine_options_are_the_preset_and_nothing_else() -> None:
    # BIMCaP: exactly the robust preset (every term of the method on).
    assert solver_options(RefineConfig()).to_flat() == SolverOptions.preset("robust").to_flat()
    # FACaP: the paper preset with its point error and a floor plane fitted to the scan.
    facap = solver_options(RefineConfig(method="facap"))
    expected = SolverOptions.preset("paper").with_terms("G+F+W")
    expected.plane_mode = PlaneMode.FACAP
    assert facap.to_flat() == expected.to_flat()


def test_solver_table_wins_over_loss_and_geometric_mode() -> None:
    cfg = RefineConfig(loss="huber", geometric_mode="point",
                       solver={"geometric_mode": "landmark", "wall": {"loss": "tukey"},
                               "prior": {"sigma_r_deg": 5.0}})
    opts = solver_options(cfg)
    assert opts.geometric_mode is GeometricMode.LANDMARK
    assert opts.wall.loss is Loss.TUKEY and opts.floor.loss is Loss.HUBER
    assert opts.prior.params["sigma_r_deg"] == 5.0
    with pytest.raises(ConfigError, match="loss"):
        RefineConfig(loss="l2")
    with pytest.raises(SolverInputError, match=r"wall\.sigma"):
        solver_options(RefineConfig(solver={"wall": {"sigma": -1.0}}))


def test_registration_table_reaches_coarse_options() -> None:
    assert CoarseOptions().frame_orientation  # the pipeline's choice is the default
    opts = coarse_options(RefineConfig(registration={"xy_range_m": 3, "use_icp": False}))
    assert opts.xy_range_m == 3.0 and isinstance(opts.xy_range_m, float) and not opts.use_icp
    for table, key in (({"xy_rang_m": 1.0}, "registration.xy_rang_m"),
                       ({"use_icp": 1}, "registration.use_icp"),
                       ({"window_frames": 2.5}, "registration.window_frames"),
                       ({"xy_range_m": -1.0}, "registration.xy_range_m")):
        with pytest.raises(ConfigError) as info:
            validate_settings(RefineConfig(registration=table))
        assert info.value.field == key, table
    with pytest.raises(ConfigError, match="registration"):
        RefineConfig(registration=[1])  # type: ignore[arg-type]


def test_features_table_reaches_the_sift_options(tmp_path: Path) -> None:
    from bimcap.features.sift import SiftBackend, SiftOptions

    assert sift_options(RefineConfig()) == SiftOptions()
    opts = sift_options(RefineConfig(features={"backend": "opencv", "max_image_size": 800,
                                               "peak_threshold": 0.01}))
    assert opts.backend is SiftBackend.OPENCV and opts.max_image_size == 800
    orb = sift_options(RefineConfig(features={"backend": "orb", "orb_max_num_features": 1024}))
    assert orb.backend is SiftBackend.ORB and orb.orb_max_num_features == 1024
    toml = tmp_path / "orb.toml"
    toml.write_text('[features]\nbackend = "orb"\n', encoding="utf-8")
    assert sift_options(RefineConfig.from_toml(toml)).backend is SiftBackend.ORB
    for table, key in (({"backend": "surf"}, "features.backend"),
                       ({"max_features": 10}, "features.max_features"),
                       ({"first_octave": 0.5}, "features.first_octave"),
                       ({"max_image_size": "big"}, "features.max_image_size"),
                       ({"max_num_features": 0}, "features")):
        with pytest.raises(ConfigError) as info:
            validate_settings(RefineConfig(features=table))
        assert info.value.field == key, table


def test_matching_table_reaches_the_front_end(tmp_path: Path) -> None:
    from bimcap.features import MatchOptions, Verification

    assert match_options(RefineConfig()) == MatchOptions()
    toml = tmp_path / "run.toml"
    toml.write_text('[matching]\nransac_min_trials = 30\nverification = "fundamental"\n')
    opts = match_options(RefineConfig.from_toml(toml))
    assert opts.ransac_min_trials == 30 and opts.verification is Verification.FUNDAMENTAL
    assert opts.max_ratio == MatchOptions().max_ratio
    for table, key in (({"ransac_min_trials": 0}, "matching"),
                       ({"ransac_min_trials": 2.5}, "matching.ransac_min_trials"),
                       ({"min_trials": 30}, "matching.min_trials"),
                       ({"verification": "affine"}, "matching.verification")):
        with pytest.raises(ConfigError) as info:
            validate_settings(RefineConfig(matching=table))
        assert info.value.field == key, table
    with pytest.raises(ConfigError, match="matching"):
        RefineConfig(matching=[1])  # type: ignore[arg-type]


def test_geometric_table_reaches_the_segmenter(tmp_path: Path) -> None:
    from bimcap.segmentation.geometric import GeometricOptions

    assert geometric_options(RefineConfig()) == GeometricOptions()
    toml = tmp_path / "run.toml"
    toml.write_text("[geometric]\nwork_width = 129\nransac_iterations = 60\n")
    config = RefineConfig.from_toml(toml)
    opts = geometric_options(config)
    assert (opts.work_width, opts.ransac_iterations) == (129, 60)
    assert opts.plane_threshold_m == GeometricOptions().plane_threshold_m

    class _Seq:  # make_providers reads only what the sources need
        has_labels = False
        has_depth = False

    _, labels, _ = make_providers(config, _Seq())  # type: ignore[arg-type]
    assert labels.segmenter.options == opts
    for table, key in (({"work_width": 16}, "geometric.work_width"),
                       ({"work_px": 100}, "geometric.work_px"),
                       ({"work_width": 1.5}, "geometric.work_width")):
        with pytest.raises(ConfigError) as info:
            validate_settings(RefineConfig(geometric=table))
        assert info.value.field == key, table
    with pytest.raises(ConfigError, match="geometric"):
        RefineConfig(geometric=[1])  # type: ignore[arg-type]


def _print_config(*flags: str) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["refine", "--print-config", *flags]) == 0
    return out.getvalue()


def test_print_config_shows_the_matching_default(tmp_path: Path) -> None:
    """The default of 2026-11-27 (10 RANSAC trials) is printed, and the previous one (100,
    pycolmap's own) reads back from a TOML file."""
    text = _print_config()
    matching = text.partition("[matching]")[2].partition("\n[")[0]
    assert "ransac_min_trials = 10" in matching.splitlines()
    assert 'product = "int8"' in matching.splitlines()
    floats = tmp_path / "float32.toml"
    floats.write_text('[matching]\nproduct = "float32"\n')
    assert 'product = "float32"' in _print_config("--config", str(floats)).splitlines()
    assert match_options(RefineConfig.from_toml(floats)).product.value == "float32"
    old = tmp_path / "old.toml"
    old.write_text("[matching]\nransac_min_trials = 100\n")
    printed = _print_config("--config", str(old))
    assert "ransac_min_trials = 100" in printed.splitlines()
    assert match_options(RefineConfig.from_toml(old)).ransac_min_trials == 100


@pytest.mark.parametrize("flags", [
    (),
    ("--method", "facap"),
    ("--weighting", "paper", "--loss", "huber", "--terms", "G+F+W"),
    ("--geometric", "landmark", "--no-coarse", "--window", "2", "--workers", "1"),
])
def test_print_config_reads_back_to_the_same_run(tmp_path: Path, flags: tuple[str, ...]) -> None:
    given = tmp_path / "given.toml"
    given.write_text("[solver]\nassociation_gate = 0.3\n[solver.wall]\nsigma = 0.02\n"
                     "[registration]\nxy_range_m = 1.5\nview_bins = 2\n"
                     "[features]\nbackend = \"opencv\"\n[matching]\nransac_min_trials = 30\n"
                     "[geometric]\nwork_width = 200\n")
    text = _print_config("--config", str(given), *flags)
    assert "[solver.wall]" in text and "[registration]" in text
    printed = tmp_path / "printed.toml"
    printed.write_text(text)
    original = RefineConfig.from_toml(given, **_overrides(flags))
    again = RefineConfig.from_toml(printed)
    assert solver_options(again).to_flat() == solver_options(original).to_flat()
    assert asdict(coarse_options(again)) == asdict(coarse_options(original))
    assert sift_options(again) == sift_options(original) and sift_options(again).backend.value == \
        "opencv"
    assert match_options(again) == match_options(original)
    assert match_options(again).ransac_min_trials == 30
    assert geometric_options(again) == geometric_options(original)
    assert geometric_options(again).work_width == 200
    assert coarse_options(again).xy_range_m == 1.5 and solver_options(again).wall.sigma == 0.02
    for name in ("method", "completion", "segmentation", "window", "workers", "effective_terms",
                 "effective_weighting", "effective_coarse", "effective_solve_match_distance"):
        assert getattr(again, name) == getattr(original, name), name
    # Printing the printed file changes nothing.
    assert _print_config("--config", str(printed)).split("\n", 1)[1] == text.split("\n", 1)[1]


def _overrides(flags: tuple[str, ...]) -> dict[str, object]:
    names = {"--method": "method", "--weighting": "weighting", "--loss": "loss",
             "--terms": "terms", "--geometric": "geometric_mode", "--window": "window",
             "--workers": "workers"}
    out: dict[str, object] = {"coarse": False} if "--no-coarse" in flags else {}
    for flag, value in itertools.pairwise(flags):
        if flag in names:
            out[names[flag]] = int(value) if flag in ("--window", "--workers") else value
    return out


def test_refine_without_sequence_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["refine", "-o", "somewhere"]) == 2
    assert "SEQUENCE is required" in capsys.readouterr().err


def test_depth_source_is_the_completion_method() -> None:
    from bimcap.fusion import CompletionMethod, CompletionOptions, FusionInputError
    from bimcap.pipeline.config import DepthSource

    assert DepthSource is CompletionMethod
    cfg = RefineConfig(completion="hybrid", completion_model="m.onnx")
    assert cfg.completion is CompletionMethod.HYBRID and cfg.completion.needs_model
    assert CompletionOptions("classical").method is CompletionMethod.CLASSICAL
    with pytest.raises(FusionInputError) as info:
        CompletionOptions(CompletionMethod.GROUND_TRUTH)
    assert info.value.field == "method"


@pytest.mark.parametrize(("method", "given", "expected"), [
    ("facap", None, 0.4), ("bimcap", None, None), ("facap", 0.0, None), ("bimcap", 0.25, 0.25)])
def test_solve_match_distance_reaches_every_problem_build(
        monkeypatch: pytest.MonkeyPatch, method: str, given: float | None,
        expected: float | None) -> None:
    """FACaP's 0.4 m filter on matches is a setting (``solve_match_distance``), not a constant."""
    from types import SimpleNamespace

    import numpy as np

    import bimcap.pipeline.refine as refine

    seen: list[float | None] = []

    class BuiltError(Exception):
        pass

    def fake_build(prepared, poses, max_match_distance=None, *args, **kwargs):
        seen.append(max_match_distance)
        raise BuiltError

    monkeypatch.setattr(refine, "build_problem", fake_build)
    monkeypatch.setattr(refine, "segment_free_normals", lambda reference: None)
    monkeypatch.setattr(refine, "choose_sample_planes", lambda prepared, poses, *a: None)
    poses = np.tile([0.0, 0, 0, 0, 0, 0, 1], (3, 1))
    prepared = SimpleNamespace(init=SimpleNamespace(poses=poses), reference=None)
    prepared.first_stage = lambda: prepared  # no LiDAR scan samples: one problem throughout
    cfg = RefineConfig(method=method, coarse=False, solve_match_distance=given,
                       global_align="off")
    assert cfg.effective_solve_match_distance == expected
    with pytest.raises(BuiltError):
        refine.solve_prepared(prepared, cfg, quiet=True)  # type: ignore[arg-type]
    assert seen == [expected]


def test_solve_match_distance_is_checked() -> None:
    with pytest.raises(ConfigError, match="solve_match_distance"):
        RefineConfig(solve_match_distance=-0.1)
