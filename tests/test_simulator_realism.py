"""The simulator's realism: ceilings the sensors see, and the settings ``bimcap simulate`` exposes
(pitch, field of view, LiDAR noise and dropout, clutter, label noise), each checked against the
simulator's own ground truth (true labels, ray-cast ranges, the generator's sidecar)."""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest

from bimcap.cli import main as cli_main
from bimcap.labels import Label
from bimcap.sim.clutter import box_mesh
from bimcap.sim.label_noise import LabelNoiseConfig, corrupt_labels
from bimcap.sim.lidar import LidarConfig, LidarSimulator
from bimcap.sim.render import MeshPart, SimConfigError, World
from bimcap.sim.walk import DEFAULT_PITCH_DEG, WalkConfig


@pytest.fixture(scope="module")
def tiny_ifc(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from bimcap.sim.building import BuildingSpec, generate_building

    path = tmp_path_factory.mktemp("tiny") / "tiny.ifc"
    generate_building(BuildingSpec.tiny(), seed=0, ifc_path=path)
    return path


@pytest.fixture(scope="module")
def looking_up(tiny_ifc: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """8 frames at 1/8 ConSLAM resolution in the tiny building, the camera looking 8° up."""
    from bimcap.sim.simulator import CONSLAM_CAMERA, SimulatorConfig, simulate

    out = tmp_path_factory.mktemp("up") / "seq"
    cfg = SimulatorConfig(camera=CONSLAM_CAMERA.scaled(0.125), frames=8, fps=2.0, workers=1,
                          threads_per_worker=0,
                          walk=WalkConfig(pitch_deg=8.0, pitch_amplitude_deg=0.0))
    simulate(tiny_ifc, out, cfg, seed=1)
    return out


def _ceiling_heights(ifc: Path) -> list[float]:
    from bimcap.sim.building import truth_path_for
    from bimcap.sim.building_truth import load_building_truth

    truth = load_building_truth(truth_path_for(ifc))
    return sorted({c.z_min for c in truth.coverings})


# --------------------------------------------------------------------------------- ceilings
def test_ceiling_pixels_get_lidar_returns_at_the_covering_heights(looking_up: Path,
                                                                  tiny_ifc: Path) -> None:
    from bimcap.dataset import read_sequence
    from bimcap.fusion import project_lidar
    from bimcap.geometry.poses import transform_points

    seq = read_sequence(looking_up)
    gt = seq.trajectory("gt").poses
    heights = np.array(_ceiling_heights(tiny_ifc))
    assert heights.tolist() == pytest.approx([2.5, 2.7])
    frames_with_ceiling = frames_with_returns = 0
    for i in range(len(seq.frames)):
        lab, depth = seq.load_labels(i), seq.load_depth(i)
        ceiling = lab == Label.CEILING
        frames_with_ceiling += bool(ceiling.any())
        scan = seq.load_lidar(i)
        sparse = project_lidar(scan, seq.cam_from_lidar, seq.camera, distort=True)
        u, v = np.rint(sparse.uv).astype(int).T
        on = ceiling[v, u]
        if on.sum() < 5:
            continue
        frames_with_returns += 1
        # the return's depth is the ray-cast depth of its pixel, within the LiDAR noise
        err = sparse.z[on] - depth[v[on], u[on]]
        assert np.median(np.abs(err)) < 0.05
        # and in the world it lies on a suspended ceiling (2.5 m corridor, 2.7 m rooms)
        p_cam = seq.camera.backproject(sparse.uv[on], sparse.z[on], distorted=True)
        z = transform_points(gt[i], p_cam)[:, 2]
        near = np.abs(z[:, None] - heights[None, :]).min(axis=1)
        assert np.median(near) < 0.05
    assert frames_with_ceiling >= 3 and frames_with_returns >= 3


@pytest.mark.slow
def test_refine_problem_has_ceiling_samples_on_the_covering_planes(looking_up: Path,
                                                                    tiny_ifc: Path,
                                                                    tmp_path: Path) -> None:
    pytest.importorskip("bimcap._core", reason="the C++ core is not built")
    from bimcap.geometry.poses import transform_points
    from bimcap.pipeline.config import RefineConfig
    from bimcap.pipeline.refine import build_problem, prepare

    prepared = prepare(looking_up, tiny_ifc, looking_up / "poses" / "gt.tum",
                       RefineConfig(workers=1), tmp_path / "run", quiet=True)
    problem, stats = build_problem(prepared)
    assert stats.ceiling > 20
    arrays = problem.arrays()
    planes = arrays["planes"][arrays["ceiling_plane"]]
    assert np.isin(np.round(planes[:, 3], 6), _ceiling_heights(tiny_ifc)).all()
    # at the true poses the samples lie on their planes (LiDAR noise, interpolation)
    p = transform_points(prepared.init.poses[arrays["ceiling_frame"]],
                         arrays["ceiling_p_in_cam"])
    dist = np.einsum("ij,ij->i", p, planes[:, :3]) + planes[:, 3]
    assert np.median(np.abs(dist)) < 0.05


def test_the_walk_looks_up_now_and_then() -> None:
    from bimcap.sim.simulator import corridor_building
    from bimcap.sim.walk import FreeSpace, plan_walk

    parts, polys, doors = corridor_building(rooms_per_side=2)
    free = FreeSpace.from_polygons(World.from_parts(parts), polys, 0.0, doors)
    cfg = WalkConfig()
    assert cfg.pitch_deg == DEFAULT_PITCH_DEG == -12.0
    walk = plan_walk(free, 120.0, np.random.default_rng(3), cfg)
    flat = plan_walk(free, 120.0, np.random.default_rng(3), WalkConfig(pitch_amplitude_deg=0.0))
    pitch, flat_pitch = np.rad2deg(walk.pitch), np.rad2deg(flat.pitch)
    # the glances are added on top: path, yaw and the rest of the motion stay the same
    np.testing.assert_array_equal(walk.xyz, flat.xyz)
    np.testing.assert_array_equal(walk.yaw, flat.yaw)
    assert np.median(flat_pitch) == pytest.approx(-12.0, abs=1.0)
    assert flat_pitch.max() < -5.0
    up = pitch - flat_pitch
    assert up.min() >= 0 and up.max() <= cfg.pitch_amplitude_deg + 1e-9
    assert 0.05 < np.mean(up > 5.0) < 0.5  # now and then, not all the time
    assert pitch.max() > 0.0  # above the horizon: the ceiling comes into view


# ------------------------------------------------------------------------------ LiDAR model
def _box_room(half: float = 6.0, height: float = 3.0) -> World:
    parts = []
    for k, (lo, hi) in enumerate([((-half, -half, -0.2), (half, half, 0.0)),
                                  ((-half, -half, height), (half, half, height + 0.2)),
                                  ((-half - 0.2, -half, 0), (-half, half, height)),
                                  ((half, -half, 0), (half + 0.2, half, height)),
                                  ((-half, -half - 0.2, 0), (half, -half, height)),
                                  ((-half, half, 0), (half, half + 0.2, height))]):
        v, f = box_mesh(np.array(lo, float), np.array(hi, float))
        parts.append(MeshPart(f"p{k}", Label.WALL, v, f))
    return World.from_parts(parts, split_slabs=False)


def _scan_vs_truth(cfg: LidarConfig, seed: int = 0) -> dict[str, np.ndarray]:
    """One scan from the middle of a 12 m box room and, per return, the true range and
    |cos incidence| of its beam (ray-cast without noise)."""
    world = _box_room()
    pose = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 1.0])
    pts = LidarSimulator(world, cfg).scan(pose, np.random.default_rng(seed))
    dirs = cfg.directions()
    hit = world.cast(np.broadcast_to(pose[:3], dirs.shape), dirs)
    r = np.linalg.norm(pts[:, :3], axis=1)
    # each return's beam from its direction (noise moves a return along its beam only)
    elev = np.rad2deg(np.arcsin(np.clip(pts[:, 2] / r, -1.0, 1.0)))
    lo, hi = cfg.vertical_fov_deg
    ch = np.rint((elev - lo) / (hi - lo) * (cfg.channels - 1)).astype(int)
    az = np.rint(np.rad2deg(np.arctan2(pts[:, 1], pts[:, 0])) / cfg.azimuth_step_deg)
    beam = (az.astype(int) % cfg.columns) * cfg.channels + ch
    np.testing.assert_allclose(dirs[beam], pts[:, :3] / r[:, None], atol=1e-4)
    cos_inc = np.abs(np.einsum("ij,ij->i", dirs, hit["primitive_normals"]))
    return {"r": r, "r_true": hit["t_hit"][beam], "cos": cos_inc[beam], "n_beams": len(dirs),
            "cos_all": cos_inc}


def test_lidar_noise_sigma_matches_the_model_and_grows_at_grazing_incidence() -> None:
    stds = {}
    for sigma0 in (0.10, 0.01):  # --lidar-noise 0.1 and a quiet sensor
        cfg = LidarConfig(range_noise_m=sigma0, dropout=0.0)
        s = _scan_vs_truth(cfg)
        err = s["r"] - s["r_true"]
        sigma = cfg.range_sigma(s["r_true"], s["cos"])
        assert np.std(err / sigma) == pytest.approx(1.0, abs=0.05)
        assert abs(np.mean(err / sigma)) < 0.05
        head_on = (s["cos"] > 0.9) & (s["r_true"] < 8.0)
        grazing = (s["cos"] < 0.25) & (s["r_true"] > 5.0)
        assert head_on.sum() > 500 and grazing.sum() > 500
        stds[sigma0] = (np.std(err[head_on]), np.std(err[grazing]))
    assert stds[0.10][0] == pytest.approx(0.10, rel=0.1)  # the σ the flag asks for
    assert stds[0.01][0] == pytest.approx(0.01, rel=0.2)
    assert stds[0.01][1] > 2 * stds[0.01][0]  # grazing returns are noisier


def test_lidar_dropout_fraction_and_grazing_share() -> None:
    base = _scan_vs_truth(LidarConfig(dropout=0.0))
    for dropout in (0.1, 0.3):
        s = _scan_vs_truth(LidarConfig(dropout=dropout))
        lost = 1.0 - len(s["r"]) / len(base["r"])
        assert lost == pytest.approx(dropout, abs=0.02)
    # half the dropouts go to grazing beams: they are lost far more often than head-on ones
    cfg = LidarConfig(dropout=0.3)
    p = cfg.drop_probability(base["cos"])
    assert p.mean() == pytest.approx(0.3, abs=1e-9)
    assert p[base["cos"] < 0.3].mean() > 2 * p[base["cos"] > 0.9].mean()
    assert LidarConfig(dropout=0.3, grazing_share=0.0).drop_probability(base["cos"]) == \
        pytest.approx(0.3)
    with pytest.raises(SimConfigError, match=re.escape("lidar.dropout")):
        LidarConfig(dropout=1.2)


# ------------------------------------------------------------------------------ label noise
def _label_image() -> np.ndarray:
    """A 240×320 view of a corridor: ceiling band, walls, floor, a column, a door, some sky."""
    lab = np.full((240, 320), Label.WALL, np.uint8)
    lab[:50] = Label.CEILING
    lab[170:] = Label.FLOOR
    lab[50:170, 140:170] = Label.COLUMN
    lab[80:170, 230:270] = Label.DOOR
    lab[70:120, 40:90] = Label.UNKNOWN  # sky through a window
    return lab


def _boundary_distance(lab: np.ndarray) -> np.ndarray:
    from scipy.ndimage import distance_transform_edt

    edge = np.zeros(lab.shape, bool)
    dv, dh = lab[1:] != lab[:-1], lab[:, 1:] != lab[:, :-1]
    edge[1:] |= dv
    edge[:-1] |= dv
    edge[:, 1:] |= dh
    edge[:, :-1] |= dh
    return distance_transform_edt(~edge)


@pytest.mark.parametrize("fraction", [0.05, 0.15, 0.3])
def test_label_noise_fraction_in_blobs(fraction: float) -> None:
    from scipy.ndimage import label as connected

    truth = _label_image()
    noisy, stats = corrupt_labels(truth, LabelNoiseConfig(fraction), np.random.default_rng(4))
    labelled = truth != Label.UNKNOWN
    wrong = noisy != truth
    assert wrong[labelled].mean() == pytest.approx(fraction, abs=0.002)
    assert stats["wrong_fraction"] == pytest.approx(wrong[labelled].mean())
    assert not wrong[~labelled].any()  # sky stays unknown
    assert np.isin(noisy[wrong], [int(x) for x in Label if x != Label.UNKNOWN]).all()
    # blobs, not salt and pepper: few connected pieces, each large
    _, n_blobs = connected(wrong)
    assert wrong.sum() / n_blobs > 100


def test_label_noise_near_boundaries() -> None:
    truth = _label_image()
    dist = _boundary_distance(truth)
    for px in (2.0, 5.0):
        noisy, stats = corrupt_labels(truth, LabelNoiseConfig(0.0, px), np.random.default_rng(1))
        wrong = noisy != truth
        assert wrong.any() and stats["blob_fraction"] == 0.0
        assert dist[wrong].max() <= np.sqrt(2) * px + 1  # all of them near a true boundary
    # with a fraction too: the boundary errors count toward it, blobs make up the rest
    noisy, stats = corrupt_labels(truth, LabelNoiseConfig(0.1, 4.0), np.random.default_rng(1))
    labelled = truth != Label.UNKNOWN
    assert (noisy != truth)[labelled].mean() == pytest.approx(0.1, abs=0.002)
    assert 0 < stats["boundary_fraction"] < 0.1
    near = dist <= 4 * np.sqrt(2) + 1
    assert (noisy != truth)[near & labelled].mean() > (noisy != truth)[~near & labelled].mean()


# ------------------------------------------------------------------------------ the CLI
def _simulate_cli(ifc: Path, out: Path, *flags: str) -> dict:
    rc = cli_main(["simulate", str(ifc), "-o", str(out), "--small", "--frames", "3",
                   "--workers", "1", "--seed", "2", *flags])
    assert rc == 0
    return json.loads((out / "manifest.json").read_text())


def test_cli_flags_reach_the_config(tiny_ifc: Path, tmp_path: Path,
                                    monkeypatch: pytest.MonkeyPatch,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    """Every realism flag lands in the SimulatorConfig simulate() gets (no rendering)."""
    import bimcap.sim.simulator as simulator
    from bimcap.sim.simulator import CONSLAM_CAMERA

    seen = {}

    def fake(ifc, out, cfg, seed, as_built, clutter=True, overwrite=False, source=None):
        seen.update(cfg=cfg, clutter=clutter, source=source)
        raise SystemExit(0)

    monkeypatch.setattr(simulator, "simulate", fake)

    def run(*flags: str):
        seen.clear()
        with pytest.raises(SystemExit):
            cli_main(["simulate", str(tiny_ifc), "-o", str(tmp_path / "x"), *flags])
        return seen["cfg"]

    cfg = run()
    assert cfg.walk.pitch_deg == DEFAULT_PITCH_DEG and cfg.walk.pitch_amplitude_deg == 25.0
    assert cfg.lidar.range_noise_m == 0.03 and cfg.lidar.dropout == 0.02
    assert cfg.clutter_density_per_m2 == 0.08 and not cfg.label_noise.enabled
    assert cfg.camera.fx == pytest.approx(CONSLAM_CAMERA.scaled(0.5).fx)
    cfg = run("--pitch-deg", "-3", "--pitch-amplitude-deg", "10", "--look-up-interval", "4",
              "--focal-scale", "1.5", "--lidar-noise", "0.1", "--lidar-dropout", "0.3",
              "--clutter", "0.2", "--label-noise", "0.15", "--label-boundary-px", "3")
    assert (cfg.walk.pitch_deg, cfg.walk.pitch_amplitude_deg, cfg.walk.look_up_interval_s) == \
        (-3.0, 10.0, 4.0)
    assert cfg.camera.fx == pytest.approx(1.5 * CONSLAM_CAMERA.scaled(0.5).fx)
    assert cfg.camera.cx == pytest.approx(CONSLAM_CAMERA.scaled(0.5).cx)
    assert (cfg.lidar.range_noise_m, cfg.lidar.dropout) == (0.1, 0.3)
    assert cfg.clutter_density_per_m2 == 0.2
    assert (cfg.label_noise.fraction, cfg.label_noise.boundary_px) == (0.15, 3.0)
    assert seen["source"]["focal_scale"] == 1.5
    cfg = run("--hfov-deg", "30")
    assert 2 * np.rad2deg(np.arctan(cfg.camera.width / 2 / cfg.camera.fx)) == pytest.approx(30.0)
    cfg = run("--no-clutter")
    assert cfg.clutter_density_per_m2 == 0.0 and seen["clutter"] is False
    # bad values: one clear line naming the setting, exit 2
    capsys.readouterr()
    for flags, name in ((["--lidar-dropout", "1.5"], "lidar.dropout"),
                        (["--label-noise", "-0.1"], "label_noise.fraction"),
                        (["--focal-scale", "0"], "focal_scale"),
                        (["--pitch-amplitude-deg", "-5"], "walk.pitch_amplitude_deg")):
        assert cli_main(["simulate", str(tiny_ifc), "-o", str(tmp_path / "x"), *flags]) == 2
        err = capsys.readouterr().err
        assert name in err, (flags, err)
        assert "Traceback" not in err


@pytest.mark.slow
def test_cli_realism_outputs_and_determinism(tiny_ifc: Path, tmp_path: Path) -> None:
    from bimcap.dataset import read_sequence

    flags = ("--label-noise", "0.2", "--label-boundary-px", "2", "--focal-scale", "1.5",
             "--lidar-noise", "0.08", "--lidar-dropout", "0.2", "--clutter", "0.3")
    m = _simulate_cli(tiny_ifc, tmp_path / "a", *flags)
    src = m["source"]
    # every setting is in the provenance
    assert src["config"]["label_noise"] == {"fraction": 0.2, "boundary_px": 2.0,
                                            "blob_sigma": 0.03}
    assert src["config"]["lidar"]["range_noise_m"] == 0.08
    assert src["config"]["lidar"]["dropout"] == 0.2
    assert src["config"]["clutter_density_per_m2"] == 0.3
    assert src["config"]["walk"]["pitch_deg"] == DEFAULT_PITCH_DEG
    assert src["command_line"]["focal_scale"] == 1.5 and src["focal_scale"] == 1.5
    plain = _simulate_cli(tiny_ifc, tmp_path / "plain", "--no-clutter")
    assert m["camera"]["K"][0] == pytest.approx(1.5 * plain["camera"]["K"][0])
    assert len(src["clutter"]) > 0 and plain["source"]["clutter"] == []
    assert plain["source"]["clutter_enabled"] is False
    assert "labels_gt" not in plain["frames"][0]
    # labels/ are wrong in the asked fraction, labels_gt/ hold the truth
    seq = read_sequence(tmp_path / "a")
    for i in range(len(seq.frames)):
        truth, noisy = seq.load_labels(i, truth=True), seq.load_labels(i)
        labelled = truth != Label.UNKNOWN
        assert (noisy != truth)[labelled].mean() == pytest.approx(0.2, abs=0.005)
        np.testing.assert_array_equal(truth, seq.load_labels(i, truth=True))
    assert src["label_noise_measured"]["wrong_fraction_mean"] == pytest.approx(0.2, abs=0.005)
    # same seed, same files
    _simulate_cli(tiny_ifc, tmp_path / "b", *flags)

    def digest(root: Path) -> dict[str, str]:
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file() and p.name != "manifest.json"}

    a, b = digest(tmp_path / "a"), digest(tmp_path / "b")
    assert a == b and any(k.startswith("labels_gt/") for k in a)
    strip = lambda d: {k: v for k, v in d.items() if k != "command_line"}  # noqa: E731
    mb = json.loads((tmp_path / "b" / "manifest.json").read_text())
    assert strip(m["source"]) == strip(mb["source"]) and m["frames"] == mb["frames"]
