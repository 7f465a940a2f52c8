"""The label files of a whole dataset folder (``DIR/plants/<id>/``), split by plant:

- ``splits.json``: the seed, the ratios, the mode, the plant ids of each split and the
  number of plants of each species in it (``exports.splits``, ``exports.exact_splits``);
- ``coco/{train,val,test}.json``: COCO files whose ``file_name`` is relative to ``DIR``
  (``plants/<id>/renders/view_000.png``); image and annotation ids are unique across the
  three files, so they merge as they are, and the image ids are the torch Dataset's
  (``dataset_views``); each image carries its view's traits (``exports.figures``);
- ``counts/{train,val,test}.csv``: each view's visible leaves and plant size, a row per
  image; ``traits/{train,val,test}.csv`` and ``traits/<split>_leaves.csv``: each plant's
  and each leaf's traits from its traits.json (``traits.counts``);
- ``yolo/images/<split>/<id>__view_000.png`` (hard links to the renders),
  ``yolo/labels/<split>/<id>__view_000.txt`` and ``yolo/data.yaml``;
- ``gallery.png``, the contact sheet (``exports.gallery``);
- ``README.md`` and the ``card`` of ``dataset.json``: the dataset's card (``exports.card``),
  which also fills the COCO files' ``info`` and ``licenses``.

These are the files the exports own in ``DIR`` (``DATASET_EXPORTS``; ``output_folder``):
they are built in a staging folder beside them and moved in only when all are complete, so
a failed export (an unreadable view) leaves the previous one whole, and a process killed
while they move in leaves ``export.incomplete``, which ``PlantViews`` refuses
(``dataset_files``); a ``yolo/`` or ``coco/`` that holds anything else, or is a link, and
any of these files in a folder that holds no dataset's record, are refused before
anything is written. The caller holds the folder's lock (``dataset``, ``labels``).

The plants are those ``exports.listing`` finds finished; its finished scenes
(``DIR/scenes/<id>/``) join the split they were made for (``splits.json``'s ``scenes``),
their views numbered after every plant's. Categories are keyed by class name across plants (``exports.classes``). Nothing is written inside a plant
folder that lies outside ``DIR`` (a link to another dataset's plant): its views are read,
its own label files left as they are.
"""

from __future__ import annotations

import itertools
import json
import re
import shutil
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer import atomic
from plantdreamer.errors import InputError
from plantdreamer.exports import yolo
from plantdreamer.exports.card import (
    README_FILE,
    SUMMARY_FILE,
    coco_info,
    dataset_card,
    plant_guidance,
    write_card,
)
from plantdreamer.exports.classes import DatasetClasses, check_stuff, dataset_classes
from plantdreamer.exports.coco import CocoBuilder
from plantdreamer.exports.dataset_files import INCOMPLETE, check_top_files, swap_in
from plantdreamer.exports.exact_splits import make_splits, split_rule
from plantdreamer.exports.figures import plant_records, read_view_traits
from plantdreamer.exports.gallery import GALLERY_FILE, write_gallery
from plantdreamer.exports.instances import MIN_INSTANCE_AREA, PlantClasses, labelled_frames
from plantdreamer.exports.listing import (
    PLANTS_DIR,
    PlantEntry,
    finished_plants,
    finished_scenes,
    scene_record,
)
from plantdreamer.exports.plant import COCO_FILE, LabelReport, write_plant_exports
from plantdreamer.exports.splits import (
    DEFAULT_MODE,
    DEFAULT_RATIOS,
    DEFAULT_SEED,
    SPLIT_MODES,
    SPLITS,
    check_splits,
    species_counts,
    species_gaps,
)
from plantdreamer.output_folder import remove_temporaries, survey, tree
from plantdreamer.source_date import source_date_epoch
from plantdreamer.traits import TRAITS_FILE, read_traits
from plantdreamer.traits.counts import (
    COUNTS_DIR,
    LEAF_COLUMNS,
    PLANT_COLUMNS,
    TRAITS_DIR,
    leaf_rows,
    plant_row,
    write_counts,
    write_table,
)

SPLITS_FILE = "splits.json"
_SPLIT = "(?:" + "|".join(SPLITS) + ")"
_VIEW = r"[^/]+__view_\d{3,}"  # <plant id>__<view>: a plant's view, flattened
# What the exports write in a dataset folder (output_folder.Owned).
DATASET_EXPORTS = (
    SPLITS_FILE,
    GALLERY_FILE,
    INCOMPLETE,
    *tree("coco", re.compile(rf"{_SPLIT}\.json")),
    *tree(COUNTS_DIR, re.compile(rf"{_SPLIT}\.csv")),
    *tree(TRAITS_DIR, re.compile(rf"{_SPLIT}(?:_leaves)?\.csv")),
    *tree(
        "yolo",
        "data.yaml",
        *tree("images", *(f"{s}/" for s in SPLITS), re.compile(rf"{_SPLIT}/{_VIEW}\.png")),
        *tree("labels", *(f"{s}/" for s in SPLITS), re.compile(rf"{_SPLIT}/{_VIEW}\.txt")),
    ),
)
EXPORT_ENTRIES = (SPLITS_FILE, "coco", COUNTS_DIR, TRAITS_DIR, "yolo", GALLERY_FILE)  # together
CARD_ENTRIES = (README_FILE, SUMMARY_FILE)  # with them, when the card writes them
# Every top-level entry the exports write: a user's, unless the folder holds a dataset.
TOP_ENTRIES = (*EXPORT_ENTRIES, SUMMARY_FILE, INCOMPLETE)


@dataclass(frozen=True)
class LabelOptions:
    """How a dataset's label files are made (the options of ``dataset`` and ``labels``)."""

    ratios: tuple[float, float, float] = DEFAULT_RATIOS
    seed: int = DEFAULT_SEED
    min_area: int = MIN_INSTANCE_AREA
    allow_empty_split: bool = False
    stuff: tuple[str, ...] = ()  # class names that are no objects (``exports.classes``)
    mode: str = DEFAULT_MODE  # each plant draws its split, or exact counts (``SPLIT_MODES``)

    def __post_init__(self) -> None:
        if self.mode not in SPLIT_MODES:
            raise InputError(
                f"split mode must be one of {', '.join(SPLIT_MODES)}, got {self.mode!r}"
            )


@dataclass(frozen=True)
class DatasetLabels:
    splits: dict[str, list[str]]
    report: LabelReport
    gallery: Path
    min_area: int = MIN_INSTANCE_AREA
    species: dict[str, dict[str, int]] = field(default_factory=dict)  # split -> species -> n
    warnings: list[str] = field(default_factory=list)
    scenes: dict[str, list[str]] = field(default_factory=dict)  # split -> scene ids


@dataclass(frozen=True)
class DatasetView:
    """A labelled view of a dataset: its image id (COCO's and the torch Dataset's), plant
    and frame of the plant's transforms.json."""

    image_id: int
    plant: PlantEntry
    frame: dict


def labelled_plants(plants: list[PlantEntry]) -> tuple[list[PlantEntry], DatasetClasses]:
    """The plants with labelled views, and their classes keyed by name."""
    maps = {}
    for p in plants:
        if not (p.folder / "transforms.json").is_file():
            continue
        try:
            maps[p.id] = PlantClasses.read(p.folder).names
        except InputError:
            continue
    return [p for p in plants if p.id in maps], dataset_classes(maps)


def dataset_views(plants: list[PlantEntry]) -> list[DatasetView]:
    """Every labelled view of the plants (sorted by id), numbered from 1 in that order: the
    image ids of every COCO file of the dataset and of the torch Dataset of any split."""
    views = []
    for p in plants:
        views += [(p, frame) for frame in labelled_frames(p.folder)]
    return [DatasetView(i + 1, p, frame) for i, (p, frame) in enumerate(views)]


def check_planned_splits(
    dataset_dir: Path,
    plants: Mapping[str, str],
    options: LabelOptions,
    classes: Iterable[str] | None = None,
) -> None:
    """Refuses, before any plant runs, splits that the plants to come (``plants``: id ->
    species, ``Plant.species_name``), with those already finished in the folder, would leave
    empty, ``--stuff`` that names no class or every class of ``classes`` (the plants' class
    names; None: not known before they run), and a malformed ``SOURCE_DATE_EPOCH`` (the
    card's date)."""
    source_date_epoch()  # the card's date: a malformed one refused before any plant runs
    species_of = {p.id: p.species for p in finished_plants(dataset_dir)} | dict(plants)
    splits = make_splits(species_of, options.ratios, options.seed, options.mode)
    check_splits(splits, options.ratios, options.allow_empty_split)
    if classes is not None:
        check_stuff(options.stuff, classes)


def check_exports_owned(dataset_dir: Path) -> None:
    """Refuses a dataset folder whose export folders hold what the exports do not write
    (or are links), or that holds any file the exports write without a dataset's record
    (``dataset_files``): checked before a run starts and again before an export."""
    survey(Path(dataset_dir), DATASET_EXPORTS).refuse(Path(dataset_dir))
    check_top_files(Path(dataset_dir), TOP_ENTRIES)


def write_dataset_exports(dataset_dir: Path, options: LabelOptions | None = None) -> DatasetLabels:
    """Writes the dataset's splits, COCO and YOLO files and gallery, replacing the previous
    ones together (see the module's docstring); a plant whose own label files were made
    with another area limit gets them remade with this one."""
    dataset_dir = Path(dataset_dir)
    check_exports_owned(dataset_dir)
    remove_temporaries(dataset_dir, DATASET_EXPORTS)  # a killed export's staging folder
    stage = atomic.staging_folder(dataset_dir)
    try:
        labels, card = _write_exports(dataset_dir, stage, options or LabelOptions())
        # The card (README.md, dataset.json's card) with the exports it describes.
        labels.warnings.extend(w for w in [write_card(dataset_dir, card, into=stage)] if w)
        swap_in(dataset_dir, stage, EXPORT_ENTRIES, CARD_ENTRIES)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return labels


def _write_exports(
    dataset_dir: Path, stage: Path, options: LabelOptions
) -> tuple[DatasetLabels, dict[str, Any]]:
    """The exports of ``dataset_dir`` written into ``stage``."""
    ratios, seed, min_area = options.ratios, options.seed, options.min_area
    plants = finished_plants(dataset_dir)
    if not plants:
        raise InputError(f"{dataset_dir} has no finished plant under {PLANTS_DIR}/")
    scenes = finished_scenes(dataset_dir)
    labelled, classes = labelled_plants(plants + scenes)
    stuff_ids, things = classes.stuff_ids(options.stuff), classes.things(options.stuff)
    species_of = {p.id: p.species for p in plants}
    splits = make_splits(species_of, ratios, seed, options.mode)
    warnings = check_splits(splits, ratios, options.allow_empty_split)
    scene_splits = _scene_splits(scenes, splits)
    for p in labelled:
        if _plant_options(p.folder) == (min_area, list(options.stuff)):
            continue
        if not _inside(p.folder, dataset_dir):
            warnings.append(
                f"{p.folder} lies outside {dataset_dir}: its own label files were left as "
                "they are (made with other options)"
            )
            continue
        write_plant_exports(p.folder, min_area, options.stuff)
    species = species_counts(splits, species_of)
    warnings += species_gaps(splits, species_of, ratios)
    atomic.write_json(
        stage / SPLITS_FILE,
        {
            "seed": seed,
            "ratios": dict(zip(SPLITS, ratios, strict=True)),
            "mode": options.mode,
            **splits,
            "species": species,
            **({"scenes": scene_splits} if scenes else {}),
        },
    )
    split_of = {plant_id: split for split in SPLITS for plant_id in splits[split]}
    split_of |= {scene_id: split for split in SPLITS for scene_id in scene_splits[split]}
    views = dataset_views(labelled)
    images = Counter(split_of[v.plant.id] for v in views)
    card = dataset_card(plants, classes.names, options.stuff, splits, species, min_area, images,
                        scenes, split_rule=split_rule(ratios, seed, options.mode))  # fmt: skip
    coco_fields, licenses, licence_of = coco_info(card)
    guidance = {p.id: plant_guidance(p.folder) for p in labelled}
    guidance |= {s.id: str(scene_record(s).get("guidance", "sds")) for s in scenes}
    index = yolo.class_index(things)
    yolo_dir = stage / "yolo"
    total = LabelReport()
    annotation_ids = itertools.count(1)  # unique across the splits' files
    recorded = {p.id: plant_records(p.folder) for p in labelled}
    without: list[str] = []  # plants with no traits.json
    for split in SPLITS:
        coco = CocoBuilder(things, annotation_ids, licenses=licenses)
        report, counts = LabelReport(), []
        for view in views:
            plant = view.plant
            if split_of[plant.id] != split:
                continue
            seen = read_view_traits(plant.folder, view.frame, min_area, classes.luts[plant.id],
                                    classes.names, stuff_ids, recorded[plant.id])  # fmt: skip
            objects = seen.objects
            image = Path(view.frame["file_path"])
            relative = f"{plant.folder.parent.name}/{plant.id}/{image.as_posix()}"
            coco.add(view.image_id, relative, objects, seen.per_object, plant_id=plant.id,
                     license=licence_of[guidance[plant.id]], **seen.fields)  # fmt: skip
            counts.append({"file_name": relative, "plant_id": plant.id, **seen.fields})
            flat = f"{plant.id}__{image.stem}"
            yolo.link_image(plant.folder / image, yolo_dir / "images" / split / f"{flat}.png")
            lines = yolo.label_lines(objects, index)
            yolo.write_labels(yolo_dir / "labels" / split / f"{flat}.txt", lines)
            report += LabelReport.of(objects)
        (yolo_dir / "images" / split).mkdir(parents=True, exist_ok=True)
        (stage / "coco").mkdir(exist_ok=True)
        info = {**coco_fields, **report.info(f"{split} split", min_area, options.stuff)}
        coco.write(stage / "coco" / f"{split}.json", info)
        write_counts(stage / COUNTS_DIR / f"{split}.csv", ("file_name", "plant_id"), counts)
        in_split = [p for p in plants if split_of[p.id] == split]
        without += _write_traits(stage / TRAITS_DIR, split, in_split)
        total += report
    yolo.write_data_yaml(yolo_dir / "data.yaml", {s: f"images/{s}" for s in SPLITS}, things)
    if classes.remapped:
        warnings.append(
            f"class ids of {', '.join(classes.remapped)} renumbered by class name "
            f"({', '.join(f'{i} {n}' for i, n in classes.names.items())})"
        )
    if without:  # made before traits.json was written: their rows are missing
        warnings.append(
            f"{len(without)} plant(s) have no {TRAITS_FILE} ({', '.join(without[:5])}"
            f"{', ...' if len(without) > 5 else ''}): made before traits were written, they "
            f"are missing from {TRAITS_DIR}/; remake them (generate --overwrite) for theirs"
        )
    write_gallery(dataset_dir, stage / GALLERY_FILE)
    gallery = dataset_dir / GALLERY_FILE  # where it is once moved in
    labels = DatasetLabels(splits, total, gallery, min_area, species, warnings, scene_splits)
    return labels, card


def _scene_splits(scenes: list[PlantEntry], splits: dict[str, list[str]]) -> dict[str, list[str]]:
    """The scene ids of each split: the split each scene was made for (``scene.json``; all
    its plants are of it). A scene whose record names no split, or whose id is a plant's,
    is refused."""
    plant_ids = {i for ids in splits.values() for i in ids}
    cut: dict[str, list[str]] = {split: [] for split in SPLITS}
    for scene in scenes:
        split = scene_record(scene).get("split")
        if split not in cut or scene.id in plant_ids:
            why = "names no split" if split not in cut else "has a plant's id"
            raise InputError(f"scene {scene.folder} {why}: remake it (plantdreamer dataset)")
        cut[split].append(scene.id)
    return cut


def _write_traits(folder: Path, split: str, plants: list[PlantEntry]) -> list[str]:
    """``traits/<split>.csv``, one row per plant of the split with a traits.json, and
    ``traits/<split>_leaves.csv``, one row per leaf of theirs; returns the ids of the
    plants without one."""
    rows, leaves, without = [], [], []
    for p in plants:
        record = read_traits(p.folder)
        if record is None:
            without.append(p.id)
            continue
        rows.append({"plant_id": p.id, **plant_row(record)})
        leaves += [{"plant_id": p.id, **leaf} for leaf in leaf_rows(record)]
    write_table(folder / f"{split}.csv", ("plant_id", *PLANT_COLUMNS), rows)
    write_table(folder / f"{split}_leaves.csv", ("plant_id", *LEAF_COLUMNS), leaves)
    return without


def _inside(folder: Path, dataset_dir: Path) -> bool:
    return folder.resolve().is_relative_to(dataset_dir.resolve())


def _plant_options(folder: Path) -> tuple[int, list[str]] | None:
    """The area limit and stuff classes a plant's own label files were made with."""
    try:
        info = json.loads((folder / COCO_FILE).read_text())["info"]
        return int(info["min_instance_area"]), list(info.get("stuff_classes", []))
    except (OSError, ValueError, KeyError, TypeError):
        return None
