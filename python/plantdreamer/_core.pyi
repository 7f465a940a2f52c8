# Type stub of the native module built from crates/pyplant.
# tests/test_stub.py runs mypy.stubtest against the compiled module: keep them in step.
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = [
    "InputError",
    "PlantDreamerError",
    "PlyError",
    "__version__",
    "downsample_to_count",
    "info",
    "knn",
    "knn_mean_distance",
    "read_ply_vertex",
    "remove_statistical_outliers",
    "voxel_downsample",
    "write_ply_vertex",
]

__version__: str

class PlantDreamerError(Exception): ...
class InputError(PlantDreamerError): ...
class PlyError(PlantDreamerError): ...

def info() -> dict[str, Any]: ...

# --- point clouds and PLY (crates/pyplant/src/{ply,pointcloud}.rs) ---
def read_ply_vertex(
    path: str, groups: list[list[str]] = ...
) -> tuple[int, list[tuple[list[str], npt.NDArray[Any]]], str, list[str]]: ...
def write_ply_vertex(
    path: str,
    fields: list[tuple[list[str], npt.NDArray[Any]]],
    binary: bool = True,
    comments: list[str] = ...,
) -> None: ...
def remove_statistical_outliers(
    points: npt.NDArray[np.floating[Any]],
    nb_neighbors: int,
    std_ratio: float,
    threads: int | None = None,
) -> npt.NDArray[np.int64]: ...
def voxel_downsample(
    points: npt.NDArray[np.floating[Any]],
    voxel_size: float,
    colors: npt.NDArray[np.float32] | None = None,
    threads: int | None = None,
) -> tuple[npt.NDArray[np.floating[Any]], npt.NDArray[np.float32] | None]: ...
def downsample_to_count(
    points: npt.NDArray[np.floating[Any]],
    target: int,
    colors: npt.NDArray[np.float32] | None = None,
    tolerance: float = 0.05,
    threads: int | None = None,
) -> tuple[npt.NDArray[np.floating[Any]], npt.NDArray[np.float32] | None, float]: ...
def knn(
    points: npt.NDArray[np.floating[Any]], k: int, threads: int | None = None
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32]]: ...
def knn_mean_distance(
    points: npt.NDArray[np.floating[Any]], k: int, threads: int | None = None
) -> npt.NDArray[np.float32]: ...
