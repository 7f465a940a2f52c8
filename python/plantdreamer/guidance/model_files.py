"""What a run read of its models: the files of the base model's parts, the depth
ControlNet and the species LoRA, each with its SHA-256, for ``run.json``'s ``models``.

A run records them when it is made (``pipeline/export.py``), so a dataset's card reads what
each plant was trained with, never what the paths hold later. The files are those the
loaders read with plantdreamer's settings (no variant; safetensors where a folder has
them, else ``.bin``; the configs and tokenizer files beside them). A model is named by
its hub id (with the snapshot's commit) or by its folder's name: never by a path of the
machine that made it.

Hashes cost nothing for files of the Hugging Face cache (a weight file's blob is named by
its SHA-256) or of a folder made by ``hf download --local-dir`` (huggingface_hub records
the SHA-256 it downloaded, valid while the file is not newer than that record); any other
file is read once per process while unchanged (``digests.cached_file_digest``).
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from plantdreamer.digests import cached_file_digest
from plantdreamer.errors import PlantDreamerError

# The parts of a Stable Diffusion folder the loaders read (guidance/models.py).
BASE_PARTS = ("unet", "vae", "text_encoder", "tokenizer", "scheduler")
# The file whose cached copy finds a hub model's snapshot, and where the snapshot is from it.
_MARKERS = {"base model": ("unet/config.json", 2), "depth ControlNet": ("config.json", 1)}
_WEIGHTS = (".safetensors", ".bin")
_CONFIGS = (".json", ".txt")
_SHA256 = re.compile(r"[0-9a-f]{64}")


def run_models(sds: Any) -> list[dict[str, Any]]:
    """``model_files_record`` of a run's guidance settings (``SdsConfig``); none for a run
    without guidance, which reads no model."""
    if sds.guidance == "none":
        return []
    return model_files_record(sds.base_model, sds.controlnet, sds.lora)


def model_files_record(base_model: str, controlnet: str, lora: str | None) -> list[dict[str, Any]]:
    """The ``models`` entry of a guided run's ``run.json``: per model its role, name,
    source (``hub`` or ``local folder``), hub revision, files (path inside the model,
    bytes, sha256) and one SHA-256 over them all."""
    records = [
        _readable(
            "base model", base_model, lambda: _folder_model("base model", base_model, BASE_PARTS)
        ),
        _readable(
            "depth ControlNet",
            controlnet,
            lambda: _folder_model("depth ControlNet", controlnet, ("",)),
        ),
    ]
    if lora:
        records.append(_readable("species LoRA", lora, lambda: _lora_model(lora)))
    return records


def _readable(role: str, ident: str, record: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """``record()``, or, when the model cannot be read now (a LoRA deleted during the run),
    a record that says so: a finished run is written whatever its record can hold."""
    try:
        return record()
    except (OSError, PlantDreamerError) as exc:
        named = _folder_name(ident) if Path(ident).exists() or role == "species LoRA" else ident
        entry = _record(role, named, "unknown", None, [])
        entry["error"] = " ".join(str(exc).split())[:300]
        return entry


def _folder_model(role: str, ident: str, parts: tuple[str, ...]) -> dict[str, Any]:
    folder, revision = _local_folder(role, ident)
    source = "local folder" if Path(ident).is_dir() else "hub"
    files: list[dict[str, Any]] = []
    if folder is not None:
        for part in parts:
            for path in read_files(folder / part if part else folder):
                files.append(_file_entry(path, folder))
    name = _folder_name(ident) if source == "local folder" else ident
    return _record(role, name, source, revision, files)


def _lora_model(lora: str) -> dict[str, Any]:
    from plantdreamer.guidance.lora_weights import find_lora_file

    weights = find_lora_file(lora)
    folder = weights.parent
    paths = [weights] + [p for p in [folder / "lora.json"] if p.is_file()]
    files = [_file_entry(p, folder) for p in paths]
    given = Path(lora)
    name = (
        f"{_folder_name(str(given.parent))}/{given.name}" if given.is_file() else _folder_name(lora)
    )
    return _record("species LoRA", name, "local folder", None, files)


def _record(
    role: str, name: str, source: str, revision: str | None, files: list[dict[str, Any]]
) -> dict[str, Any]:
    return {
        "role": role,
        "name": name,
        "source": source,
        "revision": revision,
        "files": files,
        "sha256": combined_digest(files) if files else None,
    }


def combined_digest(files: list[dict[str, Any]]) -> str:
    """One SHA-256 for a model: over each file's path and SHA-256, in path order."""
    digest = hashlib.sha256()
    for f in sorted(files, key=lambda f: f["path"]):
        digest.update(f"{f['path']}\0{f['sha256']}\n".encode())
    return digest.hexdigest()


def read_files(folder: Path) -> list[Path]:
    """The files of one model folder the loaders read: its configs and tokenizer files,
    and its weights without a variant (``name.fp16.safetensors`` is one), safetensors
    where there are any, else ``.bin`` (with the index of sharded weights)."""
    if not folder.is_dir():
        return []
    files = sorted(p for p in folder.iterdir() if p.is_file())
    weights = [p for p in files if p.suffix in _WEIGHTS and "." not in p.stem]
    chosen = ".safetensors" if any(p.suffix == ".safetensors" for p in weights) else ".bin"
    kept = [p for p in weights if p.suffix == chosen]
    for p in files:
        if p.suffix not in _CONFIGS:
            continue
        if p.name.endswith(".index.json"):  # kept only for the weights chosen
            stem = p.name.removesuffix(".index.json")
            if not (stem.endswith(chosen) and "." not in stem.removesuffix(chosen)):
                continue
        kept.append(p)
    return sorted(kept)


def _file_entry(path: Path, folder: Path) -> dict[str, Any]:
    return {
        "path": path.relative_to(folder).as_posix(),
        "bytes": path.stat().st_size,
        "sha256": file_sha256(path, folder),
    }


def file_sha256(path: Path, folder: Path) -> str:
    """A model file's SHA-256: the hub's for a cached blob or a ``--local-dir`` download,
    else read from the file (once per process while it is unchanged)."""
    real = path.resolve()
    if real.parent.name == "blobs" and _SHA256.fullmatch(real.name):
        return real.name
    recorded = _downloaded_sha256(path, folder)
    return recorded if recorded is not None else cached_file_digest(path)


def _downloaded_sha256(path: Path, folder: Path) -> str | None:
    """The SHA-256 ``hf download --local-dir`` recorded for ``path`` (its etag, for files
    stored in LFS), if the file is not newer than the record; read-only."""
    relative = path.relative_to(folder).as_posix()
    meta = folder / ".cache" / "huggingface" / "download" / f"{relative}.metadata"
    try:
        _commit, etag, stamp = meta.read_text().splitlines()[:3]
        if _SHA256.fullmatch(etag.strip()) and path.stat().st_mtime - 1 <= float(stamp):
            return etag.strip()
    except (OSError, ValueError):
        pass
    return None


def _local_folder(role: str, ident: str) -> tuple[Path | None, str | None]:
    """Where a model's files are (a local folder, or its snapshot in the hub cache) and
    the snapshot's commit; (None, None) when the cache does not hold it."""
    if Path(ident).is_dir():
        return Path(ident), None
    marker, depth = _MARKERS[role]
    try:
        from huggingface_hub import try_to_load_from_cache

        found = try_to_load_from_cache(ident, marker)
    except Exception:  # not a hub id, or no cache here: nothing to list
        return None, None
    if not isinstance(found, str):
        return None, None
    snapshot = Path(found).parents[depth - 1]
    return snapshot, snapshot.name


def _folder_name(path: str) -> str:
    """A local model's name: its folder's (or file's) own name, never the path to it."""
    return Path(path).resolve().name
