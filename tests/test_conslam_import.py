"""ConSLAM importer: a bag written here with rosbags' own writer round-trips into a sequence."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore

from bimcap.cli import main
from bimcap.dataset import read_sequence
from bimcap.dataset.conslam import (
    CONSLAM_CAM_FROM_LIDAR,
    ConslamError,
    GtFrame,
    decode_pointcloud,
    import_conslam,
    pair_nearest,
)
from bimcap.geometry import write_tum
from bimcap.geometry.trajectory import Trajectory

TS = get_typestore(Stores.ROS1_NOETIC)
T0_SEC = 1_650_000_000
# The published extrinsic (DESIGN §3), written out again here on purpose.
R_CL = np.array(
    [
        [0.05758374, -0.99833897, -0.00184651],
        [-0.0017837, 0.0017467, -0.99999688],
        [0.99833909, 0.05758685, -0.00168015],
    ]
)
T_CL = np.array([-0.0081025, -0.0631593, -0.0215235])
K_INFO = (300.0, 301.0, 20.5, 14.5)
D_INFO = (-0.05, 0.1, 0.001, -0.002, 0.0)


def _header(sec: int, nsec: int) -> object:
    Header = TS.types["std_msgs/msg/Header"]
    Time = TS.types["builtin_interfaces/msg/Time"]
    return Header(seq=0, stamp=Time(sec=sec, nanosec=nsec), frame_id="f")


def _image_msg(sec: int, nsec: int, rgb: np.ndarray, pad: int = 8) -> object:
    Image = TS.types["sensor_msgs/msg/Image"]
    h, w, _ = rgb.shape
    step = w * 3 + pad
    buf = np.zeros((h, step), np.uint8)
    buf[:, : w * 3] = rgb.reshape(h, w * 3)
    buf[:, w * 3 :] = 77  # padding bytes that must not leak into the image
    return Image(
        header=_header(sec, nsec),
        height=h,
        width=w,
        encoding="rgb8",
        is_bigendian=0,
        step=step,
        data=buf.ravel(),
    )


def _cloud_msg(sec: int, nsec: int, xyzi: np.ndarray, bigendian: bool = False) -> object:
    """x, y, z at 0/4/8, a uint16 ring at 12, intensity at 16; point_step 24 (padding)."""
    PointCloud2 = TS.types["sensor_msgs/msg/PointCloud2"]
    PointField = TS.types["sensor_msgs/msg/PointField"]
    o = ">" if bigendian else "<"
    dt = np.dtype(
        {
            "names": ["x", "y", "z", "ring", "intensity"],
            "formats": [o + "f4", o + "f4", o + "f4", o + "u2", o + "f4"],
            "offsets": [0, 4, 8, 12, 16],
            "itemsize": 24,
        }
    )
    arr = np.zeros(len(xyzi), dtype=dt)
    for k, name in enumerate(("x", "y", "z")):
        arr[name] = xyzi[:, k]
    arr["intensity"] = xyzi[:, 3]
    arr["ring"] = 7
    fields = [
        PointField(name=n, offset=off, datatype=dtp, count=1)
        for n, off, dtp in (
            ("intensity", 16, 7),
            ("x", 0, 7),
            ("ring", 12, 4),
            ("y", 4, 7),
            ("z", 8, 7),
        )
    ]
    data = np.frombuffer(arr.tobytes(), np.uint8)
    return PointCloud2(
        header=_header(sec, nsec),
        height=1,
        width=len(xyzi),
        fields=fields,
        is_bigendian=bigendian,
        point_step=24,
        row_step=24 * len(xyzi),
        data=data,
        is_dense=False,
    )


def _info_msg(w: int, h: int) -> object:
    CameraInfo = TS.types["sensor_msgs/msg/CameraInfo"]
    RegionOfInterest = TS.types["sensor_msgs/msg/RegionOfInterest"]
    fx, fy, cx, cy = K_INFO
    k = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], float)
    return CameraInfo(
        header=_header(T0_SEC, 0),
        height=h,
        width=w,
        distortion_model="plumb_bob",
        D=np.array(D_INFO),
        K=k,
        R=np.eye(3).ravel(),
        P=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def _rot_z(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


@dataclass
class FakeRecording:
    bag: Path
    gt_dir: Path
    images: list[np.ndarray]  # per written frame
    clouds: list[np.ndarray]  # per written frame, finite points only
    image_times: list[float]
    world_from_lidar: list[np.ndarray]  # (4, 4) per written frame


def _write_recording(tmp: Path, w: int, h: int, with_info: bool) -> FakeRecording:
    """Six images; scans 3 ms later except image 3 (no scan); an extra lone scan; no GT for 4."""
    rng = np.random.default_rng(0)
    bag = tmp / "conslam.bag"
    gt_dir = tmp / "gt"
    gt_dir.mkdir()
    rec = FakeRecording(bag, gt_dir, [], [], [], [])
    with Writer(bag) as writer:
        c_img = writer.add_connection(
            "/pp_rgb/synced2points", "sensor_msgs/msg/Image", typestore=TS
        )
        c_pts = writer.add_connection(
            "/pp_points/synced2rgb", "sensor_msgs/msg/PointCloud2", typestore=TS
        )
        c_info = writer.add_connection(
            "/pp_rgb/camera_info", "sensor_msgs/msg/CameraInfo", typestore=TS
        )
        if with_info:
            writer.write(
                c_info,
                T0_SEC * 10**9,
                TS.serialize_ros1(_info_msg(w, h), "sensor_msgs/msg/CameraInfo"),
            )
        for k in range(6):
            nsec_img = 100_000_000 * k + 20_000  # µs-exact stamps
            nsec_pts = nsec_img + 3_000_000
            t_bag = T0_SEC * 10**9 + nsec_img
            rgb = rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)
            writer.write(
                c_img,
                t_bag,
                TS.serialize_ros1(_image_msg(T0_SEC, nsec_img, rgb), "sensor_msgs/msg/Image"),
            )
            if k == 3:
                continue  # image without a scan
            pts = rng.normal(0.0, 5.0, size=(40 + k, 4)).astype(np.float32)
            pts[5, 1] = np.nan  # a "no return" point, dropped by the importer
            writer.write(
                c_pts,
                t_bag + 3_000_000,
                TS.serialize_ros1(
                    _cloud_msg(T0_SEC, nsec_pts, pts, bigendian=(k == 2)),
                    "sensor_msgs/msg/PointCloud2",
                ),
            )
            t_scan_us = T0_SEC * 1_000_000 + nsec_pts // 1000
            pose = np.eye(4)
            pose[:3, :3] = _rot_z(0.3 * k + 0.2)
            pose[:3, 3] = [1.0 + k, 2.0 - 0.5 * k, 1.4]
            if k != 4:  # scan 4 has no ground truth
                np.savetxt(gt_dir / f"{t_scan_us}.txt", pose)
                rec.images.append(rgb)
                rec.clouds.append(np.delete(pts, 5, axis=0))
                rec.image_times.append(T0_SEC + nsec_img * 1e-9)
                rec.world_from_lidar.append(pose)
        lone = rng.normal(size=(10, 4)).astype(np.float32)
        writer.write(
            c_pts,
            T0_SEC * 10**9 + 900_000_000,
            TS.serialize_ros1(_cloud_msg(T0_SEC, 900_000_000, lone), "sensor_msgs/msg/PointCloud2"),
        )
    (gt_dir / "README").write_text("not a pose")  # ignored: not named by a timestamp
    (gt_dir / "notes.1.txt").write_text("not a pose either")
    return rec


def _hand_world_from_cam(world_from_lidar: np.ndarray) -> np.ndarray:
    """world_from_cam = world_from_lidar · (cam_from_lidar)⁻¹ with plain 4×4 matrices."""
    u, _, vt = np.linalg.svd(R_CL)  # the nearest rotation to the published 3×3 block
    cam_from_lidar = np.eye(4)
    cam_from_lidar[:3, :3] = u @ vt
    cam_from_lidar[:3, 3] = T_CL
    return world_from_lidar @ np.linalg.inv(cam_from_lidar)


def _pose_matrix(pose: np.ndarray) -> np.ndarray:
    x, y, z, w = pose[3:]
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = pose[:3]
    return m


def test_import_round_trip_with_camera_info_and_gt_folder(tmp_path: Path) -> None:
    rec = _write_recording(tmp_path, 40, 30, with_info=True)
    res = import_conslam(rec.bag, tmp_path / "seq", rec.gt_dir)
    assert (res.n_images, res.n_scans, res.n_pairs, res.n_without_gt) == (6, 6, 5, 1)
    assert res.n_frames == 4 and res.camera_source == "camera_info"
    assert res.max_pair_dt_s == pytest.approx(0.003, abs=1e-6)
    seq = read_sequence(tmp_path / "seq")
    assert len(seq) == 4
    # Calibration: camera_info's K and D; ConSLAM's extrinsic.
    assert (seq.camera.width, seq.camera.height) == (40, 30)
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy) == K_INFO
    assert seq.camera.dist == D_INFO
    np.testing.assert_allclose(_pose_matrix(seq.cam_from_lidar)[:3, :3], R_CL, atol=1e-7)
    np.testing.assert_allclose(seq.cam_from_lidar[:3], T_CL, atol=1e-15)
    assert seq.lidar.model == "VLP-16"
    assert seq.source["importer"] == "bimcap.dataset.conslam"
    np.testing.assert_allclose(seq.timestamps, rec.image_times, atol=1e-9, rtol=0)
    gt = seq.trajectory("gt")
    for i in range(len(seq)):
        # Pixels: exact, RGB order, row padding removed.
        np.testing.assert_array_equal(seq.load_image(i), rec.images[i])
        # Points: exact (including the big-endian cloud), NaN return dropped.
        np.testing.assert_array_equal(seq.load_lidar(i), rec.clouds[i])
        # Poses: the extrinsic composition, against plain matrix algebra.
        expected = _hand_world_from_cam(rec.world_from_lidar[i])
        np.testing.assert_allclose(_pose_matrix(gt.poses[i]), expected, atol=1e-9)
        # Invariant: a LiDAR point reaches the same world point through either sensor.
        p_in_lidar = np.array([3.0, -1.0, 0.5, 1.0])
        via_cam = _pose_matrix(gt.poses[i]) @ _pose_matrix(seq.cam_from_lidar) @ p_in_lidar
        np.testing.assert_allclose(via_cam, rec.world_from_lidar[i] @ p_in_lidar, atol=1e-9)


def test_hand_computed_camera_pose_for_identity_lidar_pose(tmp_path: Path) -> None:
    """With world_from_lidar = I the camera centre in the world is -R_clᵀ t_cl and the camera's
    optical axis (z) is the LiDAR's x axis (R_cl's third row is ~[1, 0.058, 0])."""
    rec = _write_recording(tmp_path, 40, 30, with_info=True)
    traj = Trajectory(
        np.array([T0_SEC + k * 0.1 + 2e-5 + 0.003 for k in range(6)]),
        np.tile([0, 0, 0, 0, 0, 0, 1.0], (6, 1)),
    )
    seq = import_conslam(rec.bag, tmp_path / "seq", traj).sequence
    pose = seq.trajectory("gt").poses[0]
    centre = -R_CL.T @ T_CL
    np.testing.assert_allclose(pose[:3], centre, atol=1e-8)
    np.testing.assert_allclose(centre, [0.021842, -0.006739, -0.063210], atol=2e-6)
    z_axis = _pose_matrix(pose)[:3, 2]
    np.testing.assert_allclose(z_axis, [0.99833909, 0.05758685, -0.00168015], atol=1e-7)


def test_import_defaults_without_camera_info_and_tum_camera_gt(tmp_path: Path) -> None:
    rec = _write_recording(tmp_path, 258, 193, with_info=False)  # ConSLAM's 2064×1544 / 8
    cam_poses = np.array([[1.0 * k, 0, 0, 0, 0, 0, 1] for k in range(6)])
    tum = tmp_path / "gt.tum"
    write_tum(tum, Trajectory(np.array([T0_SEC + k * 0.1 + 2e-5 for k in range(6)]), cam_poses))
    res = import_conslam(
        rec.bag, tmp_path / "seq", tum, gt_frame=GtFrame.CAMERA, gt_tolerance_s=0.01
    )
    seq = res.sequence
    assert res.camera_source.startswith("conslam_default scaled")
    assert seq.camera.width == 258 and seq.camera.height == 193
    assert seq.camera.fx == pytest.approx(2351.85909 / 8, rel=1e-12)
    assert seq.camera.cy == pytest.approx((788.70774 + 0.5) * 193 / 1544 - 0.5, rel=1e-12)
    assert seq.camera.dist == (-0.054366, 0.118389, 0.001781, -0.003908, 0.0)
    # Camera-frame GT is taken as it is (nearest within 10 ms of the 3-ms-later scan).
    kept = [0, 1, 2, 4, 5]
    np.testing.assert_allclose(seq.trajectory("gt").poses[:, 0], kept, atol=1e-12)
    assert res.n_without_gt == 0


def test_import_stride_no_gt_and_cli(tmp_path: Path) -> None:
    rec = _write_recording(tmp_path, 40, 30, with_info=True)
    res = import_conslam(rec.bag, tmp_path / "a", None, stride=2, max_frames=2)
    assert res.n_frames == 2 and res.sequence.poses == {}
    assert (
        main(["import-conslam", str(rec.bag), "-o", str(tmp_path / "b"), "--gt", str(rec.gt_dir)])
        == 0
    )
    assert len(read_sequence(tmp_path / "b").trajectory("gt")) == 4
    assert main(["import-conslam", str(rec.bag), "-o", str(tmp_path / "b")]) == 2  # exists
    assert (
        main(
            [
                "import-conslam",
                str(rec.bag),
                "-o",
                str(tmp_path / "b"),
                "--force",
                "--png-compression",
                "1",
            ]
        )
        == 0
    )


def test_import_errors(tmp_path: Path) -> None:
    rec = _write_recording(tmp_path, 40, 30, with_info=True)
    with pytest.raises(ConslamError, match="within 1e-05 s"):
        import_conslam(rec.bag, tmp_path / "s1", rec.gt_dir, gt_tolerance_s=0.0, tolerance_s=1e-5)
    late = Trajectory(
        np.array([T0_SEC + k * 0.1 + 0.023 for k in range(6)]),
        np.tile([0, 0, 0, 0, 0, 0, 1.0], (6, 1)),
    )  # 20 ms after each scan
    with pytest.raises(ConslamError, match="no frame has a ground-truth pose"):
        import_conslam(rec.bag, tmp_path / "s2", late, gt_tolerance_s=0.01)
    assert import_conslam(rec.bag, tmp_path / "s2", late, gt_tolerance_s=0.03).n_frames == 5
    with pytest.raises(ConslamError, match="no such bag"):
        import_conslam(tmp_path / "missing.bag", tmp_path / "s3")
    (tmp_path / "junk.bag").write_bytes(b"not a bag at all")
    with pytest.raises(ConslamError, match="cannot read the bag"):
        import_conslam(tmp_path / "junk.bag", tmp_path / "s4")
    bad_gt = tmp_path / "bad_gt"
    bad_gt.mkdir()
    (bad_gt / "1650000000003020.txt").write_text("1 2 3")
    with pytest.raises(ConslamError, match="4x4"):
        import_conslam(rec.bag, tmp_path / "s5", bad_gt)
    # A bag without the point topic.
    other = tmp_path / "other.bag"
    with Writer(other) as writer:
        c = writer.add_connection("/pp_rgb/synced2points", "sensor_msgs/msg/Image", typestore=TS)
        writer.write(
            c,
            T0_SEC * 10**9,
            TS.serialize_ros1(
                _image_msg(T0_SEC, 0, np.zeros((2, 2, 3), np.uint8)), "sensor_msgs/msg/Image"
            ),
        )
    with pytest.raises(ConslamError, match="pp_points/synced2rgb") as info:
        import_conslam(other, tmp_path / "s6")
    assert info.value.field == "topics"


def test_gt_folder_names_in_microseconds_or_seconds(tmp_path: Path) -> None:
    from bimcap.dataset.conslam import read_gt_folder

    pose = np.eye(4)
    pose[:3, 3] = [1, 2, 3]
    np.savetxt(tmp_path / "1650000000500000.txt", pose)
    np.savetxt(tmp_path / "1650000000.25.txt", pose[:3])  # 3x4 form, seconds in the name
    traj = read_gt_folder(tmp_path)
    np.testing.assert_allclose(traj.timestamps, [1650000000.25, 1650000000.5], rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.poses, [[1, 2, 3, 0, 0, 0, 1]] * 2, atol=1e-15)


def test_pair_nearest_uses_each_scan_once() -> None:
    ia, ib = pair_nearest([0.0, 0.1, 0.2, 0.5], [0.11, 0.09, 0.21, 0.9], 0.03)
    # 0.1 takes its nearest scan 0.09 or 0.11 (both 0.01 away; the first in order wins);
    # 0.0 is 0.09 from anything → unpaired; 0.5 has nothing within 30 ms.
    assert ia.tolist() == [1, 2]
    assert ib.tolist()[1] == 2 and ib.tolist()[0] in (0, 1)


def test_decode_pointcloud_field_offsets_and_endianness() -> None:
    pts = np.array([[1.5, -2.0, 3.25, 40.0], [0.0, 0.5, -1.0, 7.0]], np.float32)
    for big in (False, True):
        out = decode_pointcloud(
            TS.deserialize_ros1(
                TS.serialize_ros1(_cloud_msg(1, 0, pts, big), "sensor_msgs/msg/PointCloud2"),
                "sensor_msgs/msg/PointCloud2",
            )
        )
        np.testing.assert_array_equal(out, pts)
    assert CONSLAM_CAM_FROM_LIDAR.shape == (7,)
