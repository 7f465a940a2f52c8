"""Parsing COLMAP text models (``cameras.txt``, ``images.txt``) into pinhole cameras.

COLMAP poses are world-to-camera in OpenCV axes: exactly ``Camera.viewmat``.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from plantdreamer.cameras import intrinsics
from plantdreamer.errors import InputError
from plantdreamer.eval.images import check_image_size

__all__ = ["find_model_dir", "quat_to_rotation", "read_cameras_text", "read_images_text"]

# Pinhole-compatible models -> number of parameters. Distortion terms are ignored (warned).
MODELS = {
    "SIMPLE_PINHOLE": 3,
    "PINHOLE": 4,
    "SIMPLE_RADIAL": 4,
    "RADIAL": 5,
    "OPENCV": 8,
    "FULL_OPENCV": 12,
}


def _data_lines(path: Path) -> list[str]:
    """Lines of a COLMAP text file without comments (blank lines kept: images.txt needs them)."""
    return [
        line.rstrip("\n")
        for line in path.read_text(encoding="utf-8").splitlines()
        if not line.startswith("#")
    ]


def find_model_dir(root: Path) -> Path | None:
    """The first of ``root``, ``root/sparse/0``, ``root/sparse`` holding both text files."""
    for d in (root, root / "sparse" / "0", root / "sparse"):
        if (d / "cameras.txt").is_file() and (d / "images.txt").is_file():
            return d
    return None


def read_cameras_text(path: Path) -> dict[int, tuple[np.ndarray, int, int]]:
    """camera id -> (K, width, height). Radial models lose their distortion, with a warning."""
    cameras = {}
    for n, line in enumerate(_data_lines(path), start=1):
        parts = line.split()
        if not parts:
            continue
        where = f"{path.name} camera line {n}"
        if len(parts) < 4:
            raise InputError(f"{where}: expected 'ID MODEL WIDTH HEIGHT PARAMS...'")
        model = parts[1].upper()
        if model not in MODELS:
            raise InputError(
                f"{where}: camera model {model} is not supported "
                f"(supported: {', '.join(MODELS)}); undistort the images first"
            )
        try:
            cam_id, width, height = int(parts[0]), int(parts[2]), int(parts[3])
            params = [float(x) for x in parts[4:]]
        except ValueError as exc:
            raise InputError(f"{where}: {exc}") from exc
        if not all(math.isfinite(x) for x in params):
            raise InputError(f"{where}: parameters must be finite numbers, got {parts[4:]}")
        if len(params) != MODELS[model]:
            raise InputError(
                f"{where}: {model} needs {MODELS[model]} parameters, got {len(params)}"
            )
        if model.startswith("SIMPLE") or model == "RADIAL":  # f, cx, cy, [distortion]
            f, cx, cy = params[:3]
            k = intrinsics(f, f, cx, cy)
        else:  # fx, fy, cx, cy, [distortion]
            k = intrinsics(*params[:4])
        if not (k[0, 0] > 0 and k[1, 1] > 0):
            raise InputError(f"{where}: focal lengths must be positive, got {parts[4:]}")
        check_image_size(width, height, where)
        distortion = params[3:] if model in ("SIMPLE_RADIAL", "RADIAL") else params[4:]
        if any(d != 0.0 for d in distortion):
            warnings.warn(
                f"COLMAP camera {cam_id} ({model}): lens distortion ignored "
                "(pinhole rasterizer); undistort the images for exact metrics",
                stacklevel=3,
            )
        cameras[cam_id] = (k, width, height)
    return cameras


def quat_to_rotation(qw: float, qx: float, qy: float, qz: float) -> np.ndarray:
    """Rotation matrix of a (w, x, y, z) quaternion (normalised first)."""
    q = np.array([qw, qx, qy, qz], dtype=np.float64)
    norm = np.linalg.norm(q)
    if not norm > 0.0:
        raise InputError("zero quaternion")
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _is_points_line(line: str) -> bool:
    parts = line.split()
    if len(parts) % 3:
        return False
    try:
        [float(x) for x in parts]
    except ValueError:
        return False
    return True


def read_images_text(path: Path) -> list[tuple[str, np.ndarray, int]]:
    """(file name, world-to-camera 4x4, camera id) per image, in file order."""
    lines = _data_lines(path)
    images = []
    i = 0
    while i < len(lines):
        parts = lines[i].split()
        if not parts:
            i += 1
            continue
        where = f"{path.name} image line {i + 1}"
        if len(parts) < 10:
            raise InputError(f"{where}: expected 'ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        try:
            qvec = [float(x) for x in parts[1:5]]
            tvec = [float(x) for x in parts[5:8]]
            cam_id = int(parts[8])
        except ValueError as exc:
            raise InputError(f"{where}: {exc}") from exc
        viewmat = np.eye(4)
        viewmat[:3, :3] = quat_to_rotation(*qvec)
        viewmat[:3, 3] = tvec
        images.append((" ".join(parts[9:]), viewmat, cam_id))
        # The next line lists the image's 2D points as (X, Y, POINT3D_ID) triples, possibly
        # empty. Hand-written files sometimes leave it out: then the next line is an image.
        i += 2 if i + 1 < len(lines) and _is_points_line(lines[i + 1]) else 1
    return images
