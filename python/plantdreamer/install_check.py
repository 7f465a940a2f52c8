"""What ``plantdreamer info --check`` looks for: the diffusion weights (a local folder, or the
Hugging Face cache; nothing is downloaded; each weight file's header read, so a file cut
short is "damaged", not "present"), species LoRAs (their headers too), and the optional
extras of the installed package's metadata. Each check gives (found, one line saying what
and where)."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

# Extras for the people who build plantdreamer, not for its users.
_BUILDER_EXTRAS = ("dev", "bench")


def model_row(ident: str, kind: str) -> tuple[bool, str]:
    """A base model (``kind`` "base") or ControlNet ("controlnet") by hub id or folder."""
    from plantdreamer.guidance.models import (
        MODEL_MARKERS,
        missing_base_parts,
        missing_controlnet_parts,
    )
    from plantdreamer.guidance.weight_files import damaged_model_files

    missing_parts = missing_base_parts if kind == "base" else missing_controlnet_parts
    folder = Path(ident)
    where = f"folder {ident}"
    if not folder.is_dir():
        snapshot = _cached_snapshot(ident, MODEL_MARKERS[kind])
        if snapshot is None:
            option = "--base-model" if kind == "base" else "--controlnet"
            return False, (
                f"missing: {ident} is no folder here and not in the Hugging Face cache "
                f"(`hf download {ident}` on a machine online, or {option} FOLDER)"
            )
        folder, where = snapshot, f"{ident} in the Hugging Face cache ({snapshot.name[:12]})"
    missing = missing_parts(folder)
    if missing:
        return False, f"incomplete: {where} lacks {', '.join(missing)}"
    damaged = damaged_model_files(folder, kind)  # each weight file's header read
    if damaged:
        return False, f"damaged: {where}: {'; '.join(damaged)}"
    return True, f"present: {where}"


def lora_row(path: str | None) -> tuple[bool, str]:
    """A species LoRA (None: none given, nothing to check)."""
    if path is None:
        return True, (
            "none given (--lora PATH checks one; the authors' are lora/<species>/ in their "
            "code release, and `plantdreamer lora train` makes one)"
        )
    from plantdreamer.errors import PlantDreamerError
    from plantdreamer.guidance.lora_weights import find_lora_file
    from plantdreamer.guidance.weight_files import check_lora_weights

    try:
        found = find_lora_file(path)
    except PlantDreamerError as exc:
        return False, f"missing: {exc}"
    try:
        check_lora_weights(found)  # its header read: it will load
    except PlantDreamerError as exc:
        return False, f"damaged: {exc}"
    return True, f"present: {found}"


def extra_rows() -> dict[str, str]:
    """One row per optional extra of the installed package: present, or what is missing
    and the command that installs it."""
    from packaging.requirements import Requirement

    try:
        requires = importlib.metadata.requires("plantdreamer") or []
        extras = importlib.metadata.metadata("plantdreamer").get_all("Provides-Extra") or []
    except importlib.metadata.PackageNotFoundError:
        return {"extras": "unknown (plantdreamer is not installed as a package)"}
    rows = {}
    for extra in extras:
        if extra in _BUILDER_EXTRAS:
            continue
        needed = [
            r for r in map(Requirement, requires)
            if r.marker is not None and r.marker.evaluate({"extra": extra})
            and r.name != "plantdreamer"
        ]  # fmt: skip
        absent = [r.name for r in needed if _version(r.name) is None]
        if absent:
            rows[f"extra [{extra}]"] = (
                f"missing {', '.join(absent)}: pip install 'plantdreamer[{extra}]'"
            )
        else:
            have = ", ".join(f"{r.name} {_version(r.name)}" for r in needed)
            rows[f"extra [{extra}]"] = f"present ({have})"
    return rows


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def _cached_snapshot(repo_id: str, marker: str) -> Path | None:
    """The folder of the cached snapshot of ``repo_id`` that holds ``marker``, if any."""
    try:
        from huggingface_hub import try_to_load_from_cache

        found = try_to_load_from_cache(repo_id, marker)
    except Exception:  # not a valid hub id: not in the cache
        return None
    if not isinstance(found, str):
        return None
    path = Path(found)
    return path.parents[len(Path(marker).parts) - 1]
