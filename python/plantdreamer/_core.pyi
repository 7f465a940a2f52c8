# Type stub of the native module built from crates/pyplant.
# tests/test_stub.py runs mypy.stubtest against the compiled module: keep them in step.
from typing import Any, final

import numpy as np
import numpy.typing as npt

__all__ = [
    "InputError",
    "PlantDreamerError",
    "PlyError",
    "RasterState",
    "__version__",
    "check_ply_vertex",
    "downsample_to_count",
    "eval_sh",
    "group_coverage",
    "info",
    "knn",
    "knn_mean_distance",
    "large_gaussian_mask",
    "raster_defaults",
    "rasterize_backward_many",
    "rasterize_forward_many",
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

# Culling (crates/pyplant/src/culling.rs)
def large_gaussian_mask(
    log_scales: npt.NDArray[np.float32], c: float = 3.0
) -> tuple[npt.NDArray[np.bool_], dict[str, float]]: ...

# Each group's silhouette alone in one camera of a forward pass (crates/pyplant/src/
# coverage.rs): state from a rasterize_forward_many result; returns (alone, visible)
# pixel counts per group.
def group_coverage(
    state: RasterState,
    groups: npt.NDArray[np.int32],
    labels: npt.NDArray[np.int32],
    group_labels: npt.NDArray[np.int32],
    *,
    alpha_threshold: float,
    camera: int | None = None,
    tile_size: int | None = None,
    threads: int | None = None,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]: ...

# --- point clouds and PLY (crates/pyplant/src/{ply,pointcloud}.rs) ---
def read_ply_vertex(
    path: str, groups: list[list[str]] = ..., strict: bool = False
) -> tuple[int, list[tuple[list[str], npt.NDArray[Any]]], str, list[str], list[str]]: ...
def check_ply_vertex(path: str) -> None: ...
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

# --- rasterizer (crates/pyplant/src/raster.rs) ---
@final
class RasterState:
    """Opaque forward state for rasterize_backward_many."""

    @property
    def nbytes(self) -> int: ...

def raster_defaults() -> dict[str, Any]: ...

# A scene of rasterize_forward_many: means, quats, scales, opacities, colors (None when
# render_color is False: not read), viewmats, Ks (float32 arrays), width, height (ints),
# and optionally sh_degree (int or None) and background ([C, ch] behind the colours).
def rasterize_forward_many(
    scenes: list[dict[str, Any]],
    *,
    near_plane: float | None = None,
    far_plane: float | None = None,
    eps2d: float | None = None,
    antialiased: bool | None = None,
    render_color: bool = True,
    render_depth: bool | None = None,
    tile_size: int | None = None,
    footprint_sigma: float | None = None,
    tile_ellipse: bool | None = None,
    t_min: float | None = None,
    simd: bool | None = None,
    threads: int | None = None,
) -> list[dict[str, Any] | BaseException]: ...
def rasterize_backward_many(
    states: list[RasterState],
    v_renders: list[npt.NDArray[np.float32]],
    v_alphas: list[npt.NDArray[np.float32] | None],
    *,
    means: bool = True,
    quats: bool = True,
    scales: bool = True,
    opacities: bool = True,
    colors: bool = True,
    threads: int | None = None,
) -> list[dict[str, Any] | BaseException]: ...

# --- SH colours (crates/pyplant/src/sh.rs) ---
def eval_sh(
    degree: int, coeffs: npt.NDArray[np.float32], dirs: npt.NDArray[np.float32]
) -> npt.NDArray[np.float32]: ...
