"""The refined reconstruction as a COLMAP workspace: ``colmap/sparse/0`` and ``colmap/images``.

The model (:mod:`bimcap.io.colmap`) holds one PINHOLE camera, the undistorted pinhole camera of
the front end (``sequence.camera.pinhole()``, in which every track observation is measured), one
image per frame at its refined pose, and the front end's feature tracks re-triangulated at the
refined poses (:func:`bimcap.geometry.triangulation.triangulate_tracks`: DLT, observations
further than 2 px from their reprojection dropped), each point with its mean reprojection error,
its track and its colour (the mean of the undistorted images' pixels at its observations).

Image names are the frames' image files relative to the folder that holds them all (the
sequence's ``images/``), e.g. ``000000.png``. With :attr:`ColmapExport.IMAGES` the undistorted
images (``bimcap.frontend.runner.get_undistorter(camera).image``, the front end's own
undistortion) are written under those names into ``colmap/images/``, so that the folder is a
COLMAP workspace whose images match its camera. With :attr:`ColmapExport.MODEL` no image is
copied: the names then refer to the sequence's raw images, which are *distorted* (plumb_bob) and
do not match the PINHOLE camera exactly; undistort them first (``colmap/images`` is what
``images`` mode writes) before dense reconstruction.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import InputError
from bimcap.geometry.triangulation import TriangulationOptions, triangulate_tracks
from bimcap.io.atomic import atomic_write_bytes
from bimcap.io.colmap import (
    IMAGES_SUBDIR,
    MODEL_SUBDIR,
    ColmapFormat,
    ColmapModel,
    write_colmap_model,
)
from bimcap.pipeline.config import ColmapExport

F64 = NDArray[np.float64]


@dataclass
class ColmapExportResult:
    """What :func:`export_colmap` wrote (paths relative to the workspace folder).

    Attributes
    ----------
    model: the model folder (``sparse/0``). images: the undistorted images' folder, or None.
    image_count: images in the model. point_count: triangulated points. tracks: tracks offered.
    observations: 2-D points written. mean_error_px: mean reprojection error of the points.
    mean_track_length: observations per point. seconds: wall time. triangulation: the options.
    """

    model: str
    images: str | None
    image_count: int
    point_count: int
    tracks: int
    observations: int
    mean_error_px: float | None
    mean_track_length: float | None
    seconds: float
    triangulation: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def image_names(sequence: Any) -> list[str]:
    """The frames' image files relative to the deepest folder holding them all (POSIX)."""
    paths = [PurePosixPath(f.image) for f in sequence.frames]
    common = list(paths[0].parent.parts) if paths else []
    for p in paths[1:]:
        parts = p.parent.parts
        n = 0
        while n < min(len(common), len(parts)) and common[n] == parts[n]:
            n += 1
        common = common[:n]
    return [PurePosixPath(*p.parts[len(common):]).as_posix() for p in paths]


def _encode(name: str, rgb: NDArray[np.uint8]) -> bytes:
    """The RGB image encoded in the format its name's extension says (PNG when unknown)."""
    import cv2

    ext = PurePosixPath(name).suffix.lower()
    if ext not in (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"):
        ext = ".png"
    ok, buf = cv2.imencode(ext, np.ascontiguousarray(rgb[:, :, ::-1]))
    if not ok:
        raise InputError(f"cannot encode the undistorted image as {ext}", name)
    return bytes(buf.tobytes())


def export_colmap(
    directory: str | PathLike[str],
    sequence: Any,
    frontend: Any,
    world_from_cam: F64,
    mode: ColmapExport = ColmapExport.IMAGES,
    options: TriangulationOptions | None = None,
    fmt: ColmapFormat = ColmapFormat.TEXT,
) -> ColmapExportResult:
    """Write the COLMAP workspace of a reconstruction into ``directory`` (module docstring).

    Parameters
    ----------
    directory: the workspace folder (``colmap/``): the model goes to ``sparse/0``, the
        undistorted images (``mode`` IMAGES) to ``images/``.
    sequence: the sequence (``camera``, ``frames[i].image``, ``load_image(i)``).
    frontend: its ``FrontendResult`` (tracks in undistorted pinhole pixels of ``camera``).
    world_from_cam: (N, 7) poses of the frames, TUM order (the refined trajectory).
    mode: IMAGES or MODEL (OFF writes nothing and is refused here).
    options: the triangulation's filters.
    fmt: the model's format (text by default: what the issue's users read and diff).
    """
    from bimcap.frontend.runner import get_undistorter

    mode = ColmapExport(mode)
    if mode is ColmapExport.OFF:
        raise InputError("export_colmap with mode off writes nothing", field="colmap")
    t0 = time.perf_counter()
    poses = np.asarray(world_from_cam, np.float64)
    n = len(sequence.frames)
    if poses.shape != (n, 7) or frontend.num_frames != n:
        raise InputError(f"{poses.shape[0]} poses and {frontend.num_frames} front-end frames for "
                         f"{n} frames", field="world_from_cam")
    cam = frontend.camera
    if cam != sequence.camera.pinhole():
        raise InputError("the front end's camera is not the sequence camera's pinhole camera",
                         field="frontend.camera")
    opts = options or TriangulationOptions()
    tri = triangulate_tracks(cam.intrinsics, poses, frontend.track_obs_frame,
                             frontend.track_obs_point, frontend.track_obs_uv,
                             len(frontend.track_points), opts)
    kept = tri.obs_kept
    new_index = np.cumsum(tri.valid) - 1
    obs_image = frontend.track_obs_frame[kept].astype(np.int64)
    obs_point = new_index[frontend.track_obs_point[kept]].astype(np.int64)
    obs_uv = frontend.track_obs_uv[kept]
    p = int(tri.valid.sum())

    names = image_names(sequence)
    out = Path(directory)
    undistort = get_undistorter(sequence.camera)
    colour_sum = np.zeros((p, 3))
    for i in range(n):
        here = obs_image == i
        if mode is not ColmapExport.IMAGES and not here.any():
            continue
        rgb = undistort.image(sequence.load_image(i))
        if mode is ColmapExport.IMAGES:
            atomic_write_bytes(out / IMAGES_SUBDIR / names[i], _encode(names[i], rgb))
        px = np.rint(obs_uv[here]).astype(np.int64)
        px[:, 0] = np.clip(px[:, 0], 0, rgb.shape[1] - 1)
        px[:, 1] = np.clip(px[:, 1], 0, rgb.shape[0] - 1)
        np.add.at(colour_sum, obs_point[here], rgb[px[:, 1], px[:, 0]].astype(np.float64))
    count = np.bincount(obs_point, minlength=p)
    colour = np.rint(colour_sum / np.maximum(count, 1)[:, None]).astype(np.uint8)

    model = ColmapModel(
        width=cam.width, height=cam.height, intrinsics=cam.intrinsics, world_from_cam=poses,
        image_names=names, points_in_world=tri.points_in_world[tri.valid], point_rgb=colour,
        point_error_px=tri.error_px[tri.valid], obs_image=obs_image, obs_point=obs_point,
        obs_uv=obs_uv,
    )
    write_colmap_model(out / MODEL_SUBDIR, model, fmt)
    return ColmapExportResult(
        model=MODEL_SUBDIR,
        images=IMAGES_SUBDIR if mode is ColmapExport.IMAGES else None,
        image_count=n,
        point_count=p,
        tracks=len(tri.valid),
        observations=len(obs_image),
        mean_error_px=float(model.point_error_px.mean()) if p else None,
        mean_track_length=len(obs_image) / p if p else None,
        seconds=time.perf_counter() - t0,
        triangulation=opts.to_dict(),
    )
