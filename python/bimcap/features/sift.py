"""SIFT (or ORB) keypoints and descriptors on undistorted images.

The default backend is OpenCV's ``cv2.SIFT`` (first octave at the native resolution, DoG peak
threshold 0.004: about 2.7× cheaper than pycolmap's SIFT at the same accuracy of the refinement,
docs/speed.md "OpenCV's SIFT as the default"); ``SiftBackend.PYCOLMAP`` is pycolmap 4.x
(``pycolmap.FeatureExtractor.create`` on the CPU, the same SIFT as COLMAP).
``SiftBackend.ORB`` is OpenCV's ORB (FAST corners with Harris scores over an image pyramid,
rotated BRIEF): binary 256-bit descriptors, matched by Hamming distance
(:func:`bimcap.features.match_descriptors` tells them by their 32-byte width). Its keypoints are
spread over a grid of cells, each keeping its strongest corners, because FAST's responses
cluster on the most textured surfaces.

Pixel convention: keypoints are returned in bimcap's convention, ``(u, v) = (column, row)`` with
the origin at the **centre** of the top-left pixel. COLMAP puts the origin at the top-left
*corner* (the first pixel centre is (0.5, 0.5)), so 0.5 is subtracted from its coordinates; a test
checks this on a blob at a known pixel.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import BimcapError


class FeatureError(BimcapError):
    """A feature extraction or matching step that cannot run (bad image, missing backend)."""


class SiftBackend(str, Enum):
    """Which implementation extracts the features: SIFT (pycolmap, OpenCV) or OpenCV's ORB."""

    PYCOLMAP = "pycolmap"
    OPENCV = "opencv"
    ORB = "orb"


#: Width in bytes of ORB's binary descriptors (256 bits).
ORB_DESCRIPTOR_BYTES = 32


@dataclass(frozen=True)
class SiftOptions:
    """Settings of the feature extractor: SIFT (COLMAP's defaults unless stated) or ORB.

    Attributes
    ----------
    backend: which implementation to use: OpenCV's SIFT (default) or pycolmap's (COLMAP's SIFT;
        bimcap's default until 2026-11-27, then with ``peak_threshold = 0.02 / 3``).
    max_num_features: keep at most this many SIFT keypoints (pycolmap: the largest scales;
        OpenCV: the strongest responses, chosen before their descriptors are computed); ORB's
        budget is ``orb_max_num_features``. 2048 (the default since 2026-11-27; 4096 before):
        at 516×386 no frame of the standard and hard worlds has more than 1,326, so nothing
        changes there; at 1032×772 (up to 4,096) SIFT is ~1.26× and matching + verification
        ~2.2× cheaper a frame, the front end 1.25×, with BIMCaP within 0.0061 cm / 0.0013° of
        4096 on four worlds × four runs (docs/speed.md, "Keypoint budget").
    peak_threshold: DoG peak threshold (COLMAP ``peak_threshold``; OpenCV ``contrastThreshold``
        is ``opencv_octave_layers × peak_threshold``: the same threshold on each DoG value).
        0.004 (the default) was measured with OpenCV's SIFT; COLMAP's own is 0.02 / 3.
    edge_threshold: DoG edge threshold.
    first_octave: -1 upsamples the image once (finds small features; COLMAP's default), 0 does
        not (bimcap's default). At 516×386 the upsampled octave costs 3.7× the CPU (410 vs
        110 ms a frame, 2,300 vs 930 keypoints) and does not pay: on 5 worlds × (fixed point,
        Exp. 1/2/3) of ``bench/bench_generalization.py`` BIMCaP with 0 reached 2.21 cm mean
        ATE_pos (worst 7.45 cm) against 2.25 cm (worst 7.42 cm) with -1, better or equal in 15
        of 20 runs (docs/speed.md).
    num_octaves: number of octaves.
    max_num_orientations: orientations per keypoint (1 or 2 with COLMAP).
    num_threads: threads inside one extraction (1 when frames run in parallel processes).
    max_image_size: if the image's longer side exceeds this, extract on a copy resized to it
        (area interpolation) and map keypoints back to full-resolution pixels; None: never.
        ConSLAM's 2064×1544 images with 1032 cost about a quarter of the time.
    opencv_first_octave: OpenCV's SIFT only (``backend = "opencv"``): -1 (OpenCV's own behaviour)
        doubles the image before the first octave; 0 (the default) extracts on a copy halved with
        area interpolation, so that OpenCV's doubled first octave is the native resolution, as
        COLMAP's ``first_octave = 0`` (keypoints mapped back to full-resolution pixels). At 516×386,
        with ``peak_threshold = 0.004``, extraction is ~3× cheaper than pycolmap's first octave 0
        (64 vs 189 ms a frame, one thread; the front end 2.1 → 2.9 frames/s per core) at the same
        match error on the ground truth; BIMCaP's accuracy on 8 runs was within 0.0105 cm / 0.0016°
        of pycolmap's, better on 5 (docs/speed.md, "SIFT cost"), and on the ten worlds × four runs
        of the standard setting within 0.034 cm / 0.0042° (docs/generalization.md, "The two lone
        frames fixed"), but on the hard setting it lost the four end frames of gen-small-s3 Exp. 1
        (21.3 cm against pycolmap's 1.2 cm; docs/speed.md, "OpenCV's SIFT on the hard setting"), a
        block no match links to the rest; since the refinement tries such blocks at the input's
        motion, 0.98 cm, and all 20 hard runs within the bar (docs/speed.md, "Blocks that no match
        links"). Small images are not halved (``opencv_halve_min_side``).
    opencv_octave_layers: OpenCV's SIFT only: scale levels an octave (OpenCV's ``nOctaveLayers``,
        COLMAP's ``octave_resolution``); OpenCV's ``contrastThreshold`` is
        ``opencv_octave_layers × peak_threshold``, so the threshold on each DoG value stays
        ``peak_threshold``. 3 (the default) is OpenCV's and COLMAP's own. 2 at 516×386
        (gen-demo-s0, 12 frames): 893 keypoints a frame instead of 1,165, extraction ~1.3×
        cheaper, a quarter fewer verified matches a pair (178 against 246) at the same match
        error; the refinement's accuracy with it was not measured (docs/speed.md, "Keypoint
        budget").
    opencv_halve_min_side: with ``opencv_first_octave = 0``, an image whose shorter side is
        below this many pixels is not halved (OpenCV's doubled first octave, as at -1): halved
        to 160×120, 320×240 scenes lose matches (four front-end tests failed: fewer than their
        1,000 / 500 matches, a COLMAP export's 95th-percentile error 7 cm against 5 cm; they
        pass unhalved), while 516×386 (halved to 258×193) passed the standard, hard and
        unseen matrices (docs/speed.md).
    orb_max_num_features: ORB's keypoint budget (``max_num_features`` is SIFT's): matching
        binary descriptors costs the square of it, and at 516×386 a pair of frames with 2048
        (about 1600 kept) costs as much as their extraction.
    orb_grid_cols, orb_grid_rows: ORB only: the image is split into this many cells across and
        down, each keeping at most ``orb_max_num_features / (cols · rows)`` of its strongest
        corners.
    orb_fast_threshold: ORB only: FAST's intensity threshold (grey levels).
    orb_num_levels: ORB only: pyramid levels (scale factor 1.2 between levels).
    orb_subpixel: ORB only: move each full-resolution (level 0) corner to the sub-pixel peak of
        the Harris response (:func:`_harris_subpixel`); FAST's corners are whole pixels of their
        level. On the test room with one level this halves the match error (median 0.24 →
        0.11 cm; SIFT 0.08 cm), but on gen-demo-s0 one level loses matches and the refinement
        came out worse (docs/speed.md), and with 8 levels most corners are on coarser levels:
        off by default.
    """

    backend: SiftBackend = SiftBackend.OPENCV
    max_num_features: int = 2048
    peak_threshold: float = 0.004
    edge_threshold: float = 10.0
    first_octave: int = 0
    num_octaves: int = 4
    max_num_orientations: int = 2
    num_threads: int = 1
    max_image_size: int | None = None
    opencv_first_octave: int = 0
    opencv_halve_min_side: int = 384
    opencv_octave_layers: int = 3
    orb_max_num_features: int = 2048
    orb_grid_cols: int = 8
    orb_grid_rows: int = 6
    orb_fast_threshold: int = 10
    orb_num_levels: int = 8
    orb_subpixel: bool = False

    def __post_init__(self) -> None:
        if self.max_image_size is not None and self.max_image_size < 16:
            raise FeatureError(f"max_image_size must be >= 16 or None, got {self.max_image_size}")
        if self.max_num_features <= 0:
            raise FeatureError(f"max_num_features must be positive, got {self.max_num_features}")
        if self.peak_threshold <= 0 or self.edge_threshold <= 0:
            raise FeatureError("peak_threshold and edge_threshold must be positive")
        if self.num_octaves <= 0 or self.max_num_orientations <= 0:
            raise FeatureError("num_octaves and max_num_orientations must be positive")
        if self.opencv_first_octave not in (-1, 0):
            raise FeatureError(
                f"opencv_first_octave must be -1 or 0, got {self.opencv_first_octave!r}")
        if self.opencv_halve_min_side < 2:
            raise FeatureError(
                f"opencv_halve_min_side must be >= 2, got {self.opencv_halve_min_side}")
        if not 1 <= self.opencv_octave_layers <= 8:
            raise FeatureError(
                f"opencv_octave_layers must be in [1, 8], got {self.opencv_octave_layers}")
        if self.orb_max_num_features <= 0:
            raise FeatureError(
                f"orb_max_num_features must be positive, got {self.orb_max_num_features}")
        if self.orb_grid_cols <= 0 or self.orb_grid_rows <= 0 or self.orb_num_levels <= 0:
            raise FeatureError("orb_grid_cols, orb_grid_rows and orb_num_levels must be positive")
        if not 1 <= self.orb_fast_threshold <= 254:
            raise FeatureError(
                f"orb_fast_threshold must be in [1, 254], got {self.orb_fast_threshold}")

    def to_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["backend"] = self.backend.value
        if self.opencv_octave_layers == 3:
            del d["opencv_octave_layers"]  # the cache keys of before the option: the same features
        return d


@dataclass
class Features:
    """Keypoints and descriptors of one undistorted image.

    Attributes
    ----------
    uv: (N, 2) float64 keypoint pixels, bimcap convention (origin at the first pixel centre).
    scale: (N,) float64 keypoint scale in pixels.
    orientation: (N,) float64 orientation in radians.
    descriptors: (N, 128) uint8 SIFT descriptors (RootSIFT, L2 norm ≈ 512), or (N, 32) uint8
        ORB descriptors (256 bits, packed).
    """

    uv: NDArray[np.float64]
    scale: NDArray[np.float64]
    orientation: NDArray[np.float64]
    descriptors: NDArray[np.uint8]

    def __len__(self) -> int:
        return len(self.uv)

    @classmethod
    def empty(cls, descriptor_bytes: int = 128) -> Features:
        """No keypoints; descriptors (0, 128) for SIFT, (0, 32) for ORB."""
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0),
                   np.zeros((0, descriptor_bytes), np.uint8))


def to_gray_u8(image: NDArray[np.generic]) -> NDArray[np.uint8]:
    """(H, W) uint8 grey image from an (H, W) or (H, W, 3) uint8 RGB image (BT.601 weights)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise FeatureError(f"expected an 8-bit image, got dtype {img.dtype}")
    if img.ndim == 2:
        return np.ascontiguousarray(img)
    if img.ndim == 3 and img.shape[2] == 3:
        # rint(r · 0.299 + g · 0.587 + b · 0.114) in float64, numpy's arithmetic bit for bit, in
        # one compiled pass (cpp/bimcap/raster/gray.h; ~6× cheaper than the numpy expression)
        from bimcap import _core

        gray: NDArray[np.uint8] = _core.rgb_to_gray(np.ascontiguousarray(img))
        return gray
    raise FeatureError(f"expected an (H, W) or (H, W, 3) image, got shape {img.shape}")


def extract_sift(image: NDArray[np.generic], options: SiftOptions | None = None) -> Features:
    """Extract SIFT (or ORB, :attr:`SiftBackend.ORB`) features from one undistorted image.

    Parameters
    ----------
    image: (H, W) or (H, W, 3) uint8 image (RGB).
    options: extractor settings; defaults to :class:`SiftOptions()`.

    Returns
    -------
    Features with keypoints in bimcap's pixel convention.
    """
    opts = options or SiftOptions()
    gray = to_gray_u8(image)
    factor = 1.0
    if opts.max_image_size is not None and max(gray.shape) > opts.max_image_size:
        import cv2

        factor = opts.max_image_size / max(gray.shape)
        size = (max(1, round(gray.shape[1] * factor)), max(1, round(gray.shape[0] * factor)))
        fx, fy = size[0] / gray.shape[1], size[1] / gray.shape[0]
        gray = np.ascontiguousarray(cv2.resize(gray, size, interpolation=cv2.INTER_AREA))
    if opts.backend is SiftBackend.PYCOLMAP:
        feats = _extract_pycolmap(gray, opts)
    elif opts.backend is SiftBackend.ORB:
        feats = _extract_orb(gray, opts)
    else:
        feats = _extract_opencv(gray, opts)
    if factor != 1.0:
        _map_back(feats, fx, fy)
    return feats


def _map_back(feats: Features, fx: float, fy: float) -> None:
    """Keypoints of an image resized by (fx, fy) moved to the original image's pixels (in place).

    Pixel centres map as u_small + 0.5 = (u + 0.5) · f (what cv2.resize assumes).
    """
    feats.uv = np.stack(
        [(feats.uv[:, 0] + 0.5) / fx - 0.5, (feats.uv[:, 1] + 0.5) / fy - 0.5], axis=1
    )
    feats.scale = feats.scale / np.sqrt(fx * fy)


def _extract_pycolmap(gray: NDArray[np.uint8], opts: SiftOptions) -> Features:
    try:
        import pycolmap
    except ImportError as exc:  # pragma: no cover - pycolmap is a dependency
        raise FeatureError("pycolmap is not installed; use SiftBackend.OPENCV") from exc
    pycolmap.logging.minloglevel = 2  # silence glog's "Creating SIFT CPU feature extractor"
    eo = pycolmap.FeatureExtractionOptions()
    eo.num_threads = opts.num_threads
    eo.use_gpu = False
    eo.max_image_size = -1
    eo.sift.max_num_features = opts.max_num_features
    eo.sift.peak_threshold = opts.peak_threshold
    eo.sift.edge_threshold = opts.edge_threshold
    eo.sift.first_octave = opts.first_octave
    eo.sift.num_octaves = opts.num_octaves
    eo.sift.max_num_orientations = opts.max_num_orientations
    extractor = pycolmap.FeatureExtractor.create(eo, pycolmap.Device.cpu)
    keypoints, descriptors = extractor.extract_from_uint8_array(gray)
    n = len(keypoints)
    if n == 0:
        return Features.empty()
    kp = np.array(
        [(k.x, k.y, k.compute_scale(), k.compute_orientation()) for k in keypoints],
        dtype=np.float64,
    )
    desc = np.ascontiguousarray(descriptors.data, dtype=np.uint8)
    if n > opts.max_num_features:
        # COLMAP limits detections, but each may carry up to max_num_orientations descriptors;
        # keep the largest scales, as COLMAP does when it limits.
        keep = np.sort(np.argsort(-kp[:, 2], kind="stable")[: opts.max_num_features])
        kp, desc = kp[keep], np.ascontiguousarray(desc[keep])
    # COLMAP: first pixel centre at (0.5, 0.5); bimcap: at (0, 0).
    return Features(kp[:, :2] - 0.5, kp[:, 2].copy(), kp[:, 3].copy(), desc)


def _extract_opencv(gray: NDArray[np.uint8], opts: SiftOptions) -> Features:
    """OpenCV SIFT, descriptors converted to RootSIFT scaled like COLMAP's (×512).

    OpenCV always doubles its input before the first octave; with ``opencv_first_octave = 0``
    the input is the image halved (area interpolation: each pixel the mean of a 2 × 2 block), so
    that the first octave is the native resolution, and the keypoints are mapped back; images
    whose shorter side is below ``opencv_halve_min_side`` are not halved.
    """
    import cv2

    if opts.opencv_first_octave == 0 and min(gray.shape) >= opts.opencv_halve_min_side:
        h, w = gray.shape
        size = (max(1, round(w / 2)), max(1, round(h / 2)))
        half = np.ascontiguousarray(cv2.resize(gray, size, interpolation=cv2.INTER_AREA))
        feats = _extract_opencv(half, replace(opts, opencv_first_octave=-1))
        _map_back(feats, size[0] / w, size[1] / h)
        return feats

    sift = cv2.SIFT_create(
        nfeatures=opts.max_num_features,
        nOctaveLayers=opts.opencv_octave_layers,
        contrastThreshold=opts.opencv_octave_layers * opts.peak_threshold,
        edgeThreshold=opts.edge_threshold,
        sigma=1.6,
        # Without this, OpenCV's doubled first octave maps pixel x to 2x + 0.5 and every keypoint
        # comes out ~0.25 px too far right and down (a test checks the blob positions).
        enable_precise_upscale=True,
    )
    kps, desc = sift.detectAndCompute(gray, None)
    if desc is None or len(kps) == 0:
        return Features.empty()
    if len(kps) > opts.max_num_features:  # OpenCV keeps ties and a keypoint's orientations
        keep = np.sort(np.argsort([-k.response for k in kps], kind="stable")
                       [:opts.max_num_features])
        kps, desc = [kps[i] for i in keep], desc[keep]
    # L1 normalise, then sqrt: RootSIFT, ×512 to uint8, in numpy's float64 arithmetic (compiled:
    # bimcap/raster/rootsift.h)
    from bimcap import _core

    d = _core.rootsift_u8(np.ascontiguousarray(desc, dtype=np.float32))
    # OpenCV: pixel-centre origin already; its float32 points widened, as k.pt's floats are
    uv = np.asarray(cv2.KeyPoint_convert(kps), dtype=np.float64).reshape(-1, 2)
    scale = np.array([k.size / 2.0 for k in kps], dtype=np.float64)
    ori = np.deg2rad(np.array([k.angle for k in kps], dtype=np.float64))
    return Features(uv, scale, ori, np.ascontiguousarray(d))


def _extract_orb(gray: NDArray[np.uint8], opts: SiftOptions) -> Features:
    """OpenCV ORB with the keypoint budget spread over a grid of cells.

    FAST corners (Harris-scored, over ``orb_num_levels`` pyramid levels) are detected with a
    budget of 4× ``orb_max_num_features``; each of the ``orb_grid_cols × orb_grid_rows`` cells keeps
    its strongest ``orb_max_num_features / cells``, and the rotated-BRIEF descriptors are computed
    for those alone. ``scale`` is half of OpenCV's keypoint size (the 31-pixel patch times the
    level's scale), as for OpenCV's SIFT.
    """
    import cv2

    orb = cv2.ORB_create(  # type: ignore[attr-defined]
        nfeatures=4 * opts.orb_max_num_features,
        scaleFactor=1.2,
        nlevels=opts.orb_num_levels,
        edgeThreshold=31,
        firstLevel=0,
        WTA_K=2,
        scoreType=cv2.ORB_HARRIS_SCORE,
        patchSize=31,
        fastThreshold=opts.orb_fast_threshold,
    )
    kps = orb.detect(gray, None)
    if len(kps) == 0:
        return Features.empty(ORB_DESCRIPTOR_BYTES)
    h, w = gray.shape
    pt = np.array([k.pt for k in kps], dtype=np.float64)
    response = np.array([k.response for k in kps], dtype=np.float64)
    col = np.clip((pt[:, 0] + 0.5) * opts.orb_grid_cols / w, 0, opts.orb_grid_cols - 1)
    row = np.clip((pt[:, 1] + 0.5) * opts.orb_grid_rows / h, 0, opts.orb_grid_rows - 1)
    cell = row.astype(np.int64) * opts.orb_grid_cols + col.astype(np.int64)
    per_cell = max(1, opts.orb_max_num_features // (opts.orb_grid_cols * opts.orb_grid_rows))
    # Strongest first within each cell (ties by detection order), then the rank in the cell.
    order = np.lexsort((np.arange(len(kps)), -response, cell))
    sorted_cell = cell[order]
    first = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.arange(len(order)) - first
    keep = np.sort(order[rank < per_cell])
    kept, desc = orb.compute(gray, [kps[i] for i in keep])
    if desc is None or len(kept) == 0:
        return Features.empty(ORB_DESCRIPTOR_BYTES)
    # OpenCV multiplies a level's pixel by the level's scale s; its pyramid (cv2.resize) puts
    # that pixel's centre at (u + 0.5) · s - 0.5 in the full image: add 0.5 · (s - 1).
    level = np.array([k.octave for k in kept], dtype=np.int64)
    level_scale = 1.2 ** level.astype(np.float64)
    uv = np.array([k.pt for k in kept], dtype=np.float64) + 0.5 * (level_scale[:, None] - 1.0)
    if opts.orb_subpixel:
        uv[level == 0] = _harris_subpixel(gray, uv[level == 0])
    scale = np.array([k.size / 2.0 for k in kept], dtype=np.float64)
    ori = np.deg2rad(np.array([k.angle for k in kept], dtype=np.float64))
    return Features(uv, scale, ori, np.ascontiguousarray(desc, dtype=np.uint8))


def _harris_subpixel(gray: NDArray[np.uint8], uv: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 2) corners moved to the sub-pixel peak of the Harris response (block 5, Sobel 3).

    Each corner moves to the largest response among its pixel and the 8 around it, then by a
    parabola fitted through that pixel and its neighbours along u and along v (at most half a
    pixel each way). Corners within 2 pixels of the border stay where they are.
    """
    import cv2

    resp: NDArray[np.float64] = np.asarray(cv2.cornerHarris(gray.astype(np.float32), 5, 3, 0.04),
                                           dtype=np.float64)
    h, w = resp.shape
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    inside = (u >= 2) & (u < w - 2) & (v >= 2) & (v < h - 2)
    u, v = np.where(inside, u, 2), np.where(inside, v, 2)
    best = np.full(len(u), -np.inf)
    bu, bv = u.copy(), v.copy()
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            r = resp[v + dv, u + du]
            better = r > best
            best[better], bu[better], bv[better] = r[better], u[better] + du, v[better] + dv

    def offset(lo: NDArray[np.float64], mid: NDArray[np.float64],
               hi: NDArray[np.float64]) -> NDArray[np.float64]:
        curv = 2.0 * mid - lo - hi
        off = np.where(curv > 0, 0.5 * (hi - lo) / np.maximum(curv, 1e-30), 0.0)
        return np.clip(off, -0.5, 0.5)

    c = resp[bv, bu]
    out = uv.copy()
    out[inside, 0] = (bu + offset(resp[bv, bu - 1], c, resp[bv, bu + 1]))[inside]
    out[inside, 1] = (bv + offset(resp[bv - 1, bu], c, resp[bv + 1, bu]))[inside]
    return out
