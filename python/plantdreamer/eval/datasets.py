"""Posed ground-truth images: NeRF/nerfstudio ``transforms.json`` and COLMAP text models.

Every loader returns a list of ``Frame``: a camera in the rasterizer's convention (OpenCV
world-to-camera, see ``plantdreamer.cameras``), the image and, when the dataset has one, the
plant mask. Masks come from, in order: a nerfstudio per-frame ``mask_path``, the file
``masks/<name>.png`` beside the dataset, or the image's alpha channel (non-zero = plant).
Lens distortion coefficients are ignored with a warning: the rasterizer is a pinhole camera.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer.cameras import Camera, intrinsics
from plantdreamer.errors import InputError
from plantdreamer.eval.images import read_mask, read_rgba, resolve_image_path

__all__ = ["Frame", "load_colmap_text", "load_dataset", "load_transforms_json"]

_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
_UNSUPPORTED_MODELS = (
    "OPENCV_FISHEYE",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "FOV",
    "EQUIRECTANGULAR",
)


@dataclass
class Frame:
    """One ground-truth view.

    image: float32 [H, W, 3] in [0, 1], the stored colour (not composited).
    mask: bool [H, W], True on the plant, or None when the dataset has no mask.
    alpha: float32 [H, W] alpha channel of the image, or None (absent or opaque everywhere).
    """

    name: str
    camera: Camera
    image: np.ndarray
    mask: np.ndarray | None = None
    alpha: np.ndarray | None = None

    def ground_truth(self, background: tuple[float, float, float]) -> np.ndarray:
        """The image as a render with this background would show it: an RGBA image is
        composited over ``background``; an RGB image is returned as stored."""
        if self.alpha is None:
            return self.image
        a = self.alpha[..., None]
        bg = np.asarray(background, dtype=np.float32)
        return (self.image * a + bg * (1.0 - a)).astype(np.float32)


def _frame_mask(
    root: Path, name: str, explicit: Path | None, alpha: np.ndarray | None, shape: tuple[int, int]
) -> np.ndarray | None:
    if explicit is not None:
        if not explicit.is_file():
            raise FileNotFoundError(f"mask not found: {explicit}")
        path: Path | None = explicit
    else:
        default = root / "masks" / f"{name}.png"
        path = default if default.is_file() else None
    if path is not None:
        mask = read_mask(path)
        if mask.shape != shape:
            raise InputError(
                f"mask {path} is {mask.shape[1]}x{mask.shape[0]} but its image is "
                f"{shape[1]}x{shape[0]}"
            )
        return mask
    if alpha is not None:
        return alpha != 0
    return None


def _transforms_file(path: Path) -> Path:
    if path.is_file():
        return path
    if not path.exists():
        raise FileNotFoundError(f"dataset not found: {path}")
    candidate = path / "transforms.json"
    if candidate.is_file():
        return candidate
    others = sorted(p.name for p in path.glob("transforms*.json"))
    hint = f"; found {', '.join(others)}: pass one of them as the dataset" if others else ""
    raise FileNotFoundError(f"no transforms.json in {path}{hint}")


def _intrinsics(meta: dict[str, Any], width: int, height: int, where: str) -> np.ndarray:
    """K from ``fl_x/fl_y/cx/cy`` or ``camera_angle_x`` (radians, horizontal field of view)."""
    model = str(meta.get("camera_model", "OPENCV")).upper()
    if model in _UNSUPPORTED_MODELS:
        raise InputError(f"{where}: camera_model {model} is not a pinhole camera; undistort first")
    if "fl_x" in meta:
        fx = float(meta["fl_x"])
        fy = float(meta.get("fl_y", fx))
    elif "camera_angle_x" in meta:
        fx = 0.5 * width / math.tan(0.5 * float(meta["camera_angle_x"]))
        if "camera_angle_y" in meta:
            fy = 0.5 * height / math.tan(0.5 * float(meta["camera_angle_y"]))
        else:
            fy = fx
    else:
        raise InputError(f"{where}: no intrinsics (need fl_x/fl_y/cx/cy or camera_angle_x)")
    cx = float(meta.get("cx", width / 2.0))
    cy = float(meta.get("cy", height / 2.0))
    if not (fx > 0.0 and fy > 0.0 and math.isfinite(fx) and math.isfinite(fy)):
        raise InputError(f"{where}: focal lengths must be positive, got fx={fx}, fy={fy}")
    return intrinsics(fx, fy, cx, cy)


def _check_size(meta: dict[str, Any], width: int, height: int, where: str) -> None:
    w, h = meta.get("w"), meta.get("h")
    if (w is not None and int(w) != width) or (h is not None and int(h) != height):
        raise InputError(
            f"{where}: transforms.json says {w}x{h} but the image is {width}x{height} "
            "(downscaled images need matching intrinsics)"
        )


def load_transforms_json(path: str | Path) -> list[Frame]:
    """Frames of a NeRF/nerfstudio ``transforms.json`` (a directory holding one, or the file).

    ``transform_matrix`` is camera-to-world in OpenGL axes. Intrinsics and ``w``/``h`` may be
    global or per frame (per-frame values win). ``file_path`` is relative to the JSON file
    and may omit the extension.
    """
    json_path = _transforms_file(Path(path))
    root = json_path.parent
    try:
        meta = json.loads(json_path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{json_path} is not valid JSON: {exc}") from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise InputError(f"{json_path} has no 'frames' list")
    if not meta["frames"]:
        raise InputError(f"{json_path} has no frames")
    shared = {k: v for k, v in meta.items() if k != "frames"}
    frames = []
    distorted = 0
    for i, entry in enumerate(meta["frames"]):
        where = f"{json_path.name} frame {i}"
        if not isinstance(entry, dict) or "file_path" not in entry:
            raise InputError(f"{where}: missing file_path")
        if "transform_matrix" not in entry:
            raise InputError(f"{where}: missing transform_matrix")
        frame_meta = {**shared, **entry}
        distorted += any(float(frame_meta.get(k, 0.0)) != 0.0 for k in _DISTORTION_KEYS)
        image_path = resolve_image_path(root / entry["file_path"])
        name = Path(entry["file_path"]).stem
        image, alpha = read_rgba(image_path)
        height, width = image.shape[:2]
        _check_size(frame_meta, width, height, where)
        k = _intrinsics(frame_meta, width, height, where)
        c2w = np.asarray(entry["transform_matrix"], dtype=np.float64)
        camera = Camera.from_opengl_c2w(c2w, k[0, 0], k[1, 1], k[0, 2], k[1, 2], width, height)
        explicit = root / entry["mask_path"] if "mask_path" in entry else None
        mask = _frame_mask(root, name, explicit, alpha, (height, width))
        frames.append(Frame(name, camera, image, mask, alpha))
    if distorted:
        warnings.warn(
            f"{json_path}: lens distortion coefficients of {distorted} frame(s) are ignored "
            "(pinhole rasterizer); undistort the images for exact metrics",
            stacklevel=2,
        )
    return frames


# --- COLMAP ---------------------------------------------------------------------------------

# Pinhole-compatible models -> number of parameters. Distortion terms are ignored (warned).
_COLMAP_MODELS = {
    "SIMPLE_PINHOLE": 3,
    "PINHOLE": 4,
    "SIMPLE_RADIAL": 4,
    "RADIAL": 5,
    "OPENCV": 8,
    "FULL_OPENCV": 12,
}


def _data_lines(path: Path) -> list[str]:
    """Lines of a COLMAP text file without comments (blank lines kept: images.txt needs them)."""
    return [line.rstrip("\n") for line in path.read_text().splitlines() if not line.startswith("#")]


def _colmap_cameras(path: Path) -> dict[int, tuple[np.ndarray, int, int]]:
    cameras = {}
    for n, line in enumerate(_data_lines(path), start=1):
        parts = line.split()
        if not parts:
            continue
        where = f"{path.name} camera line {n}"
        if len(parts) < 4:
            raise InputError(f"{where}: expected 'ID MODEL WIDTH HEIGHT PARAMS...'")
        model = parts[1].upper()
        if model not in _COLMAP_MODELS:
            raise InputError(
                f"{where}: camera model {model} is not supported "
                f"(supported: {', '.join(_COLMAP_MODELS)}); undistort the images first"
            )
        try:
            cam_id, width, height = int(parts[0]), int(parts[2]), int(parts[3])
            params = [float(x) for x in parts[4:]]
        except ValueError as exc:
            raise InputError(f"{where}: {exc}") from exc
        if len(params) != _COLMAP_MODELS[model]:
            raise InputError(
                f"{where}: {model} needs {_COLMAP_MODELS[model]} parameters, got {len(params)}"
            )
        if model.startswith("SIMPLE") or model == "RADIAL":  # f, cx, cy, [distortion]
            f, cx, cy = params[:3]
            k = intrinsics(f, f, cx, cy)
        else:  # fx, fy, cx, cy, [distortion]
            k = intrinsics(*params[:4])
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


def _colmap_model_dir(root: Path) -> Path | None:
    for d in (root, root / "sparse" / "0", root / "sparse"):
        if (d / "cameras.txt").is_file() and (d / "images.txt").is_file():
            return d
    return None


def load_colmap_text(path: str | Path) -> list[Frame]:
    """Frames of a COLMAP text model, sorted by image name.

    The model (``cameras.txt``, ``images.txt``) is looked for in ``path``, ``path/sparse/0``
    and ``path/sparse``; images in ``path/images`` (else ``path``), masks in
    ``path/masks/<stem>.png``. Poses are world-to-camera, OpenCV axes, as COLMAP writes them.
    """
    root = Path(path)
    if not root.exists():
        raise FileNotFoundError(f"dataset not found: {root}")
    model_dir = _colmap_model_dir(root)
    if model_dir is None:
        raise FileNotFoundError(f"no COLMAP cameras.txt + images.txt in {root} or {root}/sparse/0")
    cameras = _colmap_cameras(model_dir / "cameras.txt")
    image_dir = root / "images" if (root / "images").is_dir() else root
    lines = _data_lines(model_dir / "images.txt")
    frames = []
    i = 0
    while i < len(lines):
        parts = lines[i].split()
        if not parts:
            i += 1
            continue
        where = f"images.txt image line {i + 1}"
        if len(parts) < 10:
            raise InputError(f"{where}: expected 'ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        try:
            qvec = [float(x) for x in parts[1:5]]
            tvec = np.array([float(x) for x in parts[5:8]])
            cam_id = int(parts[8])
        except ValueError as exc:
            raise InputError(f"{where}: {exc}") from exc
        file_name = " ".join(parts[9:])
        # The next line lists the image's 2D points as (X, Y, POINT3D_ID) triples, possibly
        # empty. Hand-written files sometimes leave it out: then the next line is an image.
        i += 2 if i + 1 < len(lines) and _is_points_line(lines[i + 1]) else 1
        if cam_id not in cameras:
            raise InputError(f"{where}: camera {cam_id} is not in cameras.txt")
        k, width, height = cameras[cam_id]
        viewmat = np.eye(4)
        viewmat[:3, :3] = quat_to_rotation(*qvec)
        viewmat[:3, 3] = tvec
        image, alpha = read_rgba(resolve_image_path(image_dir / file_name))
        if image.shape[:2] != (height, width):
            raise InputError(
                f"{file_name}: cameras.txt says {width}x{height} but the image is "
                f"{image.shape[1]}x{image.shape[0]}"
            )
        name = Path(file_name).stem
        mask = _frame_mask(root, name, None, alpha, (height, width))
        frames.append(Frame(name, Camera(viewmat, k, width, height), image, mask, alpha))
    if not frames:
        raise InputError(f"{model_dir / 'images.txt'} lists no images")
    frames.sort(key=lambda f: f.name)
    return frames


def load_dataset(path: str | Path) -> list[Frame]:
    """Frames of a dataset: a directory with ``transforms.json`` or a COLMAP text model, or the
    ``.json`` file itself (e.g. ``transforms_test.json``)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"dataset not found: {p}")
    if p.is_file() or (p / "transforms.json").is_file():
        return load_transforms_json(p)
    if _colmap_model_dir(p) is not None:
        return load_colmap_text(p)
    others = sorted(x.name for x in p.glob("transforms*.json"))
    hint = f" (found {', '.join(others)}: pass one of them)" if others else ""
    raise InputError(
        f"{p} is not a dataset: expected transforms.json or a COLMAP text model "
        f"(cameras.txt + images.txt, possibly under sparse/0){hint}"
    )
