"""import-bag: ROS1 and ROS2 bags written here with rosbags' own writers round-trip into a
sequence (frames, pixels, points, calibration, timestamps, trajectories), and bad input gives a
clear error."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from bimcap.cli import main
from bimcap.dataset import read_sequence
from bimcap.dataset.bag import BagError, BagTopics, import_bag, list_topics
from bimcap.dataset.calib import CalibrationError
from bimcap.dataset.importing import (
    DataImportError,
    ImportOptions,
    PoseSensor,
    TrajectoryInput,
)
from bimcap.dataset.ros import header_stamp
from bimcap.geometry.pose_formats import PoseFormat, write_kitti
from bimcap.geometry.trajectory import Trajectory, TrajectoryError, write_tum

TS1 = get_typestore(Stores.ROS1_NOETIC)
TS2 = get_typestore(Stores.ROS2_HUMBLE)
T0 = 1_700_000_000
W, H = 32, 24
K_INFO = (310.0, 311.0, 15.5, 11.5)
D_INFO = (-0.04, 0.09, 0.001, -0.002, 0.0)
# cam_from_lidar as a plain matrix: LiDAR x forward → camera z, LiDAR y left → camera -x.
R_CL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
T_CL = np.array([0.05, -0.1, 0.02])
IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC = "/cam/image_raw", "/lidar/points", "/cam/camera_info"


def _cam_from_lidar() -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R_CL, T_CL
    return m


def _write_extrinsic(path: Path) -> Path:
    path.write_text("# LiDAR -> camera\nT_cam_lidar:\n"
                    + "".join(f"  - {row.tolist()}\n" for row in _cam_from_lidar()))
    return path


def _pose_matrix(pose: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(pose[3:]).as_matrix()
    m[:3, 3] = pose[:3]
    return m


# ----------------------------------------------------------------------------- messages
class Msgs:
    """Message builders for one ROS version (field names differ between the type stores)."""

    def __init__(self, ros2: bool) -> None:
        self.ros2 = ros2
        self.ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
        if not ros2:  # Noetic's store lacks tf2_msgs; register it from its definition
            self.ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                                "tf2_msgs/msg/TFMessage"))
        self.image_frame = self.cloud_frame = "f"

    def serialize(self, msg: Any, msgtype: str) -> bytes:
        data = self.ts.serialize_cdr(msg, msgtype) if self.ros2 else self.ts.serialize_ros1(
            msg, msgtype)
        return bytes(data)

    def header(self, t_ns: int, frame_id: str = "f") -> Any:
        Header = self.ts.types["std_msgs/msg/Header"]
        Time = self.ts.types["builtin_interfaces/msg/Time"]
        stamp = Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        if self.ros2:
            return Header(stamp=stamp, frame_id=frame_id)
        return Header(seq=0, stamp=stamp, frame_id=frame_id)

    def tf_static(self, t_ns: int, edges: list[tuple[str, str, np.ndarray]]) -> Any:
        """A TFMessage of (parent, child, parent_from_child 4×4) transforms."""
        from scipy.spatial.transform import Rotation

        ty = self.ts.types
        out = []
        for parent, child, m in edges:
            x, y, z, w = Rotation.from_matrix(m[:3, :3]).as_quat()
            tr = ty["geometry_msgs/msg/Transform"](
                translation=ty["geometry_msgs/msg/Vector3"](x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                rotation=ty["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w))
            out.append(ty["geometry_msgs/msg/TransformStamped"](
                header=self.header(t_ns, parent), child_frame_id=child, transform=tr))
        return ty["tf2_msgs/msg/TFMessage"](transforms=out)

    def image(self, t_ns: int, rgb: np.ndarray, encoding: str) -> Any:
        Image = self.ts.types["sensor_msgs/msg/Image"]
        h, w, _ = rgb.shape
        px = rgb[:, :, ::-1] if encoding == "bgr8" else rgb
        step = w * 3 + 4
        buf = np.full((h, step), 99, np.uint8)  # padding bytes that must not leak
        buf[:, : w * 3] = px.reshape(h, w * 3)
        return Image(header=self.header(t_ns, self.image_frame), height=h, width=w,
                     encoding=encoding, is_bigendian=0, step=step, data=buf.ravel())

    def compressed(self, t_ns: int, rgb: np.ndarray) -> Any:
        Compressed = self.ts.types["sensor_msgs/msg/CompressedImage"]
        ok, png = cv2.imencode(".png", rgb[:, :, ::-1])
        assert ok
        return Compressed(header=self.header(t_ns, self.image_frame),
                          format="rgb8; png compressed bgr8", data=png.ravel())

    def cloud(self, t_ns: int, xyzi: np.ndarray, bigendian: bool = False) -> Any:
        PointCloud2 = self.ts.types["sensor_msgs/msg/PointCloud2"]
        PointField = self.ts.types["sensor_msgs/msg/PointField"]
        o = ">" if bigendian else "<"
        dt = np.dtype({"names": ["x", "y", "z", "intensity"],
                       "formats": [o + "f4", o + "f4", o + "f4", o + "f4"],
                       "offsets": [0, 4, 8, 16], "itemsize": 20})
        arr = np.zeros(len(xyzi), dtype=dt)
        for k, name in enumerate(("x", "y", "z", "intensity")):
            arr[name] = xyzi[:, k]
        fields = [PointField(name=n, offset=off, datatype=7, count=1)
                  for n, off in (("x", 0), ("y", 4), ("z", 8), ("intensity", 16))]
        return PointCloud2(header=self.header(t_ns, self.cloud_frame), height=1,
                           width=len(xyzi), fields=fields, is_bigendian=bigendian,
                           point_step=20, row_step=20 * len(xyzi),
                           data=np.frombuffer(arr.tobytes(), np.uint8), is_dense=False)

    def info(self, t_ns: int) -> Any:
        CameraInfo = self.ts.types["sensor_msgs/msg/CameraInfo"]
        RoI = self.ts.types["sensor_msgs/msg/RegionOfInterest"]
        fx, fy, cx, cy = K_INFO
        k = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], float)
        mats = {"D": np.array(D_INFO), "K": k, "R": np.eye(3).ravel(), "P": np.zeros(12)}
        if self.ros2:
            mats = {key.lower(): v for key, v in mats.items()}
        return CameraInfo(header=self.header(t_ns), height=H, width=W,
                          distortion_model="plumb_bob", binning_x=0, binning_y=0,
                          roi=RoI(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
                          **mats)


@dataclass
class Recording:
    bag: Path
    images: list[np.ndarray] = field(default_factory=list)  # per expected frame
    clouds: list[np.ndarray] = field(default_factory=list)  # per expected frame, finite only
    times: list[float] = field(default_factory=list)  # image stamps of expected frames
    all_image_times: list[float] = field(default_factory=list)


def write_bag(path: Path, ros2: bool, encoding: str = "rgb8", with_info: bool = True,
              image_topic: str = IMAGE_TOPIC,
              tf: list[tuple[str, str, np.ndarray]] | None = None,
              mcap: bool = False) -> Recording:
    """Six images 0.1 s apart; clouds 4 ms later except after image 2 (none); one lone cloud
    at the end; cloud 3 big-endian; one NaN point per cloud (dropped). With ``tf``: images in
    frame ``cam_optical``, clouds in ``os_lidar``, and a /tf_static message of ``tf``."""
    m = Msgs(ros2)
    if tf is not None:
        m.image_frame, m.cloud_frame = "cam_optical", "/os_lidar"
    rng = np.random.default_rng(1)
    rec = Recording(path)
    image_type = ("sensor_msgs/msg/CompressedImage" if encoding == "png"
                  else "sensor_msgs/msg/Image")
    plugin = StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3
    writer = Writer2(path, version=9, storage_plugin=plugin) if ros2 else Writer1(path)
    with writer:
        typestore = m.ts
        c_img = writer.add_connection(image_topic, image_type, typestore=typestore)
        c_pts = writer.add_connection(CLOUD_TOPIC, "sensor_msgs/msg/PointCloud2",
                                      typestore=typestore)
        c_info = writer.add_connection(INFO_TOPIC, "sensor_msgs/msg/CameraInfo",
                                       typestore=typestore)
        writer.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=typestore)
        if tf is not None:
            c_tf = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage",
                                         typestore=typestore)
            writer.write(c_tf, T0 * 10**9, m.serialize(m.tf_static(T0 * 10**9, tf),
                                                       "tf2_msgs/msg/TFMessage"))
        if with_info:
            writer.write(c_info, T0 * 10**9, m.serialize(m.info(T0 * 10**9),
                                                         "sensor_msgs/msg/CameraInfo"))
        for k in range(6):
            t_img = T0 * 10**9 + 100_000_000 * k + 20_000
            t_pts = t_img + 4_000_000
            rgb = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
            msg = m.compressed(t_img, rgb) if encoding == "png" else m.image(t_img, rgb,
                                                                             encoding)
            # record time 1 ms after the stamp: the importer must use the header stamps
            writer.write(c_img, t_img + 1_000_000, m.serialize(msg, image_type))
            rec.all_image_times.append(t_img * 1e-9)
            if k == 2:
                continue
            pts = rng.normal(0.0, 4.0, size=(30 + k, 4)).astype(np.float32)
            pts[7, 0] = np.nan
            writer.write(c_pts, t_pts + 1_000_000,
                         m.serialize(m.cloud(t_pts, pts, bigendian=(k == 3)),
                                     "sensor_msgs/msg/PointCloud2"))
            rec.images.append(rgb)
            rec.clouds.append(np.delete(pts, 7, axis=0))
            rec.times.append(t_img * 1e-9)
        lone = T0 * 10**9 + 900_000_000
        writer.write(c_pts, lone, m.serialize(m.cloud(lone, np.ones((3, 4), np.float32)),
                                              "sensor_msgs/msg/PointCloud2"))
    return rec


def _check_sequence(seq_dir: Path, rec: Recording) -> Any:
    """The imported sequence, loaded with bimcap's own loader, against what was written."""
    seq = read_sequence(seq_dir)
    assert len(seq) == len(rec.images) == 5
    np.testing.assert_allclose(seq.timestamps, rec.times, rtol=0, atol=5e-7)  # ulp 2.4e-7
    for i in range(len(seq)):
        np.testing.assert_array_equal(seq.load_image(i), rec.images[i])
        np.testing.assert_array_equal(seq.load_lidar(i), rec.clouds[i])
    cam = seq.camera
    assert (cam.width, cam.height) == (W, H)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == K_INFO
    assert cam.dist == D_INFO
    np.testing.assert_allclose(_pose_matrix(seq.cam_from_lidar), _cam_from_lidar(), atol=1e-12)
    return seq


# ----------------------------------------------------------------------------- round trips
@pytest.mark.parametrize(("ros2", "encoding"), [(False, "rgb8"), (True, "bgr8"), (True, "png")])
def test_round_trip_with_camera_info_topic(tmp_path: Path, ros2: bool, encoding: str) -> None:
    rec = write_bag(tmp_path / ("rec" if ros2 else "rec.bag"), ros2, encoding)
    seen: list[tuple[str, int, int]] = []
    opts = ImportOptions(progress=lambda stage, done, total: seen.append((stage, done, total)))
    res = import_bag(rec.bag, tmp_path / "seq", BagTopics(IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC),
                     lidar_extrinsic=_write_extrinsic(tmp_path / "ext.yaml"), options=opts)
    assert (res.n_images, res.n_clouds, res.n_pairs, res.n_frames) == (6, 6, 5, 5)
    assert res.max_pair_dt_s == pytest.approx(0.004, abs=1e-6)  # float s at 1.7e9
    seq = _check_sequence(tmp_path / "seq", rec)
    assert seq.source["importer"] == "bimcap.dataset.bag"
    assert seq.source["ros_version"] == (2 if ros2 else 1)
    assert seq.poses == {}
    assert ("index", 13, 13) in seen and ("write", 5, 5) in seen  # 6 + 6 + 1 messages


def test_ros2_mcap_bag_directory_or_its_storage_file(tmp_path: Path) -> None:
    rec = write_bag(tmp_path / "rec", ros2=True, mcap=True)
    topics = BagTopics(IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC)
    ext = _write_extrinsic(tmp_path / "ext.yaml")
    import_bag(rec.bag, tmp_path / "a", topics, lidar_extrinsic=ext)
    _check_sequence(tmp_path / "a", rec)
    import_bag(rec.bag / "rec.mcap", tmp_path / "b", topics, lidar_extrinsic=ext)
    _check_sequence(tmp_path / "b", rec)


def test_ros2_with_calib_file_and_tum_trajectory(tmp_path: Path) -> None:
    """Camera from a camera_info YAML holding the extrinsic too; camera poses from TUM."""
    rec = write_bag(tmp_path / "rec", ros2=True, with_info=False)
    calib = tmp_path / "cam.yaml"
    fx, fy, cx, cy = K_INFO
    calib.write_text(
        f"image_width: {W}\nimage_height: {H}\ncamera_name: cam\n"
        f"camera_matrix: {{rows: 3, cols: 3, data: [{fx}, 0, {cx}, 0, {fy}, {cy}, 0, 0, 1]}}\n"
        "distortion_model: plumb_bob\n"
        f"distortion_coefficients: {{rows: 1, cols: 5, data: {list(D_INFO)}}}\n"
        f"T_cam_lidar: {_cam_from_lidar().tolist()}\n")
    poses = np.array([[0.5 * k, 1.0, 1.5, 0, 0, np.sin(0.1 * k), np.cos(0.1 * k)]
                      for k in range(6)])
    tum = tmp_path / "slam.tum"
    write_tum(tum, Trajectory(np.array(rec.all_image_times) + 0.002, poses))
    opts = ImportOptions(trajectory=TrajectoryInput(tum, PoseFormat.TUM, tolerance_s=0.01))
    res = import_bag(rec.bag, tmp_path / "seq", BagTopics(IMAGE_TOPIC, CLOUD_TOPIC),
                     calib=calib, options=opts)
    assert res.pose_match == "timestamp" and res.max_pose_dt_s == pytest.approx(0.002, abs=1e-6)
    seq = _check_sequence(tmp_path / "seq", rec)
    np.testing.assert_allclose(seq.trajectory("init").poses, poses[[0, 1, 3, 4, 5]], atol=1e-12)
    assert seq.source["calibration"]["format"] == "camera_info"


def test_ros1_lidar_poses_from_kitti_become_camera_poses(tmp_path: Path) -> None:
    """KITTI rows are matched to the images by order; LiDAR poses are composed with the
    extrinsic: world_from_cam = world_from_lidar · cam_from_lidar⁻¹ (plain matrices here)."""
    rec = write_bag(tmp_path / "rec.bag", ros2=False)
    world_from_lidar = np.tile(np.eye(4), (6, 1, 1))
    for k in range(6):
        a = 0.3 * k
        world_from_lidar[k, :3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0],
                                       [0, 0, 1]]
        world_from_lidar[k, :3, 3] = [k, 2.0 - k, 1.2]
    kitti = tmp_path / "lidar.txt"
    write_kitti(kitti, world_from_lidar)
    traj = TrajectoryInput(kitti, PoseFormat.KITTI, sensor=PoseSensor.LIDAR, name="gt")
    res = import_bag(rec.bag, tmp_path / "seq", BagTopics(IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC),
                     lidar_extrinsic=_write_extrinsic(tmp_path / "ext.yaml"),
                     options=ImportOptions(trajectory=traj))
    assert res.pose_match == "order"
    seq = _check_sequence(tmp_path / "seq", rec)
    gt = seq.trajectory("gt")
    for i, k in enumerate([0, 1, 3, 4, 5]):
        expected = world_from_lidar[k] @ np.linalg.inv(_cam_from_lidar())
        np.testing.assert_allclose(_pose_matrix(gt.poses[i]), expected, atol=1e-9)


def test_camera_info_found_beside_the_image_topic_and_cli(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    rec = write_bag(tmp_path / "rec", ros2=True)
    ext = _write_extrinsic(tmp_path / "ext.yaml")
    assert main(["import-bag", str(rec.bag), "-o", str(tmp_path / "seq"), "--image-topic",
                 IMAGE_TOPIC.lstrip("/"), "--cloud-topic", CLOUD_TOPIC, "--lidar-extrinsic",
                 str(ext), "--lidar-model", "OS1-64"]) == 0
    out = capsys.readouterr().out
    assert "5 frames from 6 images / 6 clouds" in out and "camera_info topic" in out
    seq = _check_sequence(tmp_path / "seq", rec)
    assert seq.lidar.model == "OS1-64"
    # Existing output: refused without --overwrite, one line, exit 2.
    assert main(["import-bag", str(rec.bag), "-o", str(tmp_path / "seq"), "--image-topic",
                 IMAGE_TOPIC, "--cloud-topic", CLOUD_TOPIC, "--lidar-extrinsic", str(ext)]) == 2
    assert "already a sequence" in capsys.readouterr().err
    assert main(["import-bag", str(rec.bag), "--list"]) == 0
    listing = capsys.readouterr().out
    assert "/imu\tsensor_msgs/msg/Imu\t0" in listing
    assert f"{CLOUD_TOPIC}\tsensor_msgs/msg/PointCloud2\t6" in listing
    assert list_topics(rec.bag)[0] == (INFO_TOPIC, "sensor_msgs/msg/CameraInfo", 1)


# ----------------------------------------------------------------------------- errors
def test_missing_topic_names_the_topics_of_the_bag(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    for ros2 in (False, True):
        rec = write_bag(tmp_path / ("r2" if ros2 else "r1.bag"), ros2)
        with pytest.raises(BagError, match=r"'/camera/color'.*not in the bag") as info:
            import_bag(rec.bag, tmp_path / "s", BagTopics("/camera/color", CLOUD_TOPIC),
                       lidar_extrinsic="identity")
        msg = str(info.value)
        assert info.value.field == "topics"
        for topic in (IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC, "/imu"):
            assert topic in msg
        assert "sensor_msgs/msg/PointCloud2, 6 msgs" in msg
    # Through the CLI: one line, exit 2, no traceback.
    assert main(["import-bag", str(rec.bag), "-o", str(tmp_path / "s"), "--image-topic",
                 IMAGE_TOPIC, "--cloud-topic", "/velodyne_points", "--lidar-extrinsic",
                 "identity"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'/velodyne_points'" in err and "Traceback" not in err


def test_wrong_type_no_pairs_no_camera_no_extrinsic(tmp_path: Path) -> None:
    rec = write_bag(tmp_path / "rec", ros2=True, with_info=False)
    topics = BagTopics(IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC)
    with pytest.raises(BagError, match="carries sensor_msgs/msg/Image, expected"):
        import_bag(rec.bag, tmp_path / "s", BagTopics(IMAGE_TOPIC, IMAGE_TOPIC),
                   lidar_extrinsic="identity")
    with_info = write_bag(tmp_path / "rec1.bag", ros2=False)
    with pytest.raises(DataImportError, match=r"no image/cloud pair within 0.001 s \(6 images at "):
        import_bag(with_info.bag, tmp_path / "s", topics, lidar_extrinsic="identity",
                   options=ImportOptions(tolerance_s=0.001))
    with pytest.raises(BagError, match="no message on the camera_info topic"):
        import_bag(rec.bag, tmp_path / "s", topics, lidar_extrinsic="identity")
    with pytest.raises(BagError, match="no LiDAR extrinsic"):
        import_bag(rec.bag, tmp_path / "s", topics)
    bad = tmp_path / "bad_ext.yaml"
    bad.write_text("T_cam_lidar: [[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    with pytest.raises(CalibrationError, match="T_cam_lidar: the 3x3 block is not a rotation"):
        import_bag(rec.bag, tmp_path / "s", topics, lidar_extrinsic=bad)
    # A malformed trajectory fails before the bag is read (no progress reported).
    bad_tum = tmp_path / "bad.tum"
    bad_tum.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 0\n")
    calls: list[tuple[str, int, int]] = []
    opts = ImportOptions(trajectory=TrajectoryInput(bad_tum),
                         progress=lambda *a: calls.append(a))
    with pytest.raises(TrajectoryError, match="line 2: expected 8 fields"):
        import_bag(with_info.bag, tmp_path / "s", topics, lidar_extrinsic="identity",
                   options=opts)
    assert calls == []
    assert not (tmp_path / "s" / "manifest.json").exists()


def test_unreadable_bags(tmp_path: Path) -> None:
    topics = BagTopics(IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC)
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all")
    with pytest.raises(BagError, match="cannot read the bag"):
        import_bag(junk, tmp_path / "s", topics, lidar_extrinsic="identity")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"without metadata\.yaml"):
        import_bag(tmp_path / "empty", tmp_path / "s", topics, lidar_extrinsic="identity")
    with pytest.raises(BagError, match="no such bag"):
        import_bag(tmp_path / "nope.bag", tmp_path / "s", topics, lidar_extrinsic="identity")


def test_header_stamp_reads_ros1_and_both_cdr_byte_orders() -> None:
    for ros2 in (False, True):
        m = Msgs(ros2)
        raw = m.serialize(m.header(1_700_000_123_456_789_012), "std_msgs/msg/Header")
        assert header_stamp(raw, ros2) == pytest.approx(1_700_000_123.456789012, abs=5e-7)
    big = bytes(TS2.serialize_cdr(Msgs(True).header(5 * 10**9 + 7), "std_msgs/msg/Header",
                                  little_endian=False))
    assert big[1] == 0 and header_stamp(big, ros2=True) == pytest.approx(5.000000007)


def test_a_conslam_bag_imports_the_same_through_import_bag(tmp_path: Path) -> None:
    """Oracle: the ConSLAM importer. The generic importer, given ConSLAM's topics and its
    published extrinsic as a YAML, writes the same frames, camera and extrinsic."""
    from bimcap.dataset.conslam import CONSLAM_CAM_FROM_LIDAR_MATRIX, import_conslam
    from test_conslam_import import _write_recording

    rec = _write_recording(tmp_path, 40, 30, with_info=True)
    a = import_conslam(rec.bag, tmp_path / "a").sequence
    ext = tmp_path / "conslam_ext.yaml"
    ext.write_text(f"T_cam_lidar: {CONSLAM_CAM_FROM_LIDAR_MATRIX.tolist()}\n")  # 3x4 form
    b = import_bag(rec.bag, tmp_path / "b", BagTopics("/pp_rgb/synced2points",
                                                      "pp_points/synced2rgb",
                                                      "pp_rgb/camera_info"),
                   lidar_extrinsic=ext).sequence
    assert len(a) == len(b) == 5
    np.testing.assert_array_equal(a.timestamps, b.timestamps)
    assert a.camera == b.camera
    np.testing.assert_allclose(a.cam_from_lidar, b.cam_from_lidar, atol=1e-12)
    for i in range(len(a)):
        np.testing.assert_array_equal(a.load_image(i), b.load_image(i))
        np.testing.assert_array_equal(a.load_lidar(i), b.load_lidar(i))


def test_camera_info_reasons_for_unusable_messages() -> None:
    from dataclasses import replace

    from bimcap.dataset.ros import camera_from_info_or_reason

    for ros2 in (False, True):
        m = Msgs(ros2)
        info = m.info(0)
        cam, _ = camera_from_info_or_reason(info)
        assert cam is not None and (cam.fx, cam.fy, cam.cx, cam.cy) == K_INFO
        k_name, d_name = ("k", "d") if ros2 else ("K", "D")
        cam, why = camera_from_info_or_reason(replace(info, **{k_name: np.zeros(9)}))
        assert cam is None and "not a calibrated camera matrix" in why
        cam, why = camera_from_info_or_reason(
            replace(info, distortion_model="equidistant", **{d_name: np.zeros(4)}))
        assert cam is None and "'equidistant'" in why
        eight = np.array([*D_INFO, 0.0, 0.0, 0.0])
        cam, _ = camera_from_info_or_reason(
            replace(info, distortion_model="rational_polynomial", **{d_name: eight}))
        assert cam is not None and cam.dist == D_INFO


@pytest.mark.parametrize("ros2", [False, True])
def test_extrinsic_from_tf_static(tmp_path: Path, ros2: bool) -> None:
    """--lidar-extrinsic tf: cam_from_lidar composed along /tf_static (base_link → os_sensor →
    os_lidar, base_link → cam_link → cam_optical; parent_from_child each), against plain
    matrix algebra."""
    base_from_sensor, sensor_from_lidar, base_from_link = (
        np.eye(4), np.eye(4), np.eye(4))
    base_from_sensor[:3, 3] = [0.1, 0.0, 0.3]
    sensor_from_lidar[:3, :3] = [[-1, 0, 0], [0, -1, 0], [0, 0, 1]]  # Ouster's 180° yaw
    sensor_from_lidar[:3, 3] = [0, 0, 0.036]
    a = 0.2
    base_from_link[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    base_from_link[:3, 3] = [0.25, 0.02, 0.1]
    link_from_optical = np.eye(4)
    link_from_optical[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # REP 103 optical frame
    tf = [("base_link", "os_sensor", base_from_sensor),
          ("os_sensor", "os_lidar", sensor_from_lidar),
          ("/base_link", "cam_link", base_from_link),
          ("cam_link", "cam_optical", link_from_optical)]
    rec = write_bag(tmp_path / ("r" if ros2 else "r.bag"), ros2, tf=tf)
    res = import_bag(rec.bag, tmp_path / "seq", BagTopics(IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC),
                     lidar_extrinsic="tf")
    expected = (np.linalg.inv(base_from_link @ link_from_optical)
                @ base_from_sensor @ sensor_from_lidar)
    np.testing.assert_allclose(_pose_matrix(res.sequence.cam_from_lidar), expected, atol=1e-9)
    assert res.sequence.source["calibration"]["extrinsic"] == "/tf_static: os_lidar -> cam_optical"
    broken = tf[:2] + tf[3:]  # base_link → cam_link missing
    rec = write_bag(tmp_path / ("b" if ros2 else "b.bag"), ros2, tf=broken)
    with pytest.raises(BagError, match="no chain of /tf_static transforms from the cloud's frame "
                       "'os_lidar' to the image's frame 'cam_optical'"):
        import_bag(rec.bag, tmp_path / "s2", BagTopics(IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC),
                   lidar_extrinsic="tf")
    plain = write_bag(tmp_path / ("p" if ros2 else "p.bag"), ros2)
    with pytest.raises(BagError, match="no /tf_static"):
        import_bag(plain.bag, tmp_path / "s3", BagTopics(IMAGE_TOPIC, CLOUD_TOPIC, INFO_TOPIC),
                   lidar_extrinsic="tf")


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "rgba8", "bgra8", "mono8"])
def test_decode_image_encodings(encoding: str) -> None:
    from types import SimpleNamespace

    from bimcap.dataset.ros import RosMessageError, decode_image

    rgb = np.random.default_rng(2).integers(0, 256, (3, 5, 3), dtype=np.uint8)
    if encoding == "mono8":
        rgb[:] = rgb[:, :, :1]
    px = {"rgb8": rgb, "bgr8": rgb[:, :, ::-1], "mono8": rgb[:, :, :1],
          "rgba8": np.dstack([rgb, np.full((3, 5), 7, np.uint8)]),
          "bgra8": np.dstack([rgb[:, :, ::-1], np.full((3, 5), 7, np.uint8)])}[encoding]
    step = 5 * px.shape[2] + 3
    buf = np.full((3, step), 255, np.uint8)
    buf[:, : 5 * px.shape[2]] = px.reshape(3, -1)
    msg = SimpleNamespace(height=3, width=5, step=step, encoding=encoding, data=buf.ravel())
    np.testing.assert_array_equal(decode_image(msg), rgb)
    with pytest.raises(RosMessageError, match="unsupported image encoding '16UC1'"):
        decode_image(SimpleNamespace(height=3, width=5, step=10, encoding="16UC1",
                                     data=np.zeros(30, np.uint8)))
