"""What a run leaves in its output folder: the 3DGS PLY, renders, turntable, logs."""

from __future__ import annotations

import csv
import functools
import importlib.util
import io
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer import atomic, turntable
from plantdreamer.atomic import atomic_write
from plantdreamer.cameras import orbit_ring
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.gaussians import Gaussians
from plantdreamer.pointcloud import NormalizeTransform
from plantdreamer.settings import option_prefix, setting
from plantdreamer.turntable import TURNTABLE_FORMATS, TURNTABLE_FRAMES
from plantdreamer.views.config import ViewsConfig

# float32 positions must resolve the plant at least this finely (relative to its size);
# georeferenced scans (UTM: 1e6 m from the origin) do not, and are exported with an offset.
EXPORT_PRECISION = 1e-5


# The orbit's cameras are held until the export ends (its views are written as they are
# made): one view per 0.1 degree is more than any use of the orbit needs.
MAX_EVAL_VIEWS = 3600
# The longest cadence of progress pictures taken: beyond any run's steps (whose last step
# has its pictures whatever the cadence).
MAX_PROGRESS_EVERY = 2**31 - 1
# Settings that only watch a run: they change none of its plant's outputs.
WATCHING = ("progress-every", "tensorboard")


@dataclass
class OutputsConfig:
    """The outputs section: the evaluation orbit, the turntable and the PLY's contents."""

    eval_views: int = setting(120, "Renders on the evaluation orbit.", range=(0, MAX_EVAL_VIEWS))
    eval_distance: float | None = setting(
        None,
        "Evaluation orbit camera distance (scene units; the plant's longest side is scene-size).",
        default_text="framed: the closest at which the whole plant is in every view",
    )
    eval_elevation_deg: float = setting(15.0, "Evaluation orbit elevation (degrees).")
    eval_fovy_deg: float = setting(70.0, "Evaluation orbit vertical field of view (degrees).")
    turntable_frames: int = setting(TURNTABLE_FRAMES, "Frames of the turntable.")
    turntable: str = setting(
        "gif",
        "Turntable of the evaluation orbit: turntable.gif, turntable.mp4, both or none.",
        choices=TURNTABLE_FORMATS,
    )
    sh_degree_export: int | None = setting(
        3,
        "SH degree of plant.ply, zero-padded or cut (3: what INRIA's loader and strict "
        "viewers accept).",
        range=(0, 3),
    )
    labels: bool = setting(
        True, "Write label/instance into plant.ply and the class and instance masks."
    )
    leaf_occlusion: bool = setting(
        True,
        "Count each visible leaf's silhouette alone on each view's render pass, to "
        "measure how much of it the view shows (traits.json, COCO's visible_fraction; "
        "docs/traits.md: about 3% of a --guidance none run's CPU time).",
    )
    progress_every: int | None = setting(
        None,
        "Steps between the progress pictures (progress/step_N.png, progress.png, loss.png), "
        "and at the last step.",
        range=(1, MAX_PROGRESS_EVERY),
        default_text="at each checkpoint",
    )
    tensorboard: bool = setting(
        False,
        "Write TensorBoard events in each plant's tensorboard/ folder: log.csv's figures at "
        "every step and the progress pictures (the tensorboard extra).",
    )
    # The exported views' rig, background and jitter (the orbit on grey by default).
    views: ViewsConfig = field(default_factory=ViewsConfig, metadata=option_prefix(""))

    def validate(self) -> None:
        """The evaluation orbit is a camera and the turntable a count, checked before a run
        trains (the export comes after all training)."""
        if not 0 < self.eval_fovy_deg < 180:
            raise InputError(f"eval-fovy-deg must be in (0, 180) degrees, got {self.eval_fovy_deg}")
        if self.eval_distance is not None and not self.eval_distance > 0:  # None: framed
            raise InputError(f"eval-distance must be positive, got {self.eval_distance}")
        if not -90 <= self.eval_elevation_deg <= 90:
            raise InputError(
                f"eval-elevation-deg must be in [-90, 90] degrees, got {self.eval_elevation_deg}"
            )
        if self.tensorboard:  # found before anything trains, not after
            check_tensorboard()
        if self.turntable_frames < 0:
            raise InputError(
                f"turntable-frames must be >= 0, got {self.turntable_frames} "
                "(--turntable none makes no turntable)"
            )
        self.views.validate()


def check_tensorboard() -> None:
    """PlantDreamerError saying what to install when ``tensorboard`` is on and TensorBoard is
    not there (looked for, not imported)."""
    if importlib.util.find_spec("tensorboard") is None:
        raise PlantDreamerError(
            "the tensorboard setting needs the tensorboard package, which is not installed: "
            "pip install 'plantdreamer[tensorboard]' (or: pip install tensorboard)"
        )


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


def export_ply(
    path: Path,
    g: Gaussians,
    sh_degree: int | None,
    labels: bool = True,
    comments: tuple[str, ...] = (),
) -> None:
    """Writes the INRIA-layout PLY (atomically: no partial file on failure); with
    ``labels``, the Gaussians' labels follow as ``label`` and ``instance``."""
    from plantdreamer.io import write_splat_ply

    write_splat_ply(path, g, sh_degree=sh_degree, labels=labels, comments=comments)


def eval_orbit(oc: OutputsConfig, scene: Gaussians, resolution: int) -> tuple[list, float | None]:
    """The evaluation orbit's cameras for the model ``scene`` (scene frame) and its distance:
    ``eval_distance``, or framed on the model (``framing.framed_distance``); None without
    views."""
    from plantdreamer.framing import framed_distance

    if oc.eval_views <= 0:
        return [], oc.eval_distance
    distance = oc.eval_distance
    if distance is None:
        distance = framed_distance(
            scene, oc.eval_views, oc.eval_elevation_deg, oc.eval_fovy_deg, resolution, resolution
        )
    cameras = orbit_ring(
        oc.eval_views, distance, oc.eval_elevation_deg, oc.eval_fovy_deg, resolution, resolution
    )
    return cameras, distance


def to_uint8(image) -> np.ndarray:
    """A float [H, W, 3] image in [0, 1] as uint8 (clipped, rounded)."""
    image = np.asarray(image, dtype=np.float32)
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_renders(out_dir: Path, frames: list[np.ndarray], **png: Any) -> None:
    """``view_NNN.png`` per frame (``png``: Pillow's PNG options, as ``compress_level``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        atomic.write_image(out_dir / f"view_{i:03d}.png", frame, **png)


def write_turntables(
    out_dir: Path, frames: list[np.ndarray], count: int, fmt: str = "gif"
) -> list[Path]:
    """``turntable.gif`` and/or ``turntable.mp4`` (``fmt``: one of TURNTABLE_FORMATS) of
    ``count`` frames evenly picked from the orbit renders; returns the files written."""
    picks = turntable_picks(len(frames), count)
    return write_turntable_frames(out_dir, [frames[i] for i in picks], fmt)


def turntable_picks(views: int, count: int) -> list[int]:
    """The views of an orbit of ``views`` that a turntable of ``count`` frames shows (evenly
    spaced, from the first)."""
    if views <= 0 or count <= 0:
        return []
    return [int(i) for i in np.linspace(0, views, num=min(count, views), endpoint=False)]


class StreamedViews:
    """The views written as they are made (``view_NNN.png`` in ``out_dir``; ``png``:
    Pillow's PNG options, as ``compress_level``), with only the frames its turntable shows
    kept: the memory a render holds is the turntable's frames (``turntable_frames`` at
    most), whatever the number of views."""

    def __init__(
        self,
        out_dir: Path,
        views: int,
        turntable_frames: int,
        fmt: str,
        png: dict[str, Any] | None = None,
    ) -> None:
        if fmt not in TURNTABLE_FORMATS:
            raise InputError(
                f"turntable must be one of {', '.join(TURNTABLE_FORMATS)}, got {fmt!r}"
            )
        self.out_dir, self.fmt, self.png = out_dir, fmt, dict(png or {})
        count = turntable_frames if fmt != "none" else 0
        self.picks = set(turntable_picks(views, count))
        self.kept: list[np.ndarray] = []
        self.written = 0
        out_dir.mkdir(parents=True, exist_ok=True)

    def add(self, index: int, frame: np.ndarray) -> None:
        atomic.write_image(self.out_dir / f"view_{index:03d}.png", frame, **self.png)
        self.written += 1
        if index in self.picks:
            self.kept.append(frame)

    def write_turntables(self, folder: Path) -> list[Path]:
        """The turntable of the kept frames, into ``folder``."""
        return write_turntable_frames(folder, self.kept, self.fmt)


def write_turntable_frames(out_dir: Path, chosen: list[np.ndarray], fmt: str) -> list[Path]:
    """``turntable.gif`` and/or ``turntable.mp4`` of the frames ``chosen``."""
    if fmt not in TURNTABLE_FORMATS:
        raise InputError(f"turntable must be one of {', '.join(TURNTABLE_FORMATS)}, got {fmt!r}")
    if not chosen:
        return []
    writers = {"gif": turntable.write_gif, "mp4": turntable.write_mp4}
    paths = []
    for suffix in turntable.suffixes(fmt):
        path = out_dir / f"turntable.{suffix}"
        atomic_write(path, functools.partial(writers[suffix], frames=chosen))
        paths.append(path)
    return paths


def write_json(path: Path, data: dict[str, Any]) -> None:
    atomic.write_json(path, data, default=_jsonable)


def samples_cell(values: Sequence[float]) -> str:
    """A per-sample figure's log.csv cell (e.g. each drawn timestep): the values separated
    by spaces, whole numbers without a decimal point."""
    return " ".join(str(int(v)) if float(v).is_integer() else repr(float(v)) for v in values)


def read_samples_cell(text: str) -> list[float]:
    """The values of a ``samples_cell``; none for an empty cell (a row logged without it)."""
    return [float(v) for v in text.split()]


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
