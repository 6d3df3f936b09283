"""COLMAP sparse models: arrays in, ``cameras`` / ``images`` / ``points3D`` files out.

Writes COLMAP's classic model, as text (``cameras.txt``, ``images.txt``, ``points3D.txt``, the
format of ``colmap model_converter --output_type TXT``) and/or binary (``.bin``), for one
undistorted PINHOLE camera shared by every image. COLMAP ≥ 3.12 and pycolmap 4 read it as well
(they add a trivial rig and one frame per image when ``rigs`` / ``frames`` files are absent).

Layout (:data:`MODEL_SUBDIR`, :data:`IMAGES_SUBDIR`): a workspace folder ``colmap/`` holding
``images/`` (the undistorted images the model's camera describes) and ``sparse/0/`` (the model).
That is the layout COLMAP itself produces (``colmap automatic_reconstructor`` writes
``sparse/0``, and ``images/`` beside it) and the one its users' tools expect: the GUI's
*File → Import model* on ``sparse/0`` with ``images/`` as the image folder, ``colmap
image_undistorter`` / ``patch_match_stereo``, Gaussian splatting (``<source>/images`` +
``<source>/sparse/0``) and nerfstudio (``ns-process-data`` / ``colmap/sparse/0``).

Conventions (the differences from bimcap's, handled here):

- COLMAP stores each image's ``cam_from_world`` as ``QW QX QY QZ TX TY TZ``; bimcap's poses are
  ``world_from_cam`` in TUM order ``[tx ty tz qx qy qz qw]``: inverted and reordered here.
- COLMAP's pixel origin is the top-left **corner** of the image (the first pixel centre is
  (0.5, 0.5)); bimcap's is the first pixel **centre** (``bimcap.features.sift``): 0.5 is added
  to every 2-D point written.
- Ids start at 1: image ``i`` (0-based) is ``IMAGE_ID`` ``i + 1``, point ``j`` is ``POINT3D_ID``
  ``j + 1``; the camera is ``CAMERA_ID`` 1. Each image lists only the observations of the
  written points (``POINT2D_IDX`` in the order given), so every 2-D point has a 3-D point.
- Numbers are written with 17 significant digits (a double survives the round trip).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.geometry.poses import invert
from bimcap.io.atomic import atomic_write_bytes, atomic_write_text

F64 = NDArray[np.float64]

#: Where the model goes inside a COLMAP workspace folder (module docstring).
MODEL_SUBDIR = "sparse/0"
#: Where the images the model's camera describes go inside the workspace folder.
IMAGES_SUBDIR = "images"
#: COLMAP's id of the PINHOLE camera model (``fx fy cx cy``).
PINHOLE_MODEL_ID = 1
#: COLMAP's offset of bimcap pixels: COLMAP (u, v) = bimcap (u, v) + 0.5.
PIXEL_OFFSET = 0.5


class ColmapError(InputError):
    """A COLMAP model that cannot be written: wrong shapes, bad indices, unusable names."""


class ColmapFormat(str, Enum):
    """Which of COLMAP's model formats to write."""

    TEXT = "text"  #: cameras.txt, images.txt, points3D.txt
    BINARY = "binary"  #: cameras.bin, images.bin, points3D.bin
    BOTH = "both"


@dataclass
class ColmapModel:
    """A sparse model with one undistorted pinhole camera, in bimcap's conventions.

    Attributes
    ----------
    width, height: image size in pixels.
    intrinsics: (4,) ``fx fy cx cy`` in pixels (bimcap's ``cx, cy``: origin at the first pixel
        centre; COLMAP's principal point is ``cx + 0.5, cy + 0.5``).
    world_from_cam: (N, 7) poses of the images, TUM order ``[tx ty tz qx qy qz qw]``, metres.
    image_names: N names relative to the image folder (POSIX, no whitespace).
    points_in_world: (P, 3) metres.
    point_rgb: (P, 3) uint8 colours.
    point_error_px: (P,) mean reprojection error of each point (pixels).
    obs_image: (K,) int image index (0-based) of each observation.
    obs_point: (K,) int point index (0-based) of each observation.
    obs_uv: (K, 2) pixels ``(u, v)``, origin at the first pixel centre.
    """

    width: int
    height: int
    intrinsics: F64
    world_from_cam: F64
    image_names: Sequence[str]
    points_in_world: F64
    point_rgb: NDArray[np.uint8]
    point_error_px: F64
    obs_image: NDArray[np.integer]
    obs_point: NDArray[np.integer]
    obs_uv: F64

    def validate(self) -> None:
        """Raise :class:`ColmapError` naming the field for anything COLMAP could not read."""
        n, p, k = len(self.image_names), len(self.points_in_world), len(self.obs_image)
        shapes = {"intrinsics": (4,), "world_from_cam": (n, 7), "points_in_world": (p, 3),
                  "point_rgb": (p, 3), "point_error_px": (p,), "obs_image": (k,),
                  "obs_point": (k,), "obs_uv": (k, 2)}
        for name, shape in shapes.items():
            got = np.shape(getattr(self, name))
            if got != shape:
                raise ColmapError(f"expected shape {shape}, got {got}", field=name)
        if self.width <= 0 or self.height <= 0:
            raise ColmapError(f"image size must be positive, got {self.width}x{self.height}",
                              field="width/height")
        for name in ("intrinsics", "world_from_cam", "points_in_world", "point_error_px",
                     "obs_uv"):
            if not np.all(np.isfinite(np.asarray(getattr(self, name), np.float64))):
                raise ColmapError("non-finite values", field=name)
        if k and (np.min(self.obs_image) < 0 or np.max(self.obs_image) >= n):
            raise ColmapError(f"image indices must lie in 0..{n - 1}", field="obs_image")
        if k and (np.min(self.obs_point) < 0 or np.max(self.obs_point) >= p):
            raise ColmapError(f"point indices must lie in 0..{p - 1}", field="obs_point")
        for i, name in enumerate(self.image_names):
            if not name or any(c.isspace() for c in name) or name.startswith("/"):
                raise ColmapError(f"image name {name!r} must be a relative path without "
                                  "whitespace (COLMAP's text format splits on spaces)",
                                  field=f"image_names[{i}]")
        if len(set(self.image_names)) != n:
            raise ColmapError("image names must be unique", field="image_names")


@dataclass
class _Tables:
    """The model in COLMAP's terms (ids from 1, cam_from_world, corner-origin pixels)."""

    camera_params: F64  # (4,) fx fy cx cy, COLMAP pixels
    qvec_wxyz: F64  # (N, 4)
    tvec: F64  # (N, 3)
    image_obs: list[NDArray[np.int64]]  # per image: observation indices, in POINT2D_IDX order
    point2d_idx: NDArray[np.int64]  # (K,) index of each observation within its image
    tracks: list[NDArray[np.int64]]  # per point: observation indices
    xy: F64  # (K, 2) COLMAP pixels


def _tables(model: ColmapModel) -> _Tables:
    n, p = len(model.image_names), len(model.points_in_world)
    k = np.asarray(model.intrinsics, np.float64)
    params = np.array([k[0], k[1], k[2] + PIXEL_OFFSET, k[3] + PIXEL_OFFSET])
    cam_from_world = invert(np.asarray(model.world_from_cam, np.float64)) if n else \
        np.zeros((0, 7))
    qvec = cam_from_world[:, [6, 3, 4, 5]]
    image = np.asarray(model.obs_image, np.int64)
    point = np.asarray(model.obs_point, np.int64)
    by_image = np.argsort(image, kind="stable")
    starts = np.searchsorted(image[by_image], np.arange(n + 1))
    image_obs = [by_image[starts[i]:starts[i + 1]] for i in range(n)]
    idx = np.empty(len(image), np.int64)
    for obs in image_obs:
        idx[obs] = np.arange(len(obs))
    by_point = np.argsort(point, kind="stable")
    pstarts = np.searchsorted(point[by_point], np.arange(p + 1))
    tracks = [by_point[pstarts[j]:pstarts[j + 1]] for j in range(p)]
    xy = np.asarray(model.obs_uv, np.float64) + PIXEL_OFFSET
    return _Tables(params, qvec, cam_from_world[:, :3], image_obs, idx, tracks, xy)


def _num(values: NDArray[np.generic]) -> str:
    """Space-separated numbers, 17 significant digits for floats."""
    return " ".join(f"{v:.17g}" if isinstance(v, float) else str(v) for v in values.tolist())


def _text_files(model: ColmapModel, t: _Tables) -> dict[str, str]:
    n, p = len(model.image_names), len(model.points_in_world)
    cameras = ["# Camera list with one line of data per camera:",
               "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
               "# Number of cameras: 1",
               f"1 PINHOLE {int(model.width)} {int(model.height)} {_num(t.camera_params)}"]
    n_obs = len(model.obs_image)
    images = ["# Image list with two lines of data per image:",
              "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
              "#   POINTS2D[] as (X, Y, POINT3D_ID)",
              f"# Number of images: {n}, mean observations per image: "
              f"{n_obs / n if n else 0:.17g}"]
    point_id = np.asarray(model.obs_point, np.int64) + 1
    for i, name in enumerate(model.image_names):
        images.append(f"{i + 1} {_num(t.qvec_wxyz[i])} {_num(t.tvec[i])} 1 {name}")
        obs = t.image_obs[i]
        images.append(" ".join(f"{_num(t.xy[o])} {point_id[o]}" for o in obs.tolist()))
    lengths = [len(tr) for tr in t.tracks]
    points = ["# 3D point list with one line of data per point:",
              "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
              f"# Number of points: {p}, mean track length: "
              f"{float(np.mean(lengths)) if p else 0:.17g}"]
    image_id = np.asarray(model.obs_image, np.int64) + 1
    xyz = np.asarray(model.points_in_world, np.float64)
    rgb = np.asarray(model.point_rgb, np.uint8)
    err = np.asarray(model.point_error_px, np.float64)
    for j in range(p):
        track = " ".join(f"{image_id[o]} {t.point2d_idx[o]}" for o in t.tracks[j].tolist())
        points.append(f"{j + 1} {_num(xyz[j])} {_num(rgb[j])} {float(err[j]):.17g} {track}")
    return {"cameras.txt": "\n".join(cameras) + "\n", "images.txt": "\n".join(images) + "\n",
            "points3D.txt": "\n".join(points) + "\n"}


def _binary_files(model: ColmapModel, t: _Tables) -> dict[str, bytes]:
    n, p = len(model.image_names), len(model.points_in_world)
    cameras = struct.pack("<Q", 1) + struct.pack("<IiQQ", 1, PINHOLE_MODEL_ID, int(model.width),
                                                 int(model.height))
    cameras += np.asarray(t.camera_params, "<f8").tobytes()
    point_id = np.asarray(model.obs_point, np.uint64) + np.uint64(1)
    obs_dtype = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<u8")])
    images = [struct.pack("<Q", n)]
    for i, name in enumerate(model.image_names):
        images.append(struct.pack("<I", i + 1) + np.asarray(t.qvec_wxyz[i], "<f8").tobytes()
                      + np.asarray(t.tvec[i], "<f8").tobytes() + struct.pack("<I", 1)
                      + name.encode("utf-8") + b"\0")
        obs = t.image_obs[i]
        rec = np.empty(len(obs), obs_dtype)
        rec["x"], rec["y"], rec["id"] = t.xy[obs, 0], t.xy[obs, 1], point_id[obs]
        images.append(struct.pack("<Q", len(obs)) + rec.tobytes())
    image_id = np.asarray(model.obs_image, np.uint32) + np.uint32(1)
    track_dtype = np.dtype([("image", "<u4"), ("idx", "<u4")])
    head_dtype = np.dtype([("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3), ("err", "<f8"),
                           ("len", "<u8")])
    points = [struct.pack("<Q", p)]
    for j in range(p):
        track = t.tracks[j]
        head = np.empty(1, head_dtype)
        head["id"], head["xyz"], head["rgb"] = j + 1, model.points_in_world[j], model.point_rgb[j]
        head["err"], head["len"] = model.point_error_px[j], len(track)
        rec = np.empty(len(track), track_dtype)
        rec["image"], rec["idx"] = image_id[track], t.point2d_idx[track]
        points.append(head.tobytes() + rec.tobytes())
    return {"cameras.bin": cameras, "images.bin": b"".join(images),
            "points3D.bin": b"".join(points)}


def write_colmap_model(directory: str | PathLike[str], model: ColmapModel,
                       fmt: ColmapFormat = ColmapFormat.TEXT) -> list[Path]:
    """Write ``model`` into ``directory`` (created if needed; each file atomically).

    Parameters
    ----------
    directory: the model folder, e.g. ``colmap/sparse/0`` (:data:`MODEL_SUBDIR`).
    model: the arrays (:class:`ColmapModel`), validated first.
    fmt: text, binary or both.

    Returns
    -------
    The files written. Raises :class:`ColmapError` naming the field for a model COLMAP could not
    read.
    """
    fmt = ColmapFormat(fmt)
    model.validate()
    tables = _tables(model)
    out = Path(directory)
    written = []
    if fmt in (ColmapFormat.TEXT, ColmapFormat.BOTH):
        for name, text in _text_files(model, tables).items():
            atomic_write_text(out / name, text)
            written.append(out / name)
    if fmt in (ColmapFormat.BINARY, ColmapFormat.BOTH):
        for name, data in _binary_files(model, tables).items():
            atomic_write_bytes(out / name, data)
            written.append(out / name)
    return written
