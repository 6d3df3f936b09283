"""Type stubs of the compiled C++ core (cpp/python/bind_*.cc). Use bimcap.optimize instead."""

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

PROBLEM_FILE_VERSION: int

class InputError(ValueError):
    """A malformed array, option or problem file; the message starts with the field name."""

    field: str  #: the culprit's name ("" when none)

def solve(arrays: dict[str, NDArray[Any]], options: Mapping[str, object]) -> dict[str, Any]:
    """Solve one problem; returns poses, planes, track_points, ``<key>_segment`` per segment term
    (wall_segment, column_segment), covariance (or None) and summary (dict)."""

def default_options() -> dict[str, str]: ...
def preset_options(name: str) -> dict[str, str]: ...
def preset_names() -> list[str]: ...
def check_options(options: Mapping[str, object]) -> dict[str, str]: ...
def option_keys() -> list[str]: ...
def option_specs() -> list[dict[str, Any]]: ...
def terms() -> list[dict[str, Any]]: ...
def problem_fields() -> list[tuple[str, str, int, bool, str]]: ...
def serialize_problem(arrays: dict[str, NDArray[Any]], options: Mapping[str, object]) -> bytes: ...
def validate_problem(arrays: dict[str, NDArray[Any]]) -> None: ...
def read_problem_file(path: str) -> tuple[dict[str, NDArray[Any]], dict[str, str]]: ...
def parse_problem_bytes(data: bytes) -> tuple[dict[str, NDArray[Any]], dict[str, str]]: ...
def write_problem_file(
    path: str, arrays: dict[str, NDArray[Any]], options: Mapping[str, object]
) -> None: ...
def describe_problem_file(path: str) -> str: ...
def evaluate_reprojection(
    world_from_cam_a: NDArray[np.float64],
    world_from_cam_b: NDArray[np.float64],
    p_a_in_cam: NDArray[np.float64],
    uv_b: NDArray[np.float64],
    intrinsics_b: NDArray[np.float64],
) -> tuple[NDArray[np.float64], tuple[NDArray[np.float64], NDArray[np.float64]]]: ...
def evaluate_landmark(
    world_from_cam: NDArray[np.float64],
    point_in_world: NDArray[np.float64],
    uv: NDArray[np.float64],
    intrinsics: NDArray[np.float64],
) -> tuple[NDArray[np.float64], tuple[NDArray[np.float64], NDArray[np.float64]]]: ...
def fill_triangle_ids(
    corners: NDArray[np.int32], ids: NDArray[np.int32], height: int, width: int, shift: int = 4,
    centres: bool = False,
) -> NDArray[np.int32]:
    """(height, width) ids of cv2.fillConvexPoly(image, corners[t], ids[t], LINE_8, shift) drawn
    for t = 0, 1, ... on a zero image; corners (T, 3, 2) int32, ids (T,) int32; with centres,
    then each pixel whose centre a triangle contains (top-left rule) takes that triangle's id."""

def delaunay_triangles(points: NDArray[np.float64]) -> NDArray[np.int32]:
    """(T, 3) int32 vertex indices of the Delaunay triangles of the (n, 2) float64 points, each
    counter-clockwise (x right, y up), in the order a sweep of the convex hull made them."""

def evaluate_piecewise_affine(
    tri_id: NDArray[np.int32], coef: NDArray[np.float64], inverse_depth: bool
) -> NDArray[np.float32]:
    """(H, W) float32 depth of f = c0[id] u + c1[id] v + c2[id] (numpy's rounding), 1/f or f."""
def rgb_to_gray(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """(H, W) uint8 rint(0.299 r + 0.587 g + 0.114 b) of a C-contiguous (H, W, 3) uint8 RGB
    image (numpy's float64 rounding)."""
def decode_png_rows(
    stream: NDArray[np.uint8], rows: int, row_bytes: int, bpp: int
) -> NDArray[np.uint8]:
    """(rows, row_bytes) uint8 scanlines of a PNG image from the zlib stream of its IDAT chunks
    (their data joined; `bpp` bytes a pixel, 1-8): inflated, the PNG filters undone."""
def nearest_pixels(
    row_start: NDArray[np.int64], cols: NDArray[np.int64], queries: NDArray[np.float64], k: int
) -> NDArray[np.int64]:
    """(N, k) indices of the k pixels (given row by row, as np.nonzero lists them) nearest each
    (x, y) query, nearest first, ties by index (scipy cKDTree.query's neighbours)."""
def near_region(
    region_id: NDArray[np.int32], k: int, reach: int, at: NDArray[np.int64],
    rows_ascending: bool, top: int, stop: int
) -> NDArray[np.int64]:
    """Positions (ascending) in `at` (raveled pixels) of the pixels within `reach` rows and
    columns of a pixel of region `k` (whose pixels lie in rows [top, stop))."""
def split_descriptors(
    descriptors: NDArray[np.uint8],
) -> tuple[NDArray[np.int64], int, NDArray[np.uint8], NDArray[np.uint8], NDArray[np.int8],
           NDArray[np.uint8], NDArray[np.int8]]:
    """(order, first, d[order], lo, lo_t, hi, hi_t): the rows without a value >= 128 first, the
    low 7 bits and the high bits of the reordered rows, and their transposes."""
def nearest_points(
    points: NDArray[np.float64], queries: NDArray[np.float64], k: int, cell: float
) -> NDArray[np.int64]:
    """(N, k) indices of the k points nearest each query, nearest first, ties by index
    (scipy cKDTree.query's neighbours), found in a grid of cubes of side `cell`."""
def window_min_at(
    depth: NDArray[np.float32], at: NDArray[np.int64], radius: int
) -> NDArray[np.float32]:
    """(K,) the least positive depth within `radius` rows and columns of each pixel `at`
    (FLT_MAX where none): cv2.erode of the positive depths read there."""
def rootsift_u8(descriptors: NDArray[np.float32]) -> NDArray[np.uint8]:
    """(N, C) uint8 RootSIFT ×512 of float32 descriptors (numpy's float64 arithmetic)."""
def region_rays(
    flat: NDArray[np.int64], width: int, fx: float, fy: float, cx: float, cy: float,
    depth: NDArray[np.float32], measured: NDArray[np.float32] | None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(x, y, cur, returns): the pixels' ray x and y, their depth, and (x z, y z, z) where the
    measured depth z > 0 (numpy's arithmetic)."""
def filter_triangles(
    uv: NDArray[np.float64], z: NDArray[np.float64], triangles: NDArray[np.int32],
    max_edge: float, max_ratio: float
) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.float64], NDArray[np.float64]]:
    """(good (G,), corners (G, 3, 2) int32 in 1/16 px, edge (T,), det (T,)): the linear
    completion's triangle filter (numpy's arithmetic bit for bit)."""

def region_plane_sums(
    comp: NDArray[np.int32], valid: NDArray[np.bool_], depth: NDArray[np.float32], fx: float,
    fy: float, cx: float, cy: float, num_regions: int
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """(count (n,), ata (n, 3, 3), atb (n, 3)): per region, the normal equations of
    1 / z ≈ a x + b y + c over its valid pixels (np.bincount's sums bit for bit)."""

def scan_range_noise(
    points: NDArray[np.float64], ring_bin_deg: float, max_step_deg: float
) -> float | None:
    """Range noise σ (m) of an (M, 3) scan from its rings' second differences, or None
    (bimcap.segmentation.geometric.scan_range_noise's numpy arithmetic bit for bit)."""

def voxel_means(
    points: NDArray[np.float64], min_range: float, max_range: float, voxel: float
) -> tuple[NDArray[np.float64], int]:
    """((n, 3) voxel means in ascending flat key order, returns kept) of an (M, 3) scan whose
    range is in [min_range, max_range] (numpy's arithmetic bit for bit)."""

def pca_normals(
    cloud: NDArray[np.float64], neighbours: NDArray[np.int64], max_flatness: float,
    min_spread: float
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """((m, 3) unit normals, (m,) planar) of each row of (m, k) indices into the (n, 3) cloud:
    the covariance's least eigenvector (sign arbitrary), λ0 <= max_flatness λ1 and λ1 >=
    min_spread λ2."""

def pixel_surface_area(
    depth: NDArray[np.float64], fx: float, fy: float, cx: float, cy: float, min_cos: float
) -> NDArray[np.float64]:
    """(H, W) m² each pixel of an undistorted (H, W) z-depth map covers (numpy's rounding)."""
def add_plane_scores(
    score: NDArray[np.int64],
    points: NDArray[np.float64],
    normals: NDArray[np.float64] | None,
    planes: NDArray[np.float64],
    offsets: NDArray[np.float64],
    thresholds: NDArray[np.float64],
    cos_n: float,
) -> None:
    """Adds to ``score`` (I,) the points i where ``|p_i · h_j + d_j| < thresholds[i]`` and
    (``normals`` not None) ``|n_i · h_j| > cos_n``: the RANSACs' score tables, each product
    rounded as numpy's matrix product forms it (fused multiply-adds), without the tables."""

def similarity_top2(
    sim: NDArray[np.int32],
) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.int32], NDArray[np.int32],
           NDArray[np.int32]]:
    """(row_best, row_s1, row_s2, col_s1, col_s2) of a C-contiguous (rows >= 1, cols >= 2)
    int32 table: per row the first column of its largest value, the largest and the second
    largest (with multiplicity), per column the largest and the second largest (INT32_MIN with
    one row); the descriptor matcher's reductions in one pass."""
def move_onto_planes(
    out: NDArray[np.float32],
    flat: NDArray[np.int64],
    ray_x: NDArray[np.float64],
    ray_y: NDArray[np.float64],
    depth: NDArray[np.float64],
    planes: NDArray[np.float64],
    products: NDArray[np.float64] | None,
    assign_threshold_m: float,
    max_change_rel: float,
) -> int:
    """Moves one region's pixels ``out[flat]`` (raveled float32 depth, in place) onto the nearest
    of its (K, 4) planes along their rays (numpy's rounding); ``products`` (n, K) p · n_k, or
    None to form them as numpy's matrix product of p = (x z, y z, z) does (fused multiply-adds).
    Returns how many pixels moved."""
def points_and_cross(
    depth: NDArray[np.float32], fx: float, fy: float, cx: float, cy: float, step: int,
    float32: bool, jump_offset_m: float = 0.05,
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], NDArray[Any]]:
    """(points (H, W, 3), valid (H, W), ok (H, W), cross (H, W, 3) float32 or float64) of an
    (H, W) float32 z-depth map: the segmenter's (and, ``jump_offset_m`` 0.1, the label
    orientation check's) central-difference cross products (numpy's rounding); a depth jump is
    ``|Δz| >= 2 (0.05 z + jump_offset_m)``."""

def orient_normals(
    normals: NDArray[np.float64], points: NDArray[np.float64], ok: NDArray[np.bool_]
) -> None:
    """Normalises ``normals`` (H, W, 3) in place and turns them toward the camera; clears ``ok``
    where the norm is <= 1e-12 and the normals where ``ok`` is false (numpy's rounding)."""

def component_pixels(
    labels: NDArray[np.int32], count: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(pixels (M,), starts (count + 1,)): the nonzero pixels of an (H, W) label image grouped by
    label, row-major inside each (label c: ``pixels[starts[c]:starts[c + 1]]``)."""
