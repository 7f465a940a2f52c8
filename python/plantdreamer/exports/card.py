"""A dataset's card: what a folder of plants is, in ``DIR/README.md`` for people (with the
YAML block the Hugging Face Hub reads: ``card_metadata.py``) and in the ``card`` block of
``DIR/dataset.json`` for programs, written with the label files.

The card names the classes (ids, preview colours, what 0 and the ignore regions mean), the
plants per species and split, the plantdreamer version, the presets, the models the guided
plants were made with as each plant recorded them (``card_models.py``: a hub id or a
folder's name, the SHA-256 of the files read), their licences, the limitations of the data
and how to cite. Every user-given string (species, class and model names) is escaped where
it is written (``text_escape.py``; the YAML by its writer). Its date is the day the newest
plant finished (its ``run.json``), or ``SOURCE_DATE_EPOCH`` when set, so the same folder
gives the same bytes. The COCO files take their ``info`` and ``licenses`` from it
(``coco_info``). The card gives no address of its own (the project's is not known).

What the weights' licence means for generated data is summarised here once; it is a
summary, not legal advice.
"""

from __future__ import annotations

import datetime
import json
from collections import Counter
from pathlib import Path
from typing import Any

from plantdreamer import atomic
from plantdreamer.exports.card_metadata import card_metadata, without_metadata
from plantdreamer.exports.card_models import (
    SD_LICENCE,
    card_models,
    recorded_setting,
    uses_stable_diffusion,
)
from plantdreamer.exports.card_text import (
    CITATION,
    GUIDED_TERMS,
    RENDER_TERMS,
    SD_OUTPUT_TERMS,
    limitations,
    model_lines,
    plant_views,
)
from plantdreamer.exports.distributions import distributions, distributions_markdown
from plantdreamer.exports.listing import PlantEntry
from plantdreamer.source_date import source_date_epoch
from plantdreamer.text_escape import markdown_text as md

README_FILE = "README.md"
TITLE = "# A plantdreamer dataset"  # first after the YAML block: a README.md it may replace
SUMMARY_FILE = "dataset.json"  # the dataset's record (dataset/manifest.py writes the rest)
CARD_KEY = "card"
CODE_LICENCE = "Apache-2.0"
PAPER_URL = "https://arxiv.org/abs/2505.15528"
# The label previews' colours (pipeline/truth/dataset_export.py draws a plant's k-th class value in
# the k-th colour); the card gives each class the colour of its rank among the classes.
PREVIEW_COLOURS = (
    (31, 119, 180), (44, 160, 44), (140, 86, 75), (214, 39, 40), (148, 103, 189),
    (255, 127, 14), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)  # fmt: skip


def dataset_card(
    plants: list[PlantEntry],
    classes: dict[int, str],
    stuff: tuple[str, ...],
    splits: dict[str, list[str]],
    species: dict[str, dict[str, int]],
    min_area: int,
    images: dict[str, int],
    scenes: list[PlantEntry] | None = None,
    split_rule: str = "",
) -> dict[str, Any]:
    """The card of a dataset's finished ``plants`` and ``scenes`` (``classes``: category
    id -> name; ``species``: split -> species -> plants; ``images``: split -> labelled
    views; ``split_rule``: how the splits were made, a sentence)."""
    records = {p.id: _record(p.folder / "run.json") for p in plants}
    configs = {i: _config_of(r) for i, r in records.items()}
    guided = sorted(
        i for i, c in configs.items() if recorded_setting(c, "guidance", "sds") != "none"
    )
    models = card_models([records[i] for i in guided])
    sd = uses_stable_diffusion(models)
    return {
        "date": made_on([p.folder / "run.json" for p in plants]),
        "plantdreamer": _version(),
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
        "split_rule": split_rule,
        "presets": sorted(
            {str(recorded_setting(c, "preset", None) or "plantdreamer") for c in configs.values()}
        ),
        "guided_plants": len(guided),
        "models": models,
        "views": plant_views(list(configs.values())),
        "licences": {
            "code": CODE_LICENCE,
            # The images' licence as the Hub names it: SD 2.1's outputs carry its terms.
            "data": SD_LICENCE["hub"] if sd else "unknown",
            "images": " ".join(
                ([GUIDED_TERMS] if guided else [])
                + ([SD_OUTPUT_TERMS] if sd else [])
                + [RENDER_TERMS]
            ),
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
        "url": "",  # the dataset's own address is its publisher's to give
    }
    sd = card["licences"]["data"] == SD_LICENCE["hub"]
    guided = {"id": 1, "name": "outputs of the diffusion models the card lists", "url": ""}
    if sd:
        guided = {"id": 1, "name": f"{SD_LICENCE['name']} (Stable Diffusion 2.1 outputs)",
                  "url": SD_LICENCE["url"]}  # fmt: skip
    licenses = [guided, {"id": 2, "name": "renders without diffusion weights", "url": ""}]
    return info, licenses, {"sds": 1, "none": 2}


def plant_guidance(folder: Path) -> str:
    """``sds`` or ``none``: how a finished plant was trained (its run.json)."""
    return (
        "none"
        if recorded_setting(_config(folder / "run.json"), "guidance", "sds") == "none"
        else "sds"
    )


def write_card(dataset_dir: Path, card: dict[str, Any], into: Path | None = None) -> str | None:
    """``README.md`` and the ``card`` block of ``dataset.json`` (the rest of it kept), into
    ``into`` (a staging folder; default: the dataset folder). A README.md the card did not
    write is left as it is (none is written): the warning says so."""
    dataset_dir = Path(dataset_dir)
    target = Path(into) if into is not None else dataset_dir
    readme, warning = dataset_dir / README_FILE, None
    if readme.is_file() and not is_card(readme.read_text(errors="replace")):
        warning = f"{readme} is not a dataset card: left as it is (the card is in {SUMMARY_FILE})"
    else:
        atomic.write_text(target / README_FILE, card_markdown(card))
    path = dataset_dir / SUMMARY_FILE
    try:
        summary = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        summary = {}
    if not isinstance(summary, dict):
        summary = {}
    summary[CARD_KEY] = card
    atomic.write_text(target / SUMMARY_FILE, json.dumps(summary, indent=2, sort_keys=True) + "\n")
    return warning


def is_card(text: str) -> bool:
    """Whether a README.md is a card this module wrote (its title after the YAML block)."""
    return without_metadata(text).startswith(TITLE)


def card_markdown(card: dict[str, Any]) -> str:
    """The card as the folder's README.md: the Hub's YAML block, then the card for people
    (every user-given name escaped: ``md``)."""
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
        lines.append(f"| {c['id']} | {md(c['name'])} | {colour} | {kind} |")
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
        species = ", ".join(f"{n} {md(name)}" for name, n in row["species"].items()) or "-"
        lines.append(f"| {split} | {row['plants']} | {row['images']} | {species} |")
    total = ", ".join(f"{n} {md(name)}" for name, n in card["species"].items())
    presets = ", ".join(md(p) for p in card["presets"])
    lines += ["", f"All: {total}. Presets: {presets}."]
    if card.get("split_rule"):
        lines += ["", card["split_rule"]]
    lines += ["", *distributions_markdown(card), "## Models", ""]
    lines += model_lines(card["models"])
    lines += [
        "",
        f"{card['guided_plants']} of {sum(card['species'].values())} plants were trained with "
        "diffusion guidance.",
        "",
        "## Limitations",
        "",
        *limitations(card),
        "",
        "## Licences",
        "",
        f"- plantdreamer, the code that made this dataset: {card['licences']['code']}",
    ]
    for m in card["models"]:
        licence = m["licence"]
        named = f"[{licence['name']}]({licence['url']})" if licence else "as its own card states"
        lines.append(f"- {m['role']} {md(m['name'])}: {named}")
    lines += ["", card["licences"]["images"], "", "## Citation", "", "```bibtex",
              card["citation"], "```", ""]  # fmt: skip
    return card_metadata(card) + "\n".join(lines)


def made_on(records: list[Path]) -> str:
    """The card's date (YYYY-MM-DD, UTC): ``SOURCE_DATE_EPOCH`` when set, else the day
    the newest of ``records`` was written, else today."""
    epoch = source_date_epoch()  # InputError for a malformed value, checked up front too
    if epoch is not None:
        stamp = float(epoch)
    else:
        times = [p.stat().st_mtime for p in records if p.is_file()]
        stamp = max(times) if times else datetime.datetime.now(datetime.timezone.utc).timestamp()
    return datetime.datetime.fromtimestamp(stamp, datetime.timezone.utc).strftime("%Y-%m-%d")


def _version() -> str:
    from plantdreamer import __version__

    return __version__


def _record(run_json: Path) -> dict[str, Any]:
    """A plant's run.json ({} when it cannot be read)."""
    try:
        record = json.loads(run_json.read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def _config_of(record: dict[str, Any]) -> dict[str, Any]:
    config = record.get("config", {})
    return config if isinstance(config, dict) else {}


def _config(run_json: Path) -> dict[str, Any]:
    return _config_of(_record(run_json))
