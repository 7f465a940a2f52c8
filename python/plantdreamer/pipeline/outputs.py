"""What a run leaves in its output folder: the 3DGS PLY, renders, turntable, logs."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import atomic
from plantdreamer.cameras import orbit_ring
from plantdreamer.gaussians import Gaussians
from plantdreamer.pointcloud import NormalizeTransform

# float32 positions must resolve the plant at least this finely (relative to its size);
# georeferenced scans (UTM: 1e6 m from the origin) do not, and are exported with an offset.
EXPORT_PRECISION = 1e-5


def export_offset(transform: NormalizeTransform, scene_size: float) -> np.ndarray | None:
    """The offset to subtract before writing float32 positions, or None when the input
    frame itself is precise enough (a plant near its origin)."""
    center = np.asarray(transform.center, dtype=np.float64)
    extent = scene_size / transform.scale
    far = float(np.abs(center).max()) + extent
    if np.spacing(np.float32(far)) <= extent * EXPORT_PRECISION:
        return None
    return np.round(center)


def offset_comment(offset: np.ndarray) -> str:
    """The PLY comment that records an export offset in plant.ply itself."""
    return "plantdreamer offset {:.17g} {:.17g} {:.17g} (add to x y z for the input frame)".format(
        *offset
    )


def to_input_frame(
    g: Gaussians, transform: NormalizeTransform, offset: np.ndarray | None = None
) -> Gaussians:
    """Undo the normalisation: positions and scales back in the input's units and place,
    minus ``offset`` (computed in float64, so no precision is lost before the subtraction)."""
    means = transform.invert(g.means.astype(np.float64))
    if offset is not None:
        means = means - offset
    return Gaussians(
        np.asarray(means, dtype=np.float32),
        g.quats.copy(),
        np.asarray(transform.invert_log_scales(g.log_scales), dtype=np.float32),
        g.opacity_logits.copy(),
        g.sh.copy(),
    )


def to_scene_frame(
    g: Gaussians,
    size: float = 4.0,
    *,
    up: str = "z",
    center: tuple[float, float, float] | None = None,
) -> Gaussians:
    """Frames any model for the orbit: axis ``up`` turned onto +z, centred on its robust
    centre (or ``center``, in the model's own frame), the longest side of its robust box
    scaled to ``size`` (see ``plantdreamer.framing``)."""
    from plantdreamer.framing import UP_AXES, robust_center_extent, rotate_up

    g = rotate_up(g, up)
    mid, extent = robust_center_extent(g)
    if center is not None:
        mid = UP_AXES[up][0] @ np.asarray(center, dtype=np.float64)
    scale = size / extent
    return Gaussians(
        ((g.means.astype(np.float64) - mid) * scale).astype(np.float32),
        g.quats.copy(),
        (g.log_scales + np.float32(math.log(scale))).astype(np.float32),
        g.opacity_logits.copy(),
        g.sh.copy(),
    )


def export_ply(
    path: Path, g: Gaussians, sh_degree: int | None, comments: tuple[str, ...] = ()
) -> None:
    """Writes the INRIA-layout PLY (atomically: no partial file on failure)."""
    from plantdreamer.io import write_splat_ply

    write_splat_ply(path, g, sh_degree=sh_degree, comments=comments)


def render_orbit(
    render, n: int, distance: float, elevation_deg: float, fovy_deg: float, resolution: int
) -> list[np.ndarray]:
    """uint8 [H, W, 3] images of the evaluation orbit; ``render(camera) -> [H, W, 3] float``."""
    frames = []
    for cam in orbit_ring(n, distance, elevation_deg, fovy_deg, resolution, resolution):
        image = np.asarray(render(cam), dtype=np.float32)
        frames.append((np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
    return frames


def write_renders(out_dir: Path, frames: list[np.ndarray]) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        atomic.write_image(out_dir / f"view_{i:03d}.png", frame)


def write_turntable(path: Path, frames: list[np.ndarray], count: int) -> None:
    """An animated GIF of ``count`` frames evenly picked from the orbit renders."""
    import imageio.v3 as iio

    if not frames or count <= 0:
        return
    picks = np.linspace(0, len(frames), num=min(count, len(frames)), endpoint=False).astype(int)
    atomic.atomic_write(
        path,
        lambda tmp: iio.imwrite(
            tmp, np.stack([frames[i] for i in picks]), extension=".gif", duration=80, loop=0
        ),
    )


def write_json(path: Path, data: dict[str, Any]) -> None:
    atomic.write_json(path, data, default=_jsonable)


def write_log_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """One row per trained step; columns are the union of the rows' keys, in first-seen order."""
    fields = {"step": None, "loss": None, "gaussians": None}
    for row in rows:
        fields.update(dict.fromkeys(row))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(fields))
    writer.writeheader()
    writer.writerows(rows)
    atomic.write_text(path, buf.getvalue())


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
