"""A real rig's cameras (a nerfstudio ``transforms.json``) framed on a plant: each camera
keeps its intrinsics, image size and orientation, and the rig keeps its shape; it is moved so
that its centre (the point nearest every optical axis, least squares; of several such, the
one nearest the file's origin) lies on the plant's centre (the scene frame's origin), and
scaled about it so that every camera sees the whole plant, less its strays, with
``FRAME_MARGIN`` to spare, as the orbit is framed.

The scale: a camera at s c (c its position relative to the centre, R its rotation) sees the
point p at x = a . p - s a . c, z = f . p + s d for each image axis a (right, down), its
optical axis f and d = -f . c, the centre's depth. A sphere of radius r at p lies inside the
side plane e x = k z (e = +-1 the side, k its extent from the principal point over the focal
length, less the margin) when s (k d + e a . c) >= e a . p - k f . p + r sqrt(1 + k^2); the
scale is the largest such bound (for an orbit, a . c = 0 and d = 1: ``orbit_distance``). A camera that does not look towards the centre cannot be framed and is refused.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError
from plantdreamer.framing import FAINT, FRAME_MARGIN, FRAME_SIGMAS, without_strays
from plantdreamer.gaussians import Gaussians


def rig_cameras(path: str | Path) -> list[Camera]:
    """The cameras of a transforms.json, as written (its frame, its units)."""
    from plantdreamer.eval.datasets import scan_transforms_json

    return [view.camera for view in scan_transforms_json(path, images_required=False)]


def rig_centre(cameras: list[Camera]) -> np.ndarray:
    """The point nearest every camera's optical axis (least squares; the one nearest the
    origin where the axes do not fix it, as for parallel cameras)."""
    a, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        f = cam.viewmat[2, :3]
        across = np.eye(3) - np.outer(f, f)
        a += across
        b += across @ cam.position
    return np.linalg.lstsq(a, b, rcond=1e-9)[0]


def framed_rig(path: str | Path, scene: Gaussians) -> list[Camera]:
    """The rig of ``path`` framed on ``scene`` (in its frame, around its origin)."""
    cameras = rig_cameras(path)
    centre = rig_centre(cameras)
    scale = rig_scale(cameras, centre, without_strays(scene), Path(path))
    framed = []
    for cam in cameras:
        rotation = cam.viewmat[:3, :3]
        position = scale * (cam.position - centre)
        viewmat = np.eye(4)
        viewmat[:3, :3] = rotation
        viewmat[:3, 3] = -rotation @ position
        framed.append(Camera(viewmat, cam.K.copy(), cam.width, cam.height))
    return framed


def rig_scale(cameras: list[Camera], centre: np.ndarray, g: Gaussians, path: Path) -> float:
    """The smallest scale of the rig about ``centre`` at which every camera sees ``g``
    (placed on ``centre``) whole (the module's docstring)."""
    means = np.asarray(g.means, dtype=np.float64)
    radius = FRAME_SIGMAS * np.exp(np.asarray(g.log_scales, dtype=np.float64).max(axis=1))
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, dtype=np.float64)))
    keep = np.isfinite(means).all(axis=1) & np.isfinite(radius) & (opacity >= FAINT)
    if not keep.any():
        raise InputError("no visible Gaussian to frame the rig on")
    means, radius = means[keep], radius[keep]
    far = -math.inf
    for i, cam in enumerate(cameras):
        right, down, forward = cam.viewmat[:3, :3]
        c = cam.position - centre
        depth = -float(forward @ c)  # the centre's depth before the camera, per unit scale
        fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
        sides = (
            (right, 1.0, (cam.width - cx) / fx),
            (right, -1.0, cx / fx),
            (down, 1.0, (cam.height - cy) / fy),
            (down, -1.0, cy / fy),
        )
        for axis, sign, extent in sides:
            k = extent * (1.0 - FRAME_MARGIN)
            coefficient = k * depth + sign * float(axis @ c)
            if not (k > 0 and coefficient > 0):
                raise InputError(
                    f"{path}: camera {i} does not look towards the rig's centre "
                    f"{np.round(centre, 6).tolist()}: the rig cannot be framed on a plant"
                )
            bound = (sign * means @ axis - k * means @ forward) + radius * math.sqrt(1 + k * k)
            far = max(far, float(bound.max()) / coefficient)
    if not far > 0:
        raise InputError("the model has no extent to frame the rig on")
    return far
