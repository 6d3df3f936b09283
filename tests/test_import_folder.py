"""import-folder, calibration files and pose formats: folders of images (cv2) and clouds (Open3D
PCD / PLY, KITTI .bin) or depth PNGs round-trip into a sequence; camera_info and Kalibr YAML
give the camera and extrinsic; KITTI / COLMAP / TUM poses round-trip (pycolmap and Open3D as
oracles); a bad calibration field is named."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from bimcap.cli import main
from bimcap.dataset import read_sequence
from bimcap.dataset.calib import CalibrationError, read_calibration
from bimcap.dataset.folder import FolderError, depth_to_cloud, import_folder, read_cloud
from bimcap.dataset.importing import (
    DataImportError,
    ImportOptions,
    PoseSensor,
    TrajectoryInput,
    stamp_from_name,
)
from bimcap.geometry.camera import Camera
from bimcap.geometry.pose_formats import (
    PoseFile,
    PoseFormat,
    PoseFormatError,
    read_colmap_images,
    read_kitti,
    read_poses,
    write_colmap_images,
    write_kitti,
    write_poses,
)

W, H = 24, 18
K = (200.0, 201.0, 11.5, 8.5)
D = (-0.03, 0.05, 0.001, -0.001, 0.0)
T0 = 1_700_000_000


def _rigid(seed: int, n: int) -> np.ndarray:
    """(n, 4, 4) random rigid transforms."""
    rng = np.random.default_rng(seed)
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    m[:, :3, 3] = rng.normal(0, 3, (n, 3))
    return m


CAM_FROM_LIDAR = _rigid(7, 1)[0]


def _camera_info_yaml(path: Path, extra: str = "", kdata: str | None = None) -> Path:
    fx, fy, cx, cy = K
    kdata = kdata or f"[{fx}, 0, {cx}, 0, {fy}, {cy}, 0, 0, 1]"
    path.write_text(
        f"image_width: {W}\nimage_height: {H}\ncamera_name: rgb\n"
        f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {kdata}\n"
        "distortion_model: plumb_bob\n"
        f"distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: {list(D)}\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
        + extra)
    return path


def _matrix_yaml(m: np.ndarray, indent: str = "  ") -> str:
    return "".join(f"{indent}- {row.tolist()}\n" for row in m)


def _extrinsic_yaml(path: Path, key: str = "T_cam_lidar", m: np.ndarray = CAM_FROM_LIDAR,
                    extra: str = "") -> Path:
    path.write_text(f"{key}:\n{_matrix_yaml(m)}{extra}")
    return path


def _pose_matrix(pose: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(pose[3:]).as_matrix()
    m[:3, 3] = pose[:3]
    return m


def _write_pcd_or_ply(path: Path, xyzi: np.ndarray) -> None:
    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(np.ascontiguousarray(xyzi[:, :3]))
    pc.point.intensity = o3d.core.Tensor(np.ascontiguousarray(xyzi[:, 3:4]))
    assert o3d.t.io.write_point_cloud(str(path), pc)


def _write_folder(root: Path, names: str = "stems") -> tuple[list[np.ndarray], list[np.ndarray],
                                                              list[float]]:
    """Five images 0.1 s apart, clouds 3 ms later (PCD, PLY, .bin in turn) except after image 1;
    names carry the times (``stems``), or are KITTI-numbered with a timestamps.txt."""
    rng = np.random.default_rng(3)
    (root / "images").mkdir(parents=True)
    (root / "clouds").mkdir()
    images, clouds, times = [], [], []
    lines = []
    for k in range(5):
        t_img = T0 + 0.1 * k + 0.25
        t_cloud_us = (T0 * 10**6 + 100_000 * k + 250_000 + 3_000)
        rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        img_name = f"{t_img:.6f}.png" if names == "stems" else f"{k:06d}.png"
        cv2.imwrite(str(root / "images" / img_name), rgb[:, :, ::-1])
        lines.append(f"images/{img_name} {t_img!r}")
        if k == 1:
            continue
        xyzi = rng.normal(0, 5, (20 + k, 4)).astype(np.float32)
        kind = ("pcd", "ply", "bin")[k % 3]
        stem = str(t_cloud_us) if names == "stems" else f"{k:06d}"
        path = root / "clouds" / f"{stem}.{kind}"
        if kind == "bin":
            path.write_bytes(xyzi.astype("<f4").tobytes())
        else:
            _write_pcd_or_ply(path, xyzi)
        lines.append(f"{path.name} {t_cloud_us * 1e-6!r}")  # name alone is accepted too
        images.append(rgb)
        clouds.append(xyzi)
        times.append(t_img)
    if names != "stems":
        (root / "timestamps.txt").write_text("# name seconds\n" + "\n".join(lines) + "\n")
    return images, clouds, times


def _check(seq_dir: Path, images: list[np.ndarray], clouds: list[np.ndarray],
           times: list[float]) -> object:
    seq = read_sequence(seq_dir)  # bimcap's own loader validates everything
    assert len(seq) == len(images) == 4
    np.testing.assert_allclose(seq.timestamps, times, rtol=0, atol=5e-7)
    for i in range(len(seq)):
        np.testing.assert_array_equal(seq.load_image(i), images[i])
        np.testing.assert_array_equal(seq.load_lidar(i), clouds[i])
    assert (seq.camera.width, seq.camera.height) == (W, H)
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy) == K
    assert seq.camera.dist == D
    return seq


# ----------------------------------------------------------------------------- folders
def test_folder_with_time_stems_pcd_ply_bin_and_tum(tmp_path: Path) -> None:
    images, clouds, times = _write_folder(tmp_path / "rec")
    calib = _camera_info_yaml(tmp_path / "cam.yaml")
    ext = _extrinsic_yaml(tmp_path / "ext.yaml")
    poses = np.array([[k, 0.5, 1.5, 0, 0, np.sin(0.2 * k), np.cos(0.2 * k)] for k in range(5)])
    tum = tmp_path / "slam.tum"
    write_poses(tum, PoseFile(_pose_matrix_batch(poses), timestamps=np.array(
        [T0 + 0.1 * k + 0.25 for k in range(5)])), PoseFormat.TUM)
    res = import_folder(tmp_path / "rec", tmp_path / "seq", calib, lidar_extrinsic=ext,
                        options=ImportOptions(trajectory=TrajectoryInput(tum)))
    assert (res.n_images, res.n_clouds, res.n_pairs, res.n_frames) == (5, 4, 4, 4)
    assert res.max_pair_dt_s == pytest.approx(0.003, abs=1e-6)
    seq = _check(tmp_path / "seq", images, clouds, times)
    np.testing.assert_allclose(_pose_matrix(seq.cam_from_lidar), CAM_FROM_LIDAR, atol=1e-12)
    np.testing.assert_allclose(seq.trajectory("init").poses, poses[[0, 2, 3, 4]], atol=1e-12)
    assert seq.source["importer"] == "bimcap.dataset.folder"


def _pose_matrix_batch(poses: np.ndarray) -> np.ndarray:
    return np.stack([_pose_matrix(p) for p in poses])


def test_folder_with_timestamps_file_kalibr_and_colmap_lidar_poses(tmp_path: Path) -> None:
    """KITTI-numbered files, a timestamps.txt; a Kalibr camchain (cam1) with T_imu_lidar;
    COLMAP poses matched by image name, of the LiDAR, made camera poses with the extrinsic."""
    images, clouds, times = _write_folder(tmp_path / "rec", names="kitti")
    cam0_from_imu, cam1_from_cam0, imu_from_lidar = _rigid(1, 3)
    fx, fy, cx, cy = K
    (tmp_path / "camchain.yaml").write_text(
        "cam0:\n  T_cam_imu:\n" + _matrix_yaml(cam0_from_imu, "  ")
        + "  camera_model: pinhole\n  distortion_coeffs: [0.1, 0.0, 0.0, 0.0]\n"
        "  distortion_model: radtan\n  intrinsics: [100, 100, 12, 9]\n  resolution: [24, 18]\n"
        "cam1:\n  T_cn_cnm1:\n" + _matrix_yaml(cam1_from_cam0, "  ")
        + f"  camera_model: pinhole\n  distortion_coeffs: {list(D[:4])}\n"
        f"  distortion_model: radtan\n  intrinsics: [{fx}, {fy}, {cx}, {cy}]\n"
        f"  resolution: [{W}, {H}]\n  rostopic: /cam1/image_raw\n")
    ext = _extrinsic_yaml(tmp_path / "ext.yaml", "T_imu_lidar", imu_from_lidar)
    world_from_lidar = _rigid(5, 5)
    names = [f"{k:06d}.png" for k in range(5)]
    images_txt = tmp_path / "images.txt"
    write_colmap_images(images_txt, world_from_lidar[::-1], names[::-1])  # order must not matter
    opts = ImportOptions(trajectory=TrajectoryInput(images_txt, PoseFormat.COLMAP,
                                                    sensor=PoseSensor.LIDAR, name="gt"))
    res = import_folder(tmp_path / "rec", tmp_path / "seq", tmp_path / "camchain.yaml",
                        calib_camera="cam1", lidar_extrinsic=ext, options=opts)
    assert res.pose_match == "name"
    seq = _check(tmp_path / "seq", images, clouds, times)
    cam1_from_lidar = cam1_from_cam0 @ cam0_from_imu @ imu_from_lidar  # plain matrices
    np.testing.assert_allclose(_pose_matrix(seq.cam_from_lidar), cam1_from_lidar, atol=1e-9)
    gt = seq.trajectory("gt")
    for i, k in enumerate([0, 2, 3, 4]):
        expected = world_from_lidar[k] @ np.linalg.inv(cam1_from_lidar)
        np.testing.assert_allclose(_pose_matrix(gt.poses[i]), expected, atol=1e-9)


def test_cli_import_folder_with_kitti_poses_and_one_column_times(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """KITTI: equally numbered images and scans, one time per line, poses one per image."""
    root = tmp_path / "kitti"
    (root / "image_2").mkdir(parents=True)
    (root / "velodyne").mkdir()
    rng = np.random.default_rng(0)
    images, clouds = [], []
    for k in range(4):
        rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        cv2.imwrite(str(root / "image_2" / f"{k:06d}.png"), rgb[:, :, ::-1])
        xyzi = rng.normal(0, 5, (10, 4)).astype(np.float32)
        (root / "velodyne" / f"{k:06d}.bin").write_bytes(xyzi.tobytes())
        images.append(rgb)
        clouds.append(xyzi)
    (root / "times.txt").write_text("".join(f"{0.1 * k:.6e}\n" for k in range(4)))
    poses = _rigid(2, 4)
    write_kitti(tmp_path / "00.txt", poses)
    calib = _camera_info_yaml(tmp_path / "cam.yaml",
                              extra="T_cam_lidar:\n" + _matrix_yaml(CAM_FROM_LIDAR))
    assert main(["import-folder", str(root), "-o", str(tmp_path / "seq"), "--calib", str(calib),
                 "--images", "image_2", "--clouds", "velodyne", "--timestamps",
                 str(root / "times.txt"), "--trajectory", str(tmp_path / "00.txt"),
                 "--trajectory-format", "kitti", "--trajectory-name", "gt"]) == 0
    assert "4 frames from 4 images / 4 clouds" in capsys.readouterr().out
    seq = read_sequence(tmp_path / "seq")
    np.testing.assert_allclose(seq.timestamps, [0.0, 0.1, 0.2, 0.3], atol=1e-12)
    for i in range(4):
        np.testing.assert_array_equal(seq.load_image(i), images[i])
        np.testing.assert_array_equal(seq.load_lidar(i), clouds[i])
        np.testing.assert_allclose(_pose_matrix(seq.trajectory("gt").poses[i]), poses[i],
                                   atol=1e-12)
    # A bad calibration field: one line naming the file and the field, exit 2.
    bad = _camera_info_yaml(tmp_path / "bad.yaml", kdata="[200, 0, 11.5, 0, 201, 8.5, 0, 0]")
    assert main(["import-folder", str(root), "-o", str(tmp_path / "seq2"), "--calib", str(bad),
                 "--lidar-extrinsic", "identity", "--images", "image_2", "--clouds",
                 "velodyne"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"{bad}: camera_matrix.data: expected 9 numbers, got 8" in err


def test_rgbd_depth_pngs_back_project_like_open3d(tmp_path: Path) -> None:
    root = tmp_path / "rgbd"
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rng = np.random.default_rng(4)
    depths = []
    for k in range(3):
        t = T0 + 0.5 * k
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"),
                    rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        depth = rng.integers(500, 4000, (H, W)).astype(np.uint16)
        depth[3:6, 4:9] = 0  # no depth
        cv2.imwrite(str(root / "depth" / f"{t + 0.01:.6f}.png"), depth)
        depths.append(depth)
    pinhole = tmp_path / "pinhole.yaml"
    fx, fy, cx, cy = K
    pinhole.write_text(f"image_width: {W}\nimage_height: {H}\ncamera_matrix:\n  data: "
                       f"[{fx}, 0, {cx}, 0, {fy}, {cy}, 0, 0, 1]\ndistortion_model: plumb_bob\n"
                       "distortion_coefficients:\n  data: [0, 0, 0, 0, 0]\n")
    res = import_folder(root, tmp_path / "seq", pinhole, depth="depth", depth_scale=5000.0)
    seq = read_sequence(tmp_path / "seq")
    assert res.n_frames == len(seq) == 3
    np.testing.assert_allclose(seq.cam_from_lidar, [0, 0, 0, 0, 0, 0, 1], atol=0)
    # Oracle: Open3D's own back-projection (pinhole), same pixel order.
    intr = o3d.camera.PinholeCameraIntrinsic(W, H, fx, fy, cx, cy)
    for i, depth in enumerate(depths):
        ref = o3d.geometry.PointCloud.create_from_depth_image(
            o3d.geometry.Image(depth), intr, depth_scale=5000.0, depth_trunc=1e6)
        got = seq.load_lidar(i)
        assert len(got) == (depth > 0).sum() == len(ref.points)
        np.testing.assert_allclose(got[:, :3], np.asarray(ref.points), atol=1e-5)
    # Distorted camera: every point projects back onto its pixel centre at its depth.
    cam = Camera(W, H, *K, D)
    cloud = depth_to_cloud(depths[0], cam, 5000.0)
    uv, _ = cam.project(cloud[:, :3].astype(np.float64))
    valid = depths[0].reshape(-1) > 0
    np.testing.assert_allclose(uv, cam.pixel_grid()[valid], atol=1e-4)
    np.testing.assert_allclose(cloud[:, 2], depths[0].reshape(-1)[valid] / 5000.0, rtol=1e-6)
    with pytest.raises(FolderError, match="no extrinsic to give"):
        import_folder(root, tmp_path / "s2", pinhole, depth="depth", lidar_extrinsic="x.yaml")


def test_folder_errors(tmp_path: Path) -> None:
    _write_folder(tmp_path / "rec")
    calib = _camera_info_yaml(tmp_path / "cam.yaml")
    with pytest.raises(FolderError, match="no LiDAR extrinsic"):
        import_folder(tmp_path / "rec", tmp_path / "s", calib)
    with pytest.raises(DataImportError, match=r"no image/cloud pair within 0\.001 s"):
        import_folder(tmp_path / "rec", tmp_path / "s", calib, lidar_extrinsic="identity",
                      options=ImportOptions(tolerance_s=0.001))
    (tmp_path / "rec" / "clouds" / "notes.bin").write_bytes(b"123")
    with pytest.raises(FolderError, match="the name is not a time"):
        import_folder(tmp_path / "rec", tmp_path / "s", calib, lidar_extrinsic="identity")
    with pytest.raises(FolderError, match="not a multiple of 16"):
        read_cloud(tmp_path / "rec" / "clouds" / "notes.bin")
    (tmp_path / "junk.pcd").write_text("garbage")
    with pytest.raises(FolderError, match="cannot read a point cloud"):
        read_cloud(tmp_path / "junk.pcd")
    assert not (tmp_path / "s" / "manifest.json").exists()


def test_stamp_from_name() -> None:
    assert stamp_from_name("1700000000.25.png") == 1700000000.25
    assert stamp_from_name("1700000000250000.pcd") == pytest.approx(1700000000.25)
    assert stamp_from_name("1700000000250000000.bin") == pytest.approx(1700000000.25)
    assert stamp_from_name("1700000000250.png") == pytest.approx(1700000000.25)
    assert stamp_from_name("000042.png") == 42.0
    assert stamp_from_name("frame_0001.png") is None


# ----------------------------------------------------------------------------- calibration
def test_calibration_files_and_their_errors(tmp_path: Path) -> None:
    cal = read_calibration(_camera_info_yaml(tmp_path / "a.yaml"))
    assert cal.camera == Camera(W, H, *K, D) and cal.cam_from_lidar is None
    ext = _extrinsic_yaml(tmp_path / "e.yaml", "T_lidar_cam", np.linalg.inv(CAM_FROM_LIDAR))
    cal = read_calibration(tmp_path / "a.yaml", lidar_extrinsic=ext)
    np.testing.assert_allclose(_pose_matrix(cal.cam_from_lidar), CAM_FROM_LIDAR, atol=1e-12)

    def fails(text: str, field: str, match: str = "", **kw: object) -> None:
        path = tmp_path / "bad.yaml"
        path.write_text(text)
        with pytest.raises(CalibrationError, match=match) as info:
            read_calibration(path, **kw)  # type: ignore[arg-type]
        assert info.value.path == str(path) and info.value.field == field, str(info.value)

    good = (tmp_path / "a.yaml").read_text()
    fails(good.replace("image_width: 24", "image_width: -3"), "image_width", "positive")
    fails(good.replace("distortion_model: plumb_bob", "distortion_model: equidistant"),
          "distortion_model", "not supported")
    fails(good.replace("camera_name: rgb\n", "") .replace("image_height: 18\n", ""),
          "image_height", "missing")
    kalibr = ("cam0:\n  camera_model: pinhole\n  distortion_model: radtan\n"
              "  distortion_coeffs: [0, 0, 0, 0]\n  intrinsics: [1, 1, 0, 0]\n"
              "  resolution: [4, 3]\n")
    fails(kalibr.replace("radtan", "equidistant"), "cam0.distortion_model", "radtan only")
    fails(kalibr.replace("  intrinsics: [1, 1, 0, 0]\n", ""), "cam0.intrinsics", "missing")
    fails(kalibr.replace("[1, 1, 0, 0]", "[1, 1, 0]"), "cam0.intrinsics", "expected 4")
    fails(kalibr, "cam1", "no camera 'cam1'", camera="cam1")
    fails(kalibr + "T_cam_lidar: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n", "T_cam_lidar",
          "expected 12 or 16")
    fails(kalibr + "T_imu_lidar: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]\n", "T_imu_lidar",
          "T_cam_imu")
    fails("just: [a mapping]\n", None, "neither a ROS camera_info")  # type: ignore[arg-type]
    fails("camera_matrix: [1, 2\n", None, "not valid YAML")  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- pose formats
def test_kitti_round_trip_and_errors(tmp_path: Path) -> None:
    m = _rigid(0, 6)
    write_kitti(tmp_path / "p.txt", m)
    back = read_kitti(tmp_path / "p.txt")
    np.testing.assert_allclose(back.world_from_cam, m, atol=1e-15)
    assert back.timestamps is None and back.names is None
    (tmp_path / "t.txt").write_text("".join(f"{0.1 * k}\n" for k in range(6)))
    timed = read_poses(tmp_path / "p.txt", "kitti", tmp_path / "t.txt")
    np.testing.assert_allclose(timed.to_trajectory().poses, timed.poses(), atol=0)
    lines = (tmp_path / "p.txt").read_text().splitlines()
    (tmp_path / "bad.txt").write_text("\n".join([*lines[:2], "1 0 0 0 0 1 0 0 0 0 1"]))
    with pytest.raises(PoseFormatError, match="line 3: expected 12 numbers"):
        read_kitti(tmp_path / "bad.txt")
    (tmp_path / "bad.txt").write_text("2 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(PoseFormatError, match="line 1: not a rotation"):
        read_kitti(tmp_path / "bad.txt")
    with pytest.raises(PoseFormatError, match="5 times for 6 poses"):
        read_kitti(tmp_path / "p.txt", times=_times_file(tmp_path, 5))


def _times_file(tmp_path: Path, n: int) -> Path:
    path = tmp_path / f"times{n}.txt"
    path.write_text("".join(f"{k}\n" for k in range(n)))
    return path


def test_colmap_images_txt_round_trip_with_pycolmap_as_oracle(tmp_path: Path) -> None:
    pycolmap = pytest.importorskip("pycolmap")
    m = _rigid(9, 4)
    names = ["a.png", "b.png", "c.png", "d.png"]
    model = tmp_path / "model"
    model.mkdir()
    write_colmap_images(model / "images.txt", m, names)
    (model / "cameras.txt").write_text("1 PINHOLE 24 18 200 201 12 9\n")
    (model / "points3D.txt").write_text("")
    rec = pycolmap.Reconstruction(str(model))
    for image in rec.images.values():
        k = names.index(image.name)
        cam_from_world = np.vstack([image.cam_from_world().matrix(), [0, 0, 0, 1]])
        np.testing.assert_allclose(cam_from_world, np.linalg.inv(m[k]), atol=1e-12)
    out = tmp_path / "out"
    out.mkdir()
    rec.write_text(str(out))  # pycolmap's own images.txt, with its own header and ids
    back = read_colmap_images(out / "images.txt")
    order = [back.names.index(n) for n in names] if back.names else []
    np.testing.assert_allclose(back.world_from_cam[order], m, atol=1e-12)
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 0 0 0 1 2 3 1 a.png\n\n")
    with pytest.raises(PoseFormatError, match="line 1: quaternion of norm 2"):
        read_colmap_images(bad)


def test_tum_through_pose_formats_is_bimcaps_tum(tmp_path: Path) -> None:
    m = _rigid(4, 3)
    stamps = np.array([1.5, 2.5, 3.25])
    write_poses(tmp_path / "p.tum", PoseFile(m, timestamps=stamps), "tum")
    back = read_poses(tmp_path / "p.tum", PoseFormat.TUM)
    np.testing.assert_allclose(back.world_from_cam, m, atol=1e-12)
    np.testing.assert_array_equal(back.timestamps, stamps)
    from bimcap.geometry.trajectory import read_tum

    np.testing.assert_allclose(read_tum(tmp_path / "p.tum").poses, back.poses(), atol=1e-15)
    with pytest.raises(PoseFormatError, match="needs image names"):
        write_poses(tmp_path / "x.txt", PoseFile(m), "colmap")
