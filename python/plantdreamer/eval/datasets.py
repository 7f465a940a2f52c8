"""Posed ground-truth images: NeRF/nerfstudio ``transforms.json`` and COLMAP text models.

``scan_*`` functions read the metadata and return ``FrameSource``s (cameras in the
rasterizer's convention, OpenCV world-to-camera, see ``plantdreamer.cameras``; image and mask
paths); ``load_*`` functions also read every image and return ``Frame``s. Masks come from, in
order: a nerfstudio per-frame ``mask_path``, the file ``masks/<name>.png`` beside the dataset
(``<name>`` is the image file name without extension), or the image's alpha channel
(non-zero = plant). Lens distortion is ignored with a warning: the rasterizer is a pinhole.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer.cameras import Camera, intrinsics
from plantdreamer.errors import InputError
from plantdreamer.eval.colmap import find_model_dir, read_cameras_text, read_images_text
from plantdreamer.eval.frames import Frame, FrameSource
from plantdreamer.eval.images import check_image_size, image_size, resolve_image_path

__all__ = [
    "Frame",
    "FrameSource",
    "load_colmap_text",
    "load_dataset",
    "load_transforms_json",
    "scan_colmap_text",
    "scan_dataset",
    "scan_transforms_json",
]

_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
_UNSUPPORTED_MODELS = ("OPENCV_FISHEYE", "EQUIRECTANGULAR")


def _mask_path(root: Path, name: str, explicit: str | None) -> Path | None:
    if explicit is not None:
        path = root / explicit
        if not path.is_file():
            raise FileNotFoundError(f"mask not found: {path}")
        return path
    default = root / "masks" / f"{name}.png"
    return default if default.is_file() else None


# --- transforms.json ------------------------------------------------------------------------


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
        fx = 0.5 * width / math.tan(0.5 * _angle(meta, "camera_angle_x", where))
        if "camera_angle_y" in meta:
            fy = 0.5 * height / math.tan(0.5 * _angle(meta, "camera_angle_y", where))
        else:
            fy = fx
    else:
        raise InputError(f"{where}: no intrinsics (need fl_x/fl_y/cx/cy or camera_angle_x)")
    cx = float(meta.get("cx", width / 2.0))
    cy = float(meta.get("cy", height / 2.0))
    if not (fx > 0.0 and fy > 0.0 and math.isfinite(fx) and math.isfinite(fy)):
        raise InputError(f"{where}: focal lengths must be positive, got fx={fx}, fy={fy}")
    return intrinsics(fx, fy, cx, cy)


def _angle(meta: dict[str, Any], key: str, where: str) -> float:
    value = float(meta[key])
    if not 0.0 < value < math.pi:
        raise InputError(f"{where}: {key} must be a field of view in (0, pi) radians, got {value}")
    return value


def _pixels(meta: dict[str, Any], key: str, where: str) -> int | None:
    """``w`` or ``h`` of ``meta`` as a pixel count (None when absent): 32.9 or ``true``
    is refused, not rendered at 32 or 1 pixels."""
    value = meta.get(key)
    if value is None:
        return None
    whole = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
    if isinstance(value, bool) or not whole:
        raise InputError(f"{where}: {key} must be a whole number of pixels, got {value!r}")
    return int(value)


def _check_size(meta: dict[str, Any], width: int, height: int, where: str) -> None:
    w, h = _pixels(meta, "w", where), _pixels(meta, "h", where)
    if (w is not None and w != width) or (h is not None and h != height):
        raise InputError(
            f"{where}: transforms.json says {w}x{h} but the image is {width}x{height} "
            "(downscaled images need matching intrinsics)"
        )


def scan_transforms_json(path: str | Path, images_required: bool = True) -> list[FrameSource]:
    """The views of a NeRF/nerfstudio ``transforms.json`` (a directory holding one, or the
    file), in file order, without reading the pixels.

    With ``images_required=False`` (cameras only, e.g. to render novel views), a frame whose
    image is absent takes its size from ``w``/``h``.

    ``transform_matrix`` is camera-to-world in OpenGL axes. Intrinsics and ``w``/``h`` may be
    global or per frame (per-frame values win). ``file_path`` is relative to the JSON file
    and may omit the extension.
    """
    json_path = _transforms_file(Path(path))
    with _malformed(json_path):
        return _scan_transforms_json(json_path, images_required)


@contextmanager
def _malformed(path: Path) -> Iterator[None]:
    """Wrong types or values anywhere in a dataset's metadata: one InputError naming the file."""
    try:
        yield
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except json.JSONDecodeError as exc:
        raise InputError(f"{path} is not valid JSON: {exc}") from exc
    except (ValueError, TypeError, KeyError, IndexError, ArithmeticError) as exc:
        raise InputError(f"{path}: malformed value ({type(exc).__name__}: {exc})") from exc


def _scan_transforms_json(json_path: Path, images_required: bool) -> list[FrameSource]:
    root = json_path.parent
    meta = json.loads(json_path.read_text(encoding="utf-8"))
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise InputError(f"{json_path} has no 'frames' list")
    if not meta["frames"]:
        raise InputError(f"{json_path} has no frames")
    shared = {k: v for k, v in meta.items() if k != "frames"}
    sources = []
    distorted = 0
    for i, entry in enumerate(meta["frames"]):
        where = f"{json_path.name} frame {i}"
        if not isinstance(entry, dict) or "file_path" not in entry:
            raise InputError(f"{where}: missing file_path")
        if "transform_matrix" not in entry:
            raise InputError(f"{where}: missing transform_matrix")
        frame_meta = {**shared, **entry}
        distorted += any(float(frame_meta.get(k, 0.0)) != 0.0 for k in _DISTORTION_KEYS)
        name = Path(entry["file_path"]).stem
        try:
            image_path = resolve_image_path(root / entry["file_path"])
            width, height = image_size(image_path)
        except FileNotFoundError:
            w, h = _pixels(frame_meta, "w", where), _pixels(frame_meta, "h", where)
            if images_required or w is None or h is None:
                raise
            image_path = root / entry["file_path"]
            width, height = check_image_size(w, h, where)
        _check_size(frame_meta, width, height, where)
        k = _intrinsics(frame_meta, width, height, where)
        c2w = np.asarray(entry["transform_matrix"], dtype=np.float64)
        camera = Camera.from_opengl_c2w(c2w, k[0, 0], k[1, 1], k[0, 2], k[1, 2], width, height)
        mask_path = _mask_path(root, name, entry.get("mask_path"))
        sources.append(FrameSource(name, camera, image_path, mask_path))
    if distorted:
        warnings.warn(
            f"{json_path}: lens distortion coefficients of {distorted} frame(s) are ignored "
            "(pinhole rasterizer); undistort the images for exact metrics",
            stacklevel=2,
        )
    return sources


def load_transforms_json(path: str | Path) -> list[Frame]:
    """``scan_transforms_json`` with every frame read into memory."""
    return [s.load() for s in scan_transforms_json(path)]


# --- COLMAP ---------------------------------------------------------------------------------


def scan_colmap_text(path: str | Path) -> list[FrameSource]:
    """The views of a COLMAP text model, sorted by image name, without reading the pixels.

    The model (``cameras.txt``, ``images.txt``) is looked for in ``path``, ``path/sparse/0``
    and ``path/sparse``; images in ``path/images`` (else ``path``), masks in
    ``path/masks/<stem>.png``. Poses are world-to-camera, OpenCV axes, as COLMAP writes them.
    """
    root = Path(path)
    if not root.exists():
        raise FileNotFoundError(f"dataset not found: {root}")
    model_dir = find_model_dir(root)
    if model_dir is None:
        raise FileNotFoundError(f"no COLMAP cameras.txt + images.txt in {root} or {root}/sparse/0")
    with _malformed(model_dir):
        return _scan_colmap_text(root, model_dir)


def _scan_colmap_text(root: Path, model_dir: Path) -> list[FrameSource]:
    cameras = read_cameras_text(model_dir / "cameras.txt")
    image_dir = root / "images" if (root / "images").is_dir() else root
    sources = []
    for file_name, viewmat, cam_id in read_images_text(model_dir / "images.txt"):
        if cam_id not in cameras:
            raise InputError(f"images.txt: {file_name} uses camera {cam_id}, not in cameras.txt")
        k, width, height = cameras[cam_id]
        image_path = resolve_image_path(image_dir / file_name)
        actual = image_size(image_path)
        if actual != (width, height):
            raise InputError(
                f"{file_name}: cameras.txt says {width}x{height} but the image is "
                f"{actual[0]}x{actual[1]}"
            )
        name = Path(file_name).stem
        camera = Camera(viewmat, k, width, height)
        sources.append(FrameSource(name, camera, image_path, _mask_path(root, name, None)))
    if not sources:
        raise InputError(f"{model_dir / 'images.txt'} lists no images")
    sources.sort(key=lambda s: s.name)
    return sources


def load_colmap_text(path: str | Path) -> list[Frame]:
    """``scan_colmap_text`` with every frame read into memory."""
    return [s.load() for s in scan_colmap_text(path)]


# --- either ---------------------------------------------------------------------------------


def scan_dataset(path: str | Path) -> list[FrameSource]:
    """The views of a dataset: a directory with ``transforms.json`` or a COLMAP text model,
    or the ``.json`` file itself (e.g. ``transforms_test.json``)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"dataset not found: {p}")
    if p.is_file() or (p / "transforms.json").is_file():
        return scan_transforms_json(p)
    if find_model_dir(p) is not None:
        return scan_colmap_text(p)
    others = sorted(x.name for x in p.glob("transforms*.json"))
    hint = f" (found {', '.join(others)}: pass one of them)" if others else ""
    raise InputError(
        f"{p} is not a dataset: expected transforms.json or a COLMAP text model "
        f"(cameras.txt + images.txt, possibly under sparse/0){hint}"
    )


def load_dataset(path: str | Path) -> list[Frame]:
    """``scan_dataset`` with every frame read into memory."""
    return [s.load() for s in scan_dataset(path)]
