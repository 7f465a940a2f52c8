"""What a run leaves in its output folder: the 3DGS PLY, renders, turntable, logs."""

from __future__ import annotations

import csv
import functools
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import turntable
from plantdreamer.atomic import atomic_write
from plantdreamer.cameras import orbit_ring
from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians
from plantdreamer.pointcloud import NormalizeTransform
from plantdreamer.turntable import TURNTABLE_FORMATS


def to_input_frame(g: Gaussians, transform: NormalizeTransform) -> Gaussians:
    """Undo the normalisation: positions and scales back in the input's units and place."""
    return Gaussians(
        np.asarray(transform.invert(g.means), dtype=np.float32),
        g.quats.copy(),
        np.asarray(transform.invert_log_scales(g.log_scales), dtype=np.float32),
        g.opacity_logits.copy(),
        g.sh.copy(),
        None if g.labels is None else g.labels.copy(),
    )


def to_scene_frame(g: Gaussians, size: float = 4.0) -> tuple[Gaussians, NormalizeTransform]:
    """Centres a model on its bounding box and scales its longest side to ``size``; returns
    it and the transform from the model's frame."""
    from plantdreamer.pointcloud import normalize

    means, transform = normalize(g.means, size=size)
    scene = Gaussians(
        np.asarray(means, dtype=np.float32),
        g.quats.copy(),
        (g.log_scales + np.float32(math.log(float(transform.scale)))).astype(np.float32),
        g.opacity_logits.copy(),
        g.sh.copy(),
        None if g.labels is None else g.labels.copy(),
    )
    return scene, transform


def export_ply(path: Path, g: Gaussians, sh_degree: int | None, labels: bool = True) -> None:
    """Writes the INRIA-layout PLY atomically (no partial file on failure); with
    ``labels``, the Gaussians' labels follow as ``label`` and ``instance``."""
    from plantdreamer.io import write_splat_ply

    atomic_write(path, lambda tmp: write_splat_ply(tmp, g, sh_degree=sh_degree, labels=labels))


def render_orbit(
    render, n: int, distance: float, elevation_deg: float, fovy_deg: float, resolution: int
) -> list[np.ndarray]:
    """uint8 [H, W, 3] images of the evaluation orbit; ``render(camera) -> [H, W, 3] float``."""
    cameras = orbit_ring(n, distance, elevation_deg, fovy_deg, resolution, resolution)
    return [to_uint8(render(cam)) for cam in cameras]


def to_uint8(image) -> np.ndarray:
    """A float [H, W, 3] image in [0, 1] as uint8 (clipped, rounded)."""
    image = np.asarray(image, dtype=np.float32)
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_renders(out_dir: Path, frames: list[np.ndarray]) -> None:
    import imageio.v3 as iio

    out_dir.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        iio.imwrite(out_dir / f"view_{i:03d}.png", frame)


def write_turntables(
    out_dir: Path, frames: list[np.ndarray], count: int, fmt: str = "gif"
) -> list[Path]:
    """``turntable.gif`` and/or ``turntable.mp4`` (``fmt``: one of TURNTABLE_FORMATS) of
    ``count`` frames evenly picked from the orbit renders; returns the files written."""
    if fmt not in TURNTABLE_FORMATS:
        raise InputError(f"turntable must be one of {', '.join(TURNTABLE_FORMATS)}, got {fmt!r}")
    if not frames or count <= 0:
        return []
    picks = np.linspace(0, len(frames), num=min(count, len(frames)), endpoint=False).astype(int)
    chosen = [frames[i] for i in picks]
    writers = {"gif": turntable.write_gif, "mp4": turntable.write_mp4}
    paths = []
    for suffix in turntable.suffixes(fmt):
        path = out_dir / f"turntable.{suffix}"
        atomic_write(path, functools.partial(writers[suffix], frames=chosen))
        paths.append(path)
    return paths


def write_json(path: Path, data: dict[str, Any]) -> None:
    text = json.dumps(data, indent=2, sort_keys=False, default=_jsonable)
    atomic_write(path, lambda tmp: tmp.write_text(text + "\n"))


def write_log_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """One row per trained step; columns are the union of the rows' keys, in first-seen order."""
    fields = {"step": None, "loss": None, "gaussians": None}
    for row in rows:
        fields.update(dict.fromkeys(row))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(fields))
    writer.writeheader()
    writer.writerows(rows)
    atomic_write(path, lambda tmp: tmp.write_text(buf.getvalue()))


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
