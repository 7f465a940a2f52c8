"""The models of a dataset's card: what each guided plant recorded in its ``run.json`` when
it was made (``models``: names, revisions and SHA-256 of every file it read, from
``guidance/model_files.py``), with the licence each model is known to carry.

Nothing is hashed here: a file retrained or replaced since a plant was made does not change
what the card says of that plant. A plant made before plantdreamer recorded its models is
named by its settings (a local folder by its own name, never a path) with no hash.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

# Licences known for hub models by id; any other model's licence is its own card's.
SD_LICENCE = {
    "name": "CreativeML Open RAIL++-M",
    "url": "https://huggingface.co/stabilityai/stable-diffusion-2-1-base/blob/main/LICENSE.md",
    "hub": "openrail++",  # the Hub's identifier of this licence
}
KNOWN_LICENCES = {"stabilityai/stable-diffusion-2-1-base": SD_LICENCE}
# The settings naming each model, by role (records before ``models``: their config's).
ROLE_SETTINGS = (
    ("base model", "base-model"),
    ("depth ControlNet", "controlnet"),
    ("species LoRA", "lora"),
)


def card_models(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each model the guided plants' ``records`` (their run.json) name, once per role,
    name and hash, with the number of plants made with it and its licence."""
    seen: dict[tuple[str, str, str | None], dict[str, Any]] = {}
    for record in records:
        for model in plant_models(record):
            key = (model["role"], model["name"], model["sha256"])
            if key in seen:
                seen[key]["plants"] += 1
            else:
                seen[key] = {**model, "plants": 1, "licence": KNOWN_LICENCES.get(model["name"])}
    return list(seen.values())


def plant_models(record: dict[str, Any]) -> list[dict[str, Any]]:
    """The models one plant's run.json says it read (role, name, source, revision, files,
    sha256); from its settings, without hashes, when it recorded none."""
    recorded = record.get("models")
    if isinstance(recorded, list):
        return [_checked(m) for m in recorded if isinstance(m, dict)]
    config = record.get("config")
    config = config if isinstance(config, dict) else {}
    out: list[dict[str, Any]] = []
    for role, name in ROLE_SETTINGS:
        value = recorded_setting(config, name)
        if value:
            named = _named(str(value), hub_allowed=role != "species LoRA")
            out.append({"role": role, **named, "revision": None, "files": [], "sha256": None})
    return out


def uses_stable_diffusion(models: list[dict[str, Any]]) -> bool:
    """Whether a base model of the card is Stable Diffusion 2.1 from the hub."""
    return any(m["role"] == "base model" and m.get("licence") is SD_LICENCE for m in models)


def _checked(model: dict[str, Any]) -> dict[str, Any]:
    """A recorded model's fields, each of the type the card writes (a record is a file a
    user may have edited: its strings are escaped where they are written)."""
    files = model.get("files")
    return {
        "role": str(model.get("role", "model")),
        "name": str(model.get("name", "unknown")),
        "source": str(model.get("source", "unknown")),
        "revision": None if model.get("revision") is None else str(model["revision"]),
        "files": [f for f in files if isinstance(f, dict)] if isinstance(files, list) else [],
        "sha256": None if model.get("sha256") is None else str(model["sha256"]),
    }


def _named(value: str, hub_allowed: bool) -> dict[str, str]:
    """A model setting as the card names it: a hub id as it is, a local path by its last
    part (the path of the machine that made the plant is not published)."""
    parts = value.split("/")
    hub_id = len(parts) == 2 and all(parts) and not value.startswith((".", "/", "~"))
    if hub_allowed and hub_id and not Path(value).exists():
        return {"name": value, "source": "hub"}
    return {"name": Path(value).name or value, "source": "local folder"}


def recorded_setting(config: dict[str, Any], name: str, section: str | None = "sds") -> Any:
    """A setting of a recorded config, by name, or under its section in records of the
    sectioned versions."""
    if name in config:
        return config[name]
    inner = config.get(section) if section else None
    return inner.get(name.replace("-", "_")) if isinstance(inner, dict) else None
