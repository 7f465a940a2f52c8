"""A generated plant read back in the frame ``generate`` rendered it in, so ``render`` makes
the same views and ground truth as ``generate`` did, at its orbit or at any camera.

``generate`` renders in its scene frame (``run.json``'s ``transform``: p_scene = (p - center)
* scale) and writes ``plant.ply`` and the poses of ``transforms.json`` in the input frame
(minus ``export_offset``, for the PLY). Reading ``run.json`` beside ``plant.ply`` gives that
frame back; its config gives the evaluation orbit (views, distance, elevation, field of view,
resolution) and the background, and ``eval_distance`` the distance generate framed the
orbit at when its config gives none.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError
from plantdreamer.gaussians import Gaussians
from plantdreamer.pipeline.settings.config import from_record
from plantdreamer.pointcloud import NormalizeTransform
from plantdreamer.settings import walk
from plantdreamer.views import ViewsConfig

RUN_FILE = "run.json"
IDENTITY = NormalizeTransform(center=(0.0, 0.0, 0.0), scale=1.0)
# The settings of generate's evaluation views (render takes them from run.json).
ORBIT = (
    "eval-views", "eval-distance", "eval-elevation-deg", "eval-fovy-deg", "resolution",
    "background",
)  # fmt: skip
# The views' rig, background and jitter, and the seed they are drawn from.
VIEWS = (*(s.name for s in walk(ViewsConfig)), "seed")


@dataclass(frozen=True)
class GenerateFrame:
    """What ``run.json`` says about a generated plant's frame and evaluation orbit."""

    transform: NormalizeTransform
    offset: np.ndarray | None  # plant.ply holds positions minus this
    orbit: dict[str, Any]  # the settings ORBIT and VIEWS name, by name

    @classmethod
    def beside(cls, ply: Path) -> GenerateFrame | None:
        """The frame of the ``generate`` run that wrote ``ply``, or None (not ours)."""
        path = Path(ply).parent / RUN_FILE
        if not path.is_file():
            return None
        try:
            run = json.loads(path.read_text())
            cfg = from_record(run["config"])
            transform = NormalizeTransform.from_dict(run["transform"])
            orbit = {name: cfg.get(name) for name in (*ORBIT, *VIEWS)}
            orbit["eval-distance"] = _orbit_distance(orbit["eval-distance"], run)
            if orbit["resolution"] is None:
                raise ValueError("no resolution recorded")
            offset = run.get("export_offset")
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, InputError) as exc:
            raise InputError(f"{path} is not a generate run.json ({exc})") from None
        return cls(transform, None if offset is None else np.asarray(offset, np.float64), orbit)

    def to_scene(self, g: Gaussians) -> Gaussians:
        """plant.ply's Gaussians in the scene frame."""
        return exported_scene(g, self.transform, self.offset)


def _orbit_distance(given: float | None, run: dict[str, Any]) -> float | None:
    """The distance generate's orbit was rendered at: given in its config, else the one it
    framed and recorded (``outputs.eval_distance``; top-level ``eval_distance`` in run.json
    files written before); None for a run without views (``render`` frames the plant by
    generate's rule then)."""
    if given is not None:
        return float(given)
    framed = run.get("outputs", {}).get("eval_distance", run.get("eval_distance"))
    return None if framed is None else float(framed)


def exported_scene(
    g: Gaussians, transform: NormalizeTransform, offset: np.ndarray | None
) -> Gaussians:
    """The Gaussians of plant.ply (float32, input frame minus ``offset``) in the scene frame.
    ``generate`` renders its views and ground truth from this too, so a re-render of the file
    gives them bit for bit (the float32 round trip through the input frame moves positions
    by an ulp or so, enough to turn a pixel)."""
    means = g.means.astype(np.float64)
    if offset is not None:
        means = means + offset
    return transform.gaussians_to_scene(g, means)


def scene_cameras(transforms: str | Path, transform: NormalizeTransform) -> list[Camera]:
    """The cameras of a transforms.json (OpenGL poses in the input frame) in the scene
    frame; poses are taken as written (not through a world-to-camera inverse and back)."""
    from plantdreamer.eval.datasets import _transforms_file, scan_transforms_json

    views = scan_transforms_json(transforms, images_required=False)
    frames = json.loads(_transforms_file(Path(transforms)).read_text())["frames"]
    center = np.asarray(transform.center, dtype=np.float64)
    cameras = []
    for view, frame in zip(views, frames, strict=True):
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
        c2w = np.vstack([c2w[:3], [0.0, 0.0, 0.0, 1.0]])
        c2w[:3, 3] = (c2w[:3, 3] - center) * transform.scale
        k, cam = view.camera.K, view.camera
        cameras.append(
            Camera.from_opengl_c2w(c2w, k[0, 0], k[1, 1], k[0, 2], k[1, 2], cam.width, cam.height)
        )
    return cameras
