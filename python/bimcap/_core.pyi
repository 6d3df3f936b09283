"""Type stubs of the compiled C++ core (cpp/python/bind_*.cc). Use bimcap.optimize instead."""

from typing import Any

import numpy as np
from numpy.typing import NDArray

PROBLEM_FILE_VERSION: int

class InputError(ValueError):
    """A malformed array, option or problem file; the message starts with the field name."""

def solve(arrays: dict[str, NDArray[Any]], options: dict[str, object]) -> dict[str, Any]:
    """Solve one problem; returns poses, planes, track_points, wall_segment, column_segment,
    covariance (or None) and summary (dict)."""

def default_options() -> dict[str, str]: ...
def check_options(options: dict[str, object]) -> dict[str, str]: ...
def option_keys() -> list[str]: ...
def validate_problem(arrays: dict[str, NDArray[Any]]) -> None: ...
def read_problem_file(path: str) -> tuple[dict[str, NDArray[Any]], dict[str, str]]: ...
def parse_problem_bytes(data: bytes) -> tuple[dict[str, NDArray[Any]], dict[str, str]]: ...
def write_problem_file(path: str, arrays: dict[str, NDArray[Any]], options: dict[str, object]) -> None: ...
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
