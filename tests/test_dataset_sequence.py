"""Sequence directory: writer/reader round trip, and one rejection test per kind of bad input."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bimcap.dataset import (
    MANIFEST,
    VLP16,
    LidarInfo,
    SequenceError,
    SequenceWriter,
    add_trajectory,
    read_sequence,
)
from bimcap.geometry import Camera, Trajectory, read_tum

W, H, N = 16, 12, 4
CAMERA = Camera(W, H, 20.0, 21.0, 7.5, 5.5, (-0.05, 0.1, 0.001, -0.002, 0.0))
CAM_FROM_LIDAR = np.array(
    [0.1, -0.2, 0.3, *Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat()]
)


def _frame_data(rng: np.random.Generator, i: int) -> dict[str, Any]:
    return {
        "timestamp": 100.0 + 0.1 * i,
        "image": rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8),
        "lidar": rng.normal(size=(50 + i, 4)).astype(np.float32),
        "labels": rng.integers(0, 8, size=(H, W), dtype=np.uint8),
        "depth": rng.uniform(0.0, 10.0, size=(H, W)).astype(np.float32),
    }


def _poses(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.concatenate(
        [rng.normal(size=(n, 3)), Rotation.random(n, random_state=rng).as_quat()], 1
    )


@pytest.fixture
def written(tmp_path: Path) -> tuple[Path, list[dict[str, Any]], np.ndarray]:
    rng = np.random.default_rng(7)
    data = [_frame_data(rng, i) for i in range(N)]
    gt = _poses(rng, N)
    root = tmp_path / "seq"
    with SequenceWriter(
        root, CAMERA, CAM_FROM_LIDAR, ifc="../model.ifc", source={"by": "test"}
    ) as w:
        for i, d in enumerate(data):
            if i == 2:  # one frame without optional files
                w.add_frame(d["timestamp"], d["image"], d["lidar"])
            else:
                w.add_frame(**d)
        w.add_trajectory("gt", gt)
    return root, data, gt


def test_round_trip(written: tuple[Path, list[dict[str, Any]], np.ndarray]) -> None:
    root, data, gt = written
    seq = read_sequence(root)
    assert len(seq) == N
    assert seq.camera == CAMERA
    np.testing.assert_allclose(seq.cam_from_lidar, CAM_FROM_LIDAR, atol=1e-15)
    assert seq.lidar == VLP16
    assert seq.ifc_path == root / "../model.ifc"
    assert seq.source == {"by": "test"}
    np.testing.assert_array_equal(seq.timestamps, [d["timestamp"] for d in data])
    for i, d in enumerate(data):
        img = seq.load_image(i)
        assert img.dtype == np.uint8 and img.shape == (H, W, 3)
        np.testing.assert_array_equal(img, d["image"])  # RGB in, RGB out (not BGR)
        pts = seq.load_lidar(i)
        assert pts.dtype == np.float32 and pts.shape == d["lidar"].shape
        np.testing.assert_array_equal(pts, d["lidar"])
        if i == 2:
            assert seq.load_labels(i) is None and seq.load_depth(i) is None
        else:
            np.testing.assert_array_equal(seq.load_labels(i), d["labels"])
            np.testing.assert_array_equal(seq.load_depth(i), d["depth"])
    assert not seq.has_labels and not seq.has_depth
    traj = seq.trajectory("gt")
    np.testing.assert_array_equal(traj.timestamps, seq.timestamps)
    np.testing.assert_allclose(traj.poses[:, :3], gt[:, :3], atol=0)
    same = np.abs(np.sum(traj.poses[:, 3:] * gt[:, 3:], axis=1))  # q and -q are one rotation
    np.testing.assert_allclose(same, 1.0, atol=1e-12)


def test_image_on_disk_is_rgb_png_read_by_opencv_as_bgr(
    written: tuple[Path, list[dict[str, Any]], np.ndarray],
) -> None:
    root, data, _ = written
    bgr = cv2.imread(str(root / "images" / "000000.png"), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(bgr[:, :, ::-1], data[0]["image"])
    raw = np.fromfile(root / "lidar" / "000001.bin", dtype="<f4").reshape(-1, 4)
    np.testing.assert_array_equal(raw, data[1]["lidar"])


def test_subset_view_and_its_trajectory(
    written: tuple[Path, list[dict[str, Any]], np.ndarray],
) -> None:
    root, _, gt = written
    seq = read_sequence(root)
    sub = seq.subset([1, 3])
    assert len(sub) == 2 and [f.index for f in sub.frames] == [1, 3]
    np.testing.assert_array_equal(sub.load_image(1), seq.load_image(3))
    np.testing.assert_allclose(sub.trajectory("gt").poses[:, :3], gt[[1, 3], :3])
    assert len(seq.subset(slice(0, 2))) == 2
    assert [f.index for f in seq.subset([-3, -1]).frames] == [1, 3]
    assert [f.index for f in sub.subset([1]).frames] == [3]  # a view of a view
    np.testing.assert_allclose(sub.subset([1]).trajectory().poses[0, :3], gt[3, :3])
    with pytest.raises(SequenceError, match="out of range"):
        seq.subset([4])
    with pytest.raises(SequenceError, match="increase"):
        seq.subset([2, 1])


def test_add_trajectory_registers_and_protects_gt(
    written: tuple[Path, list[dict[str, Any]], np.ndarray],
) -> None:
    root, _, gt = written
    seq = read_sequence(root)
    init = Trajectory(seq.timestamps, gt)
    path = add_trajectory(seq, "init", init)
    assert path == root / "poses" / "init.tum"
    again = read_sequence(root)
    assert again.poses["init"] == "poses/init.tum"
    np.testing.assert_allclose(again.trajectory("init").poses[:, :3], gt[:, :3])
    with pytest.raises(SequenceError, match="already exists"):
        add_trajectory(seq, "init", init)
    add_trajectory(seq, "init", init, overwrite=True)
    with pytest.raises(SequenceError, match="ground truth"):
        add_trajectory(seq, "gt", init, overwrite=True)
    with pytest.raises(SequenceError, match="one pose per frame"):
        add_trajectory(seq, "short", init.subset(slice(0, 2)))


# ----------------------------------------------------------------------------- writer refusals
def test_writer_refuses_bad_frames(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    d = _frame_data(rng, 0)
    w = SequenceWriter(tmp_path / "s", CAMERA, CAM_FROM_LIDAR)
    w.add_frame(**d)
    with pytest.raises(SequenceError, match="increasing time order"):
        w.add_frame(d["timestamp"], d["image"], d["lidar"])
    t = d["timestamp"] + 1
    with pytest.raises(SequenceError, match=r"frames\[1\]\.image"):
        w.add_frame(t, d["image"][:-1], d["lidar"])
    with pytest.raises(SequenceError, match=r"frames\[1\]\.image"):
        w.add_frame(t, d["image"].astype(np.float32), d["lidar"])
    with pytest.raises(SequenceError, match=r"frames\[1\]\.lidar"):
        w.add_frame(t, d["image"], d["lidar"][:, :3])
    with pytest.raises(SequenceError, match=r"frames\[1\]\.labels"):
        w.add_frame(t, d["image"], d["lidar"], labels=d["labels"].T)
    with pytest.raises(SequenceError, match=r"frames\[1\]\.labels"):
        w.add_frame(t, d["image"], d["lidar"], labels=np.full((H, W), 200, np.uint8))
    with pytest.raises(SequenceError, match=r"frames\[1\]\.depth"):
        w.add_frame(t, d["image"], d["lidar"], depth=np.full((H, W), np.nan, np.float32))
    w.add_trajectory("gt", _poses(rng, 2))
    with pytest.raises(SequenceError, match="2 poses for 1 frames"):
        w.close()
    assert not (tmp_path / "s" / MANIFEST).exists()  # the manifest is written last, or never


def test_writer_context_manager_writes_no_manifest_on_error(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)

    def crash() -> None:
        with SequenceWriter(tmp_path / "s", CAMERA, CAM_FROM_LIDAR) as w:
            w.add_frame(**_frame_data(rng, 0))
            raise RuntimeError("simulated crash")

    with pytest.raises(RuntimeError):
        crash()
    assert (tmp_path / "s" / "images" / "000000.png").exists()
    assert not (tmp_path / "s" / MANIFEST).exists()
    with pytest.raises(SequenceError, match="no manifest"):
        read_sequence(tmp_path / "s")


def test_writer_refuses_existing_sequence(
    written: tuple[Path, list[dict[str, Any]], np.ndarray],
) -> None:
    root, _, _ = written
    with pytest.raises(SequenceError, match="already a sequence"):
        SequenceWriter(root, CAMERA, CAM_FROM_LIDAR)
    SequenceWriter(root, CAMERA, CAM_FROM_LIDAR, overwrite=True)


# ----------------------------------------------------------------------------- reader refusals
Edit = Callable[[dict[str, Any], Path], None]


def _set(path: str, value: Any) -> Edit:
    def edit(doc: dict[str, Any], root: Path) -> None:
        keys = path.split(".")
        obj: Any = doc
        for k in keys[:-1]:
            obj = obj[int(k)] if isinstance(obj, list) else obj[k]
        last = keys[-1]
        if value is _DELETE:
            del obj[last]
        elif isinstance(obj, list):
            obj[int(last)] = value
        else:
            obj[last] = value

    return edit


_DELETE = object()


def _q(norm: float) -> list[float]:
    return [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, norm]


def _truncate(rel: str, nbytes: int) -> Edit:
    def edit(doc: dict[str, Any], root: Path) -> None:
        data = (root / rel).read_bytes()
        (root / rel).write_bytes(data[:nbytes])

    return edit


def _remove(rel: str) -> Edit:
    def edit(doc: dict[str, Any], root: Path) -> None:
        (root / rel).unlink()

    return edit


def _drop_last_pose(doc: dict[str, Any], root: Path) -> None:
    p = root / "poses" / "gt.tum"
    lines = p.read_text().splitlines()
    p.write_text("\n".join(lines[:-1]) + "\n")


def _drop_last_frame(doc: dict[str, Any], root: Path) -> None:
    doc["frames"].pop()


BAD: list[tuple[str, Edit, str, str]] = [
    # (id, edit, field named in the error, message fragment)
    ("missing format", _set("format", _DELETE), "format", "missing"),
    ("wrong format", _set("format", "colmap"), "format", "bimcap-sequence"),
    ("wrong version", _set("version", 2), "version", "unsupported version"),
    ("version as string", _set("version", "1"), "version", "unsupported version"),
    ("missing camera", _set("camera", _DELETE), "camera", "missing"),
    ("missing width", _set("camera.width", _DELETE), "camera.width", "missing"),
    ("zero height", _set("camera.height", 0), "camera.height", "positive integer"),
    ("bad model", _set("camera.model", "fisheye"), "camera.model", "plumb_bob"),
    ("short K", _set("camera.K", [1.0, 2.0, 3.0]), "camera.K", "4 numbers"),
    ("negative fx", _set("camera.K", [-1.0, 2.0, 3.0, 4.0]), "camera.K", "positive"),
    ("nan dist", _set("camera.dist.0", "nan"), "camera.dist[0]", "number"),
    ("missing extrinsic", _set("cam_from_lidar", _DELETE), "cam_from_lidar", "missing"),
    ("short extrinsic", _set("cam_from_lidar", [0.0] * 6), "cam_from_lidar", "7 numbers"),
    ("non-unit quaternion", _set("cam_from_lidar", _q(1.01)), "cam_from_lidar", "norm"),
    ("non-finite extrinsic", _set("cam_from_lidar.0", 1e400), "cam_from_lidar[0]", "finite"),
    ("lidar without model", _set("lidar.model", _DELETE), "lidar.model", "model"),
    ("lidar bad channels", _set("lidar.channels", -3), "lidar.channels", "positive"),
    (
        "lidar bad fov",
        _set("lidar.vertical_fov_deg", [15, -15]),
        "lidar.vertical_fov_deg",
        "lowest",
    ),
    ("ifc not a string", _set("ifc", 3), "ifc", "path"),
    ("no frames", _set("frames", []), "frames", "non-empty"),
    ("frame without image", _set("frames.1.image", _DELETE), "frames[1].image", "missing"),
    ("frame timestamp text", _set("frames.1.timestamp", "x"), "frames[1].timestamp", "number"),
    (
        "timestamps not increasing",
        _set("frames.2.timestamp", 100.1),
        "frames[2].timestamp",
        "increase",
    ),
    ("path escaping root", _set("frames.0.image", "../x.png"), "frames[0].image", "inside"),
    ("absolute path", _set("frames.0.lidar", "/etc/passwd"), "frames[0].lidar", "inside"),
    ("missing image file", _remove("images/000001.png"), "frames[1].image", "does not exist"),
    ("missing labels file", _remove("labels/000003.png"), "frames[3].labels", "does not exist"),
    ("missing depth file", _remove("depth/000000.npy"), "frames[0].depth", "does not exist"),
    ("lidar size", _truncate("lidar/000001.bin", 18), "frames[1].lidar", "multiple of 16"),
    ("missing pose file", _remove("poses/gt.tum"), "poses.gt", "does not exist"),
    ("pose count", _drop_last_pose, "poses.gt", "3 poses for 4 frames"),
    ("frame count", _drop_last_frame, "poses.gt", "4 poses for 3 frames"),
    ("pose timestamps", _set("frames.3.timestamp", 200.0), "poses.gt", "timestamp"),
    ("poses not an object", _set("poses", ["gt"]), "poses", "object"),
    ("source not an object", _set("source", 3), "source", "object"),
]


@pytest.mark.parametrize(
    ("edit", "field", "fragment"), [b[1:] for b in BAD], ids=[b[0] for b in BAD]
)
def test_reader_rejects_malformed(
    written: tuple[Path, list[dict[str, Any]], np.ndarray], edit: Edit, field: str, fragment: str
) -> None:
    root, _, _ = written
    manifest = root / MANIFEST
    doc = json.loads(manifest.read_text())
    edit(doc, root)
    manifest.write_text(json.dumps(doc))
    with pytest.raises(SequenceError) as info:
        read_sequence(root)
    err = info.value
    assert err.field == field, str(err)
    assert fragment in str(err)
    assert str(manifest) in str(err)


def test_reader_rejects_invalid_json_and_non_object(tmp_path: Path) -> None:
    (tmp_path / MANIFEST).write_text("{not json")
    with pytest.raises(SequenceError, match="not valid JSON"):
        read_sequence(tmp_path)
    (tmp_path / MANIFEST).write_text("[1, 2]")
    with pytest.raises(SequenceError, match="JSON object"):
        read_sequence(tmp_path / MANIFEST)


def test_loaders_reject_wrong_sizes(written: tuple[Path, list[dict[str, Any]], np.ndarray]) -> None:
    root, _, _ = written
    seq = read_sequence(root)
    _, buf = cv2.imencode(".png", np.zeros((H + 1, W, 3), np.uint8))
    (root / "images" / "000000.png").write_bytes(buf.tobytes())
    with pytest.raises(SequenceError, match=r"17x12|16x13") as info:
        seq.load_image(0)
    assert info.value.field == "frames[0].image"
    _, buf = cv2.imencode(".png", np.zeros((H, W, 3), np.uint8))
    (root / "labels" / "000000.png").write_bytes(buf.tobytes())
    with pytest.raises(SequenceError, match="single-channel") as info:
        seq.load_labels(0)
    assert info.value.field == "frames[0].labels"
    np.save(root / "depth" / "000000.npy", np.zeros((H, W), np.float64))
    with pytest.raises(SequenceError, match="float32"):
        seq.load_depth(0)
    (root / "images" / "000001.png").write_bytes(b"garbage")
    with pytest.raises(SequenceError, match="cannot decode"):
        seq.load_image(1)
    (root / "lidar" / "000001.bin").write_bytes(b"\0" * 20)
    with pytest.raises(SequenceError, match="multiple of 16"):
        seq.load_lidar(1)


def test_reader_accepts_extra_lidar_keys_and_moved_directory(
    written: tuple[Path, list[dict[str, Any]], np.ndarray], tmp_path: Path
) -> None:
    root, _, _ = written
    doc = json.loads((root / MANIFEST).read_text())
    doc["lidar"]["dropout"] = 0.05
    (root / MANIFEST).write_text(json.dumps(doc))
    moved = tmp_path / "elsewhere"
    shutil.move(root, moved)
    seq = read_sequence(moved)
    assert seq.lidar.extra == {"dropout": 0.05}
    assert seq.lidar.to_dict()["dropout"] == 0.05
    assert LidarInfo.from_dict(seq.lidar.to_dict()) == seq.lidar
    assert read_tum(seq.trajectory_path("gt")).poses.shape == (N, 7)


def test_frames_written_by_workers_then_registered(tmp_path: Path) -> None:
    """The parallel workflow: write_frame anywhere (any order), register_frame in order."""
    from concurrent.futures import ThreadPoolExecutor

    from bimcap.dataset import frame_info, write_frame

    rng = np.random.default_rng(3)
    data = [_frame_data(rng, i) for i in range(N)]
    root = tmp_path / "par"
    w = SequenceWriter(root, CAMERA, CAM_FROM_LIDAR, png_compression=0)
    with ThreadPoolExecutor(2) as pool:
        infos = list(
            pool.map(
                lambda i: write_frame(
                    root,
                    i,
                    data[i]["timestamp"],
                    CAMERA,
                    data[i]["image"],
                    data[i]["lidar"],
                    data[i]["labels"],
                    png_compression=9,
                ),
                reversed(range(N)),
            )
        )[::-1]
    assert infos[0] == frame_info(0, data[0]["timestamp"], labels=True)
    with pytest.raises(SequenceError, match="expected frame 0"):
        w.register_frame(infos[1])
    for info in infos:
        w.register_frame(info)
    with pytest.raises(SequenceError, match="does not exist"):
        w.register_frame(frame_info(N, 999.0))  # its files were never written
    seq = w.close()
    for i in range(N):
        np.testing.assert_array_equal(seq.load_image(i), data[i]["image"])
        np.testing.assert_array_equal(seq.load_labels(i), data[i]["labels"])
        assert seq.load_depth(i) is None
    with pytest.raises(SequenceError, match=r"frames\[0\]\.image"):
        write_frame(root, 0, 0.0, CAMERA, np.zeros((H, W), np.uint8), data[0]["lidar"])


def test_true_labels_beside_noisy_ones(tmp_path: Path) -> None:
    """``labels_gt`` (the simulator's label noise): written, listed, read, validated."""
    from bimcap.dataset import write_frame

    rng = np.random.default_rng(5)
    data = [_frame_data(rng, i) for i in range(2)]
    root = tmp_path / "noisy"
    w = SequenceWriter(root, CAMERA, CAM_FROM_LIDAR)
    truth = [rng.integers(0, 8, size=(H, W), dtype=np.uint8) for _ in range(2)]
    for i, d in enumerate(data):
        w.register_frame(write_frame(root, i, d["timestamp"], CAMERA, d["image"], d["lidar"],
                                     d["labels"], labels_gt=truth[i] if i == 0 else None))
    w.add_trajectory("gt", _poses(rng, 2))
    seq = w.close()
    doc = json.loads((root / MANIFEST).read_text())
    assert doc["frames"][0]["labels_gt"] == "labels_gt/000000.png"
    assert "labels_gt" not in doc["frames"][1]  # absent, not null: old manifests unchanged
    np.testing.assert_array_equal(seq.load_labels(0, truth=True), truth[0])
    np.testing.assert_array_equal(seq.load_labels(0), data[0]["labels"])
    np.testing.assert_array_equal(seq.load_labels(1, truth=True), data[1]["labels"])
    (root / "labels_gt" / "000000.png").unlink()
    with pytest.raises(SequenceError, match=r"frames\[0\]\.labels_gt"):
        read_sequence(root)
    with pytest.raises(SequenceError, match="labels_gt"):
        write_frame(root, 5, 9.0, CAMERA, data[0]["image"], data[0]["lidar"], None,
                    labels_gt=truth[0])
    with pytest.raises(SequenceError, match="labels_gt"):
        write_frame(root, 5, 9.0, CAMERA, data[0]["image"], data[0]["lidar"], data[0]["labels"],
                    labels_gt=truth[0][:, :3])
