"""The YAML block at the top of a dataset's ``README.md``, which the Hugging Face Hub reads
(``huggingface_hub.DatasetCard.load``): made with huggingface_hub's own card classes, so its
keys are the Hub's and its strings are quoted by its YAML writer.

- ``license``: the licence of the images: ``openrail++`` when Stable Diffusion 2.1 from the
  hub guided a plant (its outputs carry the licence's use restrictions), else ``unknown``
  (renders of procedural plants or scans, or other models: the maker's to choose; the
  card's text says which);
- ``task_categories`` / ``task_ids``: segmentation (instances and classes), detection,
  depth; ``size_categories``: the Hub's bucket of the number of labelled views;
- ``pretty_name``; ``configs``: one ``default`` config whose splits are the YOLO images of
  each split that has any (the files a viewer can show).
"""

from __future__ import annotations

from typing import Any

from plantdreamer.text_escape import one_line

TASK_CATEGORIES = ["image-segmentation", "object-detection", "depth-estimation"]
TASK_IDS = ["instance-segmentation", "semantic-segmentation"]
TAGS = ["plants", "plant-phenotyping", "synthetic", "3d-gaussian-splatting", "plantdreamer"]
# The Hub's size categories: upper bounds (exclusive) and names.
SIZE_CATEGORIES = (
    (1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"),
    (1_000_000, "100K<n<1M"), (10_000_000, "1M<n<10M"), (100_000_000, "10M<n<100M"),
)  # fmt: skip


def size_category(images: int) -> str:
    """The Hub's size category of a dataset of ``images`` items."""
    for bound, name in SIZE_CATEGORIES:
        if images < bound:
            return name
    return "n>100M"


def card_metadata(card: dict[str, Any]) -> str:
    """The YAML block (between ``---`` lines) of ``card`` (``exports.card.dataset_card``)."""
    from huggingface_hub import DatasetCardData

    images = sum(row["images"] for row in card["splits"].values())
    species = ", ".join(card["species"]) or "none"
    data = DatasetCardData(
        license=card["licences"]["data"],
        pretty_name=one_line(f"plantdreamer synthetic plants ({species})")[:200],
        task_categories=TASK_CATEGORIES,
        task_ids=TASK_IDS,
        size_categories=[size_category(images)],
        annotations_creators=["machine-generated"],
        tags=TAGS,
        configs=[
            {
                "config_name": "default",
                "data_files": [
                    {"split": split, "path": f"yolo/images/{split}/*.png"}
                    for split, row in card["splits"].items()
                    if row["images"]
                ],
            }
        ],
    )
    return f"---\n{data.to_yaml()}\n---\n"


def without_metadata(text: str) -> str:
    """A README's text after its YAML block, if it has one."""
    if text.startswith("---\n"):
        end = text.find("\n---\n", 4)
        if end >= 0:
            return text[end + len("\n---\n") :]
    return text
