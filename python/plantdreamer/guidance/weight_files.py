"""Weight files opened far enough to know they will load, before a command deletes anything.

A name is not enough: a LoRA that is not safetensors, or a model whose weight file was cut
short by a failed copy, would pass a look at the folder and fail only when loaded, after
``--overwrite`` deleted the earlier run. Each file is checked from its header, without
reading its tensors:

- ``.safetensors``: the header is read and checked against the file's length (safetensors
  refuses a header that does not cover the file exactly: a cut or padded file);
- ``.bin`` (PyTorch's zip format): the zip's directory, read from the end of the file, and
  every member lying within the file; a ``.bin`` of the legacy format (a bare pickle) is
  checked for the pickle's opening bytes only.

A model folder's part (``unet/``, ``vae/``, ...) is checked for the files its loader
reads: the ``.safetensors`` files when it has any (diffusers prefers them), else the
``.bin`` files.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

__all__ = ["check_lora_weights", "damaged_model_files", "damaged_weights", "weight_problem"]

# The parts of a Stable Diffusion folder that hold weights (guidance.models' parts).
BASE_WEIGHT_PARTS = ("unet", "vae", "text_encoder")

WEIGHT_SUFFIXES = (".safetensors", ".bin")
_ZIP_LOCAL_HEADER = 30  # bytes of a zip member's fixed local header


def weight_problem(path: Path) -> str | None:
    """What is wrong with the weight file ``path`` (one phrase), or None if its header says
    it will load."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if size == 0:
        return "is empty"
    if path.suffix == ".safetensors":
        return _safetensors_problem(path)
    return _torch_file_problem(path, size)


def damaged_weights(folder: Path) -> list[str]:
    """``"<file>: <problem>"`` for each weight file of ``folder`` (a model's part) that
    would not load; the files checked are those its loader reads (see the docstring)."""
    if not folder.is_dir():
        return []
    files = sorted(p for p in folder.iterdir() if p.suffix in WEIGHT_SUFFIXES)
    safetensors = [p for p in files if p.suffix == ".safetensors"]
    problems = []
    for path in safetensors or files:
        problem = weight_problem(path)
        if problem is not None:
            problems.append(f"{path.parent.name}/{path.name} {problem}")
    return problems


def damaged_model_files(folder: Path, kind: str) -> list[str]:
    """The weight files of a base model (``kind`` "base": its unet, vae and text encoder)
    or a ControlNet folder that would not load (``damaged_weights``)."""
    if kind == "base":
        return [p for part in BASE_WEIGHT_PARTS for p in damaged_weights(folder / part)]
    return damaged_weights(folder)


def check_lora_weights(path: Path) -> None:
    """InputError unless ``path`` is a safetensors file whose header names LoRA weights
    only (what ``lora_weights.load_lora`` takes), checked without reading the tensors."""
    from plantdreamer.errors import InputError

    problem = weight_problem(path)
    if problem is not None:
        raise InputError(f"LoRA file {str(path)!r} {problem}")
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as opened:
        keys = list(opened.keys())
    if not keys:
        raise InputError(f"LoRA file {str(path)!r} holds no weights")
    other = next((k for k in keys if "lora" not in k), None)
    if other is not None:
        raise InputError(
            f"{str(path)!r} is not a LoRA file: key {other!r} does not name a LoRA weight"
        )


def _safetensors_problem(path: Path) -> str | None:
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(path), framework="numpy") as opened:
            opened.keys()
    except (SafetensorError, OSError, ValueError) as exc:
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return f"is not a whole safetensors file ({text})"
    return None


def _torch_file_problem(path: Path, size: int) -> str | None:
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.infolist()
    except zipfile.BadZipFile:
        with open(path, "rb") as f:
            head = f.read(2)
        if len(head) == 2 and head[0] == 0x80 and 2 <= head[1] <= 5:
            return None  # the legacy format: a pickle, checked by its opening bytes only
        return "is neither a PyTorch zip file (cut short?) nor a pickle"
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if not members:
        return "is an empty zip file"
    end = max(
        m.header_offset + _ZIP_LOCAL_HEADER + len(m.filename.encode()) + m.compress_size
        for m in members
    )
    if end > size:
        return f"is cut short ({size} bytes; its members need {end})"
    return None
