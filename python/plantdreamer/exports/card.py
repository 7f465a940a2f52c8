"""A dataset's card: what a folder of plants is, in ``DIR/README.md`` for people and in the
``card`` block of ``DIR/dataset.json`` for programs, written with the label files.

The card names the classes (ids, preview colours, what 0 and the ignore regions mean), the
plants per species and split, the plantdreamer version, the presets and the models each
plant was made with (hub id or folder, and a hash: the hub snapshot's commit, or SHA-256 of
a local file), the licences and how to cite. Its date is the day the newest plant finished
(its ``run.json``), or ``SOURCE_DATE_EPOCH`` when set, so the same folder gives the same
bytes. The COCO files take their ``info`` and ``licenses`` from it (``coco_info``).

What the weights' licence means for generated data is summarised here once; it is a
summary, not legal advice.
"""

from __future__ import annotations

import datetime
import hashlib
import importlib.metadata
import json
import os
from collections import Counter
from pathlib import Path
from typing import Any

from plantdreamer import atomic
from plantdreamer.digests import file_digest
from plantdreamer.exports.distributions import distributions, distributions_markdown
from plantdreamer.exports.listing import PlantEntry

README_FILE = "README.md"
TITLE = "# A plantdreamer dataset"  # the card's first line: a README.md it may replace
SUMMARY_FILE = "dataset.json"  # the dataset's record (dataset/manifest.py writes the rest)
CARD_KEY = "card"
CODE_LICENCE = "Apache-2.0"
PAPER_URL = "https://arxiv.org/abs/2505.15528"
SD_LICENCE = {
    "name": "CreativeML Open RAIL++-M",
    "url": "https://huggingface.co/stabilityai/stable-diffusion-2-1-base/blob/main/LICENSE.md",
}
SD_OUTPUT_TERMS = (
    "The images of plants trained with diffusion guidance are outputs of Stable Diffusion "
    "2.1 (with a depth ControlNet and any species LoRA). Its weights are licensed under the "
    "CreativeML Open RAIL++-M licence, which claims no rights in the outputs you generate but "
    "makes you accountable for them and their use: no use of them may break the use-based "
    "restrictions of the licence's Attachment A, and whoever shares the weights (or a model "
    "derived from them) passes those restrictions on. The ControlNet and LoRA weights carry "
    "their own licences (see their model cards). A summary, not legal advice."
)
RENDER_TERMS = (
    "Plants made without diffusion guidance are renders of the procedural plants or point "
    "clouds alone: no model weights went into them."
)
CITATION = """@inproceedings{hartley2025plantdreamer,
  title     = {PlantDreamer: Achieving Realistic 3D Plant Models with Diffusion-Guided Gaussian Splatting},
  author    = {Hartley, Zane K. J. and Stuart, Lewis A. G. and French, Andrew P. and Pound, Michael P.},
  booktitle = {Proceedings of the IEEE/CVF International Conference on Computer Vision (ICCV)},
  year      = {2025},
  eprint    = {2505.15528},
  archivePrefix = {arXiv}
}"""
# The label previews' colours (pipeline/dataset_export.py draws a plant's k-th class value in
# the k-th colour); the card gives each class the colour of its rank among the classes.
PREVIEW_COLOURS = (
    (31, 119, 180), (44, 160, 44), (140, 86, 75), (214, 39, 40), (148, 103, 189),
    (255, 127, 14), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)  # fmt: skip
# The models a plant's record names, by setting: (role, setting, file a hub snapshot holds).
_MODELS = (
    ("base model", "base-model", "model_index.json"),
    ("depth ControlNet", "controlnet", "config.json"),
)


def dataset_card(
    plants: list[PlantEntry],
    classes: dict[int, str],
    stuff: tuple[str, ...],
    splits: dict[str, list[str]],
    species: dict[str, dict[str, int]],
    min_area: int,
    images: dict[str, int],
    scenes: list[PlantEntry] | None = None,
) -> dict[str, Any]:
    """The card of a dataset's finished ``plants`` and ``scenes`` (``classes``: category
    id -> name; ``species``: split -> species -> plants; ``images``: split -> labelled
    views)."""
    configs = {p.id: _config(p.folder / "run.json") for p in plants}
    guided = sorted(i for i, c in configs.items() if _setting(c, "guidance", "sds") != "none")
    return {
        "date": made_on([p.folder / "run.json" for p in plants]),
        "plantdreamer": _version(),
        "url": project_url(),
        "classes": [
            {
                "id": i,
                "name": name,
                "colour": list(PREVIEW_COLOURS[k % len(PREVIEW_COLOURS)]),
                "object": name not in stuff,
            }
            for k, (i, name) in enumerate(sorted(classes.items()))
        ],
        "background": 0,
        "ignore_regions": (
            f"objects of fewer than {min_area} pixels: COCO iscrowd 1, left out of the YOLO "
            "labels and of PlantViews' targets, whose 'ignore' mask holds their pixels"
        ),
        "species": dict(sorted(Counter(p.species for p in plants).items())),
        "splits": {
            s: {"plants": len(ids), "images": images.get(s, 0), "species": species.get(s, {})}
            for s, ids in splits.items()
        },
        "presets": sorted(
            {str(_setting(c, "preset", None) or "plantdreamer") for c in configs.values()}
        ),
        "guided_plants": len(guided),
        "models": _models([configs[i] for i in guided]),
        "licences": {
            "code": CODE_LICENCE,
            "weights": SD_LICENCE if guided else None,
            "images": " ".join(([SD_OUTPUT_TERMS] if guided else []) + [RENDER_TERMS]),
        },
        "citation": CITATION,
        "paper": PAPER_URL,
        "distributions": distributions(configs, scenes or []),  # the views, the scenes
    }


def coco_info(card: dict[str, Any]) -> tuple[dict[str, Any], list[dict[str, Any]], dict[str, int]]:
    """A COCO file's ``info`` fields, its ``licenses`` and the licence id of a plant's images
    by guidance (``"sds"`` / ``"none"``)."""
    info = {
        "version": card["plantdreamer"],
        "year": int(card["date"][:4]),
        "date_created": card["date"],
        "contributor": "plantdreamer",
        "url": card["url"] or card["paper"],
    }
    licenses = [
        {"id": 1, "name": f"{SD_LICENCE['name']} (Stable Diffusion 2.1 outputs)",
         "url": SD_LICENCE["url"]},
        {"id": 2, "name": "renders without diffusion weights", "url": card["url"] or ""},
    ]  # fmt: skip
    return info, licenses, {"sds": 1, "none": 2}


def plant_guidance(folder: Path) -> str:
    """``sds`` or ``none``: how a finished plant was trained (its run.json)."""
    return "none" if _setting(_config(folder / "run.json"), "guidance", "sds") == "none" else "sds"


def write_card(dataset_dir: Path, card: dict[str, Any]) -> str | None:
    """``README.md`` and the ``card`` block of ``dataset.json`` (the rest of it kept). A
    README.md the card did not write is left as it is: the warning says so."""
    dataset_dir = Path(dataset_dir)
    readme, warning = dataset_dir / README_FILE, None
    if readme.is_file() and not readme.read_text(errors="replace").startswith(TITLE):
        warning = f"{readme} is not a dataset card: left as it is (the card is in {SUMMARY_FILE})"
    else:
        atomic.write_text(readme, card_markdown(card))
    path = dataset_dir / SUMMARY_FILE
    try:
        summary = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        summary = {}
    if not isinstance(summary, dict):
        summary = {}
    summary[CARD_KEY] = card
    atomic.write_text(path, json.dumps(summary, indent=2, sort_keys=True) + "\n")
    return warning


def card_markdown(card: dict[str, Any]) -> str:
    """The card as the folder's README.md."""
    lines = [
        TITLE,
        "",
        f"Synthetic plants made with plantdreamer {card['plantdreamer']} on {card['date']}: "
        "3D Gaussian Splatting plants (`plants/<id>/plant.ply`), their renders and per-pixel "
        f"labels, split by plant into train, val and test. Method: PlantDreamer ({card['paper']}).",
        "",
        "## Files",
        "",
        "- `plants/<id>/`: one folder per plant (`renders/`, `labels/`, `instances/`, "
        "`depth/`, `transforms.json`, `run.json` with every setting)",
        "- `coco/{train,val,test}.json`: COCO instance segmentation (file names relative to "
        "this folder)",
        "- `yolo/data.yaml`, `yolo/images/`, `yolo/labels/`: YOLO-seg",
        "- `splits.json`, `manifest.jsonl`, `dataset.json` (this card under `card`), `gallery.png`",
        '- in Python: `plantdreamer.data.PlantViews("<this folder>", split="train")`',
        "",
        "## Classes",
        "",
        "| id | name | preview colour | object |",
        "|---:|---|---|---|",
    ]
    for c in card["classes"]:
        colour = "#{:02x}{:02x}{:02x}".format(*c["colour"])
        kind = "yes" if c["object"] else "no (stuff: class maps only)"
        lines.append(f"| {c['id']} | {c['name']} | {colour} | {kind} |")
    lines += [
        "",
        "Class id 0 is background: pixels that show no labelled part of the plant. Ignore "
        f"regions are {card['ignore_regions']}. Preview colours are those of `labels/preview/` "
        "and `gallery.png` for a plant that has every class.",
        "",
        "## Plants",
        "",
        "| split | plants | images | species |",
        "|---|---:|---:|---|",
    ]
    for split, row in card["splits"].items():
        species = ", ".join(f"{n} {name}" for name, n in row["species"].items()) or "-"
        lines.append(f"| {split} | {row['plants']} | {row['images']} | {species} |")
    total = ", ".join(f"{n} {name}" for name, n in card["species"].items())
    lines += ["", f"All: {total}. Presets: {', '.join(card['presets'])}.", ""]
    lines += [*distributions_markdown(card), "## Models", ""]
    if card["models"]:
        for m in card["models"]:
            lines.append(f"- {m['role']}: `{m['id']}` ({m['hash'] or 'hash unknown here'})")
    else:
        lines.append("- none: every plant was made without diffusion guidance")
    lines += [
        "",
        f"{card['guided_plants']} of {sum(card['species'].values())} plants were trained with "
        "diffusion guidance.",
        "",
        "## Licences",
        "",
        f"- plantdreamer, the code that made this dataset: {card['licences']['code']}",
    ]
    if card["licences"]["weights"]:
        w = card["licences"]["weights"]
        lines.append(f"- Stable Diffusion 2.1 weights: [{w['name']}]({w['url']})")
    lines += ["", card["licences"]["images"], "", "## Citation", "", "```bibtex",
              card["citation"], "```", ""]  # fmt: skip
    return "\n".join(lines)


def made_on(records: list[Path]) -> str:
    """The card's date (YYYY-MM-DD, UTC): ``SOURCE_DATE_EPOCH`` when set, else the day
    the newest of ``records`` was written, else today."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch is not None and epoch.strip().isdigit():
        stamp = float(epoch)
    else:
        times = [p.stat().st_mtime for p in records if p.is_file()]
        stamp = max(times) if times else datetime.datetime.now(datetime.timezone.utc).timestamp()
    return datetime.datetime.fromtimestamp(stamp, datetime.timezone.utc).strftime("%Y-%m-%d")


def project_url() -> str | None:
    """The project's home page from the installed package's metadata (None without one)."""
    try:
        meta = importlib.metadata.metadata("plantdreamer")
    except importlib.metadata.PackageNotFoundError:
        return None
    urls = [u.split(",", 1)[-1].strip() for u in meta.get_all("Project-URL") or []]
    return meta["Home-page"] or (urls[0] if urls else None)


def _version() -> str:
    from plantdreamer import __version__

    return __version__


def _config(run_json: Path) -> dict[str, Any]:
    try:
        config = json.loads(run_json.read_text()).get("config", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return config if isinstance(config, dict) else {}


def _setting(config: dict[str, Any], name: str, section: str | None) -> Any:
    """A setting of a recorded config, by name, or under its section in records of the
    sectioned versions."""
    if name in config:
        return config[name]
    inner = config.get(section) if section else None
    return inner.get(name.replace("-", "_")) if isinstance(inner, dict) else None


def _models(configs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each model the guided plants name, once, with its hash."""
    seen: dict[tuple[str, str], dict[str, Any]] = {}
    for config in configs:
        for role, name, marker in _MODELS:
            ident = _setting(config, name, "sds")
            if ident and (role, ident) not in seen:
                seen[(role, ident)] = {
                    "role": role,
                    "id": ident,
                    "hash": _model_hash(ident, marker),
                }
        lora = _setting(config, "lora", "sds")
        if lora and ("species LoRA", lora) not in seen:
            seen[("species LoRA", lora)] = {"role": "species LoRA", "id": lora,
                                            "hash": _lora_hash(lora)}  # fmt: skip
    return list(seen.values())


def _model_hash(ident: str, marker: str) -> str | None:
    """A local folder's SHA-256 over its weight files, or a hub snapshot's commit."""
    folder = Path(ident)
    if folder.is_dir():
        digest = hashlib.sha256()
        for path in sorted(folder.rglob("*")):
            if path.suffix in (".safetensors", ".bin") and path.is_file():
                digest.update(path.relative_to(folder).as_posix().encode() + b"\0")
                digest.update(file_digest(path).encode())
        return "sha256:" + digest.hexdigest()
    try:
        from huggingface_hub import try_to_load_from_cache

        found = try_to_load_from_cache(ident, marker)
    except Exception:  # not a hub id, or no cache here: the hash is unknown
        return None
    if isinstance(found, str):
        return "commit:" + Path(found).parent.name
    return None


def _lora_hash(lora: str) -> str | None:
    from plantdreamer.guidance.lora_weights import LORA_WEIGHT_NAME

    path = Path(lora)
    if path.is_dir():
        path = path / LORA_WEIGHT_NAME
    return "sha256:" + file_digest(path) if path.is_file() else None
