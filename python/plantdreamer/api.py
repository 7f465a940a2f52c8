"""The Python API: ``generate`` and ``make_dataset``, the commands ``plantdreamer generate``
and ``plantdreamer dataset`` as functions.

They take the same settings by the same names (``_`` for ``-``: ``eval_views=2`` is
``--eval-views 2``), with the same defaults: every setting is a field of ``GenerateConfig``
(``plantdreamer.settings``), read from there to build each function's signature and the list
in its docstring, so ``help(plantdreamer.generate)`` shows them all. Errors are the
package's own (``InputError``, ``ModelNotFoundError``, ...), never an exit. Each returns what
a caller opens next: the files written, and the run's figures.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer import settings as settings_of
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.pipeline.config import GenerateConfig

__all__ = ["DatasetResult", "GeneratedPlant", "generate", "make_dataset"]


@dataclass(frozen=True)
class GeneratedPlant:
    """A finished plant folder: the files a caller opens next and the run's figures."""

    folder: Path
    ply: Path  # the 3DGS model (INRIA layout, labels as ``label`` / ``instance``)
    steps: int
    gaussians: int
    seconds: float  # wall-clock time of the call that made it (0 for a plant already made)
    timings: dict[str, float] = field(default_factory=dict)  # seconds per phase (run.json)

    @property
    def renders(self) -> list[Path]:
        """The evaluation orbit's views (``renders/view_NNN.png``)."""
        return sorted((self.folder / "renders").glob("view_*.png"))

    @property
    def turntable(self) -> Path | None:
        found = [self.folder / f"turntable.{s}" for s in ("gif", "mp4")]
        return next((p for p in found if p.is_file()), None)

    @property
    def progress(self) -> Path:
        """The Gaussians at each checkpoint, side by side (``progress.png``)."""
        from plantdreamer.pipeline.progress_pictures import PROGRESS_STRIP

        return self.folder / PROGRESS_STRIP

    @property
    def loss_plot(self) -> Path | None:
        """``loss.png`` (None for a run without guidance: it has no loss)."""
        from plantdreamer.pipeline.progress_pictures import LOSS_PLOT

        path = self.folder / LOSS_PLOT
        return path if path.is_file() else None

    @property
    def log(self) -> Path:
        """``log.csv``: one row per trained step."""
        return self.folder / "log.csv"

    @property
    def record(self) -> Path:
        """``run.json``: every setting, versions, timings."""
        return self.folder / "run.json"

    @property
    def coco(self) -> Path | None:
        """The plant's COCO file (None for an unlabelled plant)."""
        from plantdreamer.exports.plant import COCO_FILE

        path = self.folder / COCO_FILE
        return path if path.is_file() else None


@dataclass(frozen=True)
class DatasetResult:
    """A dataset folder after a run: its plants, splits and label files."""

    folder: Path
    done: int  # plants made by this call
    skipped: int  # plants already complete in the folder
    seconds: float
    splits: dict[str, list[str]]  # split -> plant ids
    plants: list[Path]  # every finished plant folder
    scenes: list[Path] = field(default_factory=list)  # every finished scene folder

    @property
    def coco(self) -> dict[str, Path]:
        """``coco/<split>.json`` by split."""
        return {s: self.folder / "coco" / f"{s}.json" for s in self.splits}

    @property
    def yolo(self) -> Path:
        """``yolo/data.yaml`` (Ultralytics' dataset file)."""
        return self.folder / "yolo" / "data.yaml"

    @property
    def gallery(self) -> Path:
        return self.folder / "gallery.png"

    @property
    def card(self) -> Path:
        """The dataset's card, ``README.md`` (also under ``card`` in ``dataset.json``)."""
        from plantdreamer.exports.card import README_FILE

        return self.folder / README_FILE


def generate(
    out: str | Path,
    *,
    seeds: str | Iterable[int] | None = None,
    resume: bool = False,
    overwrite: bool = False,
    quiet: bool = False,
    **settings: Any,
) -> GeneratedPlant | list[GeneratedPlant]:
    """Generates a plant into the folder ``out``, as ``plantdreamer generate --out OUT``.

    ``settings`` are generate's settings by name (listed below, with their defaults);
    ``preset`` picks the base values and the settings given override them. ``seeds``
    (``"0-7"``, ``"0,3,5"`` or a list) trains several plants together, one folder per seed
    under ``out``, and returns a list. ``resume=True`` continues the run in ``out`` with the
    settings it started with (only ``steps`` may be given, to go further). ``overwrite``
    replaces an earlier run's outputs in ``out``; ``quiet`` shows no progress.

    Returns the finished plant (its folder, ``ply``, ``renders``, ``progress``,
    ``loss_plot``, ``gaussians``, ``seconds``, ...); raises ``InputError`` for a setting
    that cannot work (before any model loads), ``ModelNotFoundError`` for missing weights
    and ``RunInterrupted`` on Ctrl-C (a checkpoint is written: resume it).
    """
    from plantdreamer.pipeline import resolve_config
    from plantdreamer.pipeline.group import GROUP_FILE, parse_seeds
    from plantdreamer.pipeline.plants import generate_plants

    out, t0, show = Path(out), time.perf_counter(), not quiet
    if resume:
        unchanged = set(settings) - {"steps"}
        if unchanged or seeds is not None or overwrite:
            raise InputError("resume continues with the settings it started with: give only steps")
        results = generate_plants(None, out, resume=True, changes=settings, show_progress=show)
        plants = [_plant(r, t0) for r in results]
        return plants if (out / GROUP_FILE).is_file() else plants[0]
    preset = settings.pop("preset", GenerateConfig().preset)
    if seeds is None:
        cfg = resolve_config(preset, settings)
        return _plant(generate_plants([cfg], out, overwrite=overwrite, show_progress=show)[0], t0)
    if "seed" in settings:
        raise InputError("give seed or seeds, not both")
    seed_list = parse_seeds(seeds) if isinstance(seeds, str) else [int(s) for s in seeds]
    cfgs = [resolve_config(preset, {**settings, "seed": s}) for s in seed_list]
    results = generate_plants(cfgs, out, group=True, overwrite=overwrite, show_progress=show)
    return [_plant(r, t0) for r in results]


def make_dataset(
    out: str | Path,
    spec: str | Path | Mapping[str, Any] | None = None,
    *,
    species: str | Iterable[str] | None = None,
    pointcloud: str | Path | None = None,
    seeds: str | Iterable[int] | None = None,
    count: int | None = None,
    seed_start: int | None = None,
    plants_per_gpu: int | None = None,
    address: str | None = None,
    local_cpus: int | None = None,
    cpus_per_plant: float | None = None,
    gpus_per_plant: float | None = None,
    resources: Mapping[str, float] | None = None,
    max_retries: int | None = None,
    split: str | tuple[float, float, float] | None = None,
    split_seed: int | None = None,
    stuff: str | Iterable[str] | None = None,
    allow_empty_split: bool | None = None,
    min_instance_area: int | None = None,
    redo_changed: bool = False,
    quiet: bool = False,
    scenes: str | Iterable[int] | None = None,
    scene_plants: int | None = None,
    scene_layout: str | None = None,
    scene_spacing: float | None = None,
    **settings: Any,
) -> DatasetResult:
    """Makes a dataset of plants in the folder ``out``, as ``plantdreamer dataset --out OUT``.

    The plants come from ``spec`` (a TOML file, or the same as a dict) or from ``species``
    (``"bean"`` or a list) and/or ``pointcloud`` (a PLY file or a glob) with ``seeds``
    (generate's grammar, ``"0-7,9"``, or a list; ``count``/``seed_start`` are the earlier
    spelling). ``settings`` are
    generate's settings by name (listed below), for every plant, over the spec's
    ``[defaults]``. The other arguments are ``dataset``'s options of the same names
    (``split``: ``"0.8,0.1,0.1"`` or three numbers; ``stuff``: class names; ``resources``:
    custom Ray resources per plant); None leaves each at the command's default. Plants run
    on Ray: a local instance, or the cluster at ``address``.

    Plants already complete in ``out`` are skipped. At the end the finished plants are split
    into train/val/test and written as COCO, YOLO, a gallery and the dataset's card
    (README.md). ``scenes`` (seeds, as ``seeds``) adds scenes of the finished plants
    (``dataset --scenes``: ``scene_plants`` of one split together, at ``scene_layout``,
    ``scene_spacing`` apart), in ``out/scenes/``; a spec's ``[[scene]]`` tables do the same.
    Returns the folder, splits and files; raises ``PlantDreamerError`` naming the plants
    that failed (after the others are written).
    """
    from plantdreamer.dataset import RunOptions, expand, run_dataset
    from plantdreamer.dataset.engine import custom_resources
    from plantdreamer.dataset.packing import packing_from
    from plantdreamer.dataset.scenes import expand_scenes, with_scene_table
    from plantdreamer.dataset.spec import with_settings
    from plantdreamer.exports.dataset import LabelOptions
    from plantdreamer.exports.listing import finished_plants, finished_scenes
    from plantdreamer.exports.splits import parse_ratios

    table = _spec(spec, species, pointcloud, seeds, count, seed_start)
    packing = packing_from(table, {"plants-per-gpu": plants_per_gpu})
    scene_values = {"scene-plants": scene_plants, "scene-layout": scene_layout,
                    "scene-spacing": scene_spacing}  # fmt: skip
    scene_text = scenes if scenes is None or isinstance(scenes, str) else ",".join(map(str, scenes))
    table = with_scene_table(table, scene_text, scene_values)
    table = with_settings(table, {settings_of.canonical(k): v for k, v in settings.items()})
    plants = expand(table)
    scene_plans = expand_scenes(table)
    if isinstance(split, str):
        split = parse_ratios(split)
    if isinstance(stuff, str):
        stuff = [n.strip() for n in stuff.split(",") if n.strip()]
    labels = _given(
        LabelOptions, ratios=split, seed=split_seed, min_area=min_instance_area,
        allow_empty_split=allow_empty_split, stuff=None if stuff is None else tuple(stuff),
    )  # fmt: skip
    options = _given(
        RunOptions, address=address, local_cpus=local_cpus, cpus_per_plant=cpus_per_plant,
        gpus_per_plant=gpus_per_plant, max_retries=max_retries,
        resources=custom_resources({k: str(v) for k, v in (resources or {}).items()}),
        plants_per_gpu=packing.plants_per_gpu, show_progress=not quiet, labels=labels,
        redo_changed=redo_changed, scenes=scene_plans,
    )  # fmt: skip
    report = run_dataset(table, plants, out, options)
    if report.failed:
        failures = "; ".join(f"{i}: {e}" for i, e in sorted(report.failures.items()))
        raise PlantDreamerError(
            f"{report.failed} of {len(plants)} plants failed ({failures}); "
            f"see {report.out_dir / 'manifest.jsonl'}"
        )
    return DatasetResult(
        report.out_dir,
        report.done,
        report.skipped,
        report.seconds,
        report.labels.splits if report.labels is not None else {},
        [p.folder for p in finished_plants(report.out_dir)],
        [s.folder for s in finished_scenes(report.out_dir)],
    )


def _spec(
    spec: str | Path | Mapping[str, Any] | None,
    species: str | Iterable[str] | None,
    pointcloud: str | Path | None,
    seeds: str | Iterable[int] | None,
    count: int | None,
    seed_start: int | None,
) -> dict[str, Any]:
    """The spec as ``dataset`` builds it: a file, a table, or one group per species."""
    from plantdreamer.cli.dataset import spec_of_options

    if isinstance(spec, Mapping):
        if any(v is not None for v in (species, pointcloud, seeds, count, seed_start)):
            raise InputError("give a spec or species, pointcloud and seeds, not both")
        return {"base_dir": str(Path.cwd()), **spec}
    if spec is None and species is None and pointcloud is None:
        raise InputError("give a spec or species")
    names = (species,) if isinstance(species, str) else tuple(species or ())
    seed_text = seeds if seeds is None or isinstance(seeds, str) else ",".join(map(str, seeds))
    return spec_of_options(
        None if spec is None else str(spec),
        names,
        None if pointcloud is None else str(pointcloud),
        seed_text,
        count,
        seed_start,
    )


def _given(cls: type, **values: Any) -> Any:
    """``cls`` with the values given (not None); the rest keep the dataclass's defaults."""
    return cls(**{k: v for k, v in values.items() if v is not None})


def _plant(result: Any, t0: float) -> GeneratedPlant:
    return GeneratedPlant(
        Path(result.out_dir),
        Path(result.ply_path),
        result.steps,
        result.gaussians,
        round(time.perf_counter() - t0, 3),
        dict(result.timings),
    )


def _with_settings(function: Any, chosen_per_plant: tuple[str, ...] = ()) -> None:
    """Adds every setting of ``GenerateConfig`` to ``function``'s signature (keyword-only,
    with its type and default) and to its docstring, from the one definition; but those
    ``chosen_per_plant`` (a dataset's seeds and point clouds come from its spec)."""
    signature = inspect.signature(function)
    params = [p for p in signature.parameters.values() if p.kind is not p.VAR_KEYWORD]
    taken = {p.name for p in params}
    lines = ["", "Settings (each also ``--NAME`` of the command line):", ""]
    for s in settings_of.walk(GenerateConfig):
        if s.param in taken or s.name in chosen_per_plant:
            continue
        kind = inspect.Parameter.KEYWORD_ONLY
        params.append(inspect.Parameter(s.param, kind, default=s.default, annotation=s.type))
        lines.append(f"- ``{s.param}`` = {s.default!r}: {s.field.metadata[settings_of.HELP]}")
    function.__signature__ = signature.replace(parameters=params)
    function.__doc__ = (function.__doc__ or "") + "\n    ".join(lines) + "\n"


_with_settings(generate)
_with_settings(make_dataset, ("seed", "pointcloud"))
