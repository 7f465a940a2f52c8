"""The Python API's two calls: ``generate`` and ``make_dataset``, the commands
``plantdreamer generate`` and ``plantdreamer dataset`` as functions (``plantdreamer.api``
says what they share with the command line).
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from plantdreamer import settings as settings_of
from plantdreamer.api.results import DatasetResult, GeneratedPlant
from plantdreamer.api.words import python_words
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.pipeline.settings.config import GenerateConfig

__all__ = ["generate", "make_dataset"]


def generate(
    out: str | Path,
    *,
    seeds: str | Iterable[int] | None = None,
    resume: bool = False,
    overwrite: bool = False,
    quiet: bool = False,
    **settings: Any,
) -> list[GeneratedPlant]:
    """Generates plants into the folder ``out``, as ``plantdreamer generate --out OUT``.

    ``settings`` are generate's settings by name (listed below, with their defaults);
    ``preset`` picks the base values and the settings given override them. One plant is
    made in ``out`` itself; ``seeds`` (``"0-7"``, ``"0,3,5"`` or a list of integers) trains
    several together, one folder per seed under ``out``. ``resume=True`` continues the run
    in ``out`` with the settings it started with (only ``steps`` may be given, to go
    further). ``overwrite=True`` replaces an earlier run's outputs in ``out``;
    ``quiet=True`` shows no progress.

    Returns the finished plants, always a list (one item without ``seeds``), each with
    its folder, ``ply``, ``renders``, ``progress``, ``loss_plot``, ``gaussians``,
    ``seconds``, ...; every path absolute. Raises ``InputError`` for a setting that cannot
    work (checked before torch is imported), ``ModelNotFoundError`` for missing weights,
    ``PlantsFailed`` naming the plants of a group that failed (the others are written) and
    ``RunInterrupted`` on Ctrl-C (a checkpoint is written: resume it).
    """
    from plantdreamer.pipeline.settings.requested import requested_configs

    with python_words():
        for name, flag in (("resume", resume), ("overwrite", overwrite), ("quiet", quiet)):
            _check_flag(name, flag)
        out, t0, show = _folder(out), time.perf_counter(), not quiet
        if resume:
            unchanged = set(settings) - {"steps"}
            if unchanged or seeds is not None or overwrite:
                raise InputError(
                    "resume continues with the settings it started with: give only steps"
                )
            cfgs = None
        else:
            preset = settings.pop("preset", GenerateConfig().preset)
            cfgs = requested_configs(preset, settings, seeds)
        # The run's modules (torch) only once the request is checked.
        from plantdreamer.pipeline import FolderPerPlant, PlantAlone, generate_plants
        from plantdreamer.pipeline.runs.layout import found_layout
        from plantdreamer.pipeline.runs.record import GROUP_FILE
        from plantdreamer.pipeline.runs.results import finished_or_raise

        if resume:
            layout = found_layout(out)
        else:
            layout = PlantAlone() if seeds is None else FolderPerPlant()
        grouped = isinstance(layout, FolderPerPlant)
        results = generate_plants(
            cfgs, out, layout=layout, failures="record" if grouped else "raise", resume=resume,
            changes=settings if resume else None, overwrite=overwrite, show_progress=show,
        )  # fmt: skip
        return [_plant(r, t0) for r in finished_or_raise(results, out / GROUP_FILE)]


def make_dataset(
    out: str | Path,
    spec: str | Path | Mapping[str, Any] | None = None,
    *,
    species: str | Iterable[str] | None = None,
    pointcloud: str | Path | None = None,
    seeds: str | Iterable[int] | None = None,
    plants_per_gpu: int | None = None,
    address: str | None = None,
    local_cpus: int | None = None,
    cpus_per_plant: float | None = None,
    gpus_per_plant: float | None = None,
    resources: Mapping[str, float] | None = None,
    max_retries: int | None = None,
    split: str | tuple[float, float, float] | None = None,
    split_seed: int | None = None,
    split_mode: str | None = None,
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
    (generate's grammar, ``"0-7,9"``, or a list of integers). ``settings`` are generate's
    settings by name (listed below), for every plant, over the spec's ``[defaults]``. The
    other arguments are ``dataset``'s options of the same names (``split``:
    ``"0.8,0.1,0.1"`` or three non-negative numbers, normalised to shares, expected shares
    unless ``split_mode`` is ``"exact"``; ``stuff``: class names; ``resources``: custom Ray resources per plant), checked as the command line
    checks them; None leaves each at the command's default. Plants run on worker
    processes of this machine, or on Ray with ``address`` (``"auto"`` or ``HOST:PORT``: a
    cluster; ``"local"``: a private Ray started here).

    ``scenes`` (seeds, as ``seeds``) adds scenes of the finished plants (``dataset
    --scenes``: ``scene_plants`` of one split together, at ``scene_layout``,
    ``scene_spacing`` apart), in ``out/scenes/``; a spec's ``[[scene]]`` tables do the same.

    Plants already complete in ``out`` are skipped. At the end the finished plants are split
    into train/val/test and written as COCO, YOLO, a gallery and the dataset's card
    (README.md). Returns the folder, splits and files (absolute paths); raises
    ``InputError`` for an option or setting that cannot work, before anything starts,
    ``PlantDreamerError`` naming the plants that failed (after the others are written),
    and ``DatasetStopped`` on Ctrl-C (running plants checkpoint: call again to finish).
    """
    from plantdreamer.dataset import run_dataset
    from plantdreamer.dataset.request import check_flag, dataset_request
    from plantdreamer.exports.listing import finished_plants, finished_scenes

    with python_words():
        check_flag("quiet", quiet)
        folder = _folder(out)
        request = dataset_request(
            spec=spec, species=species, pointcloud=pointcloud, seeds=seeds, settings=settings,
            plants_per_gpu=plants_per_gpu, address=address, local_cpus=local_cpus,
            cpus_per_plant=cpus_per_plant, gpus_per_plant=gpus_per_plant, resources=resources,
            max_retries=max_retries, split=split, split_seed=split_seed,
            split_mode=split_mode, stuff=stuff,
            allow_empty_split=allow_empty_split, min_instance_area=min_instance_area,
            redo_changed=redo_changed, show_progress=not quiet, scenes=scenes,
            scene_settings={"scene-plants": scene_plants, "scene-layout": scene_layout,
                            "scene-spacing": scene_spacing},
        )  # fmt: skip
        report = run_dataset(request.spec, request.plants, folder, request.options)
        if report.failed:
            failures = "; ".join(f"{i}: {e}" for i, e in sorted(report.failures.items()))
            raise PlantDreamerError(
                f"{report.failed} of {len(request.plants)} plants failed ({failures}); "
                f"see {report.out_dir / 'manifest.jsonl'}"
            )
    return DatasetResult(
        report.out_dir,
        report.done,
        report.skipped,
        report.seconds,
        report.labels.splits if report.labels is not None else {},
        [p.folder.resolve() for p in finished_plants(report.out_dir)],
        [s.folder.resolve() for s in finished_scenes(report.out_dir)],
    )


def _check_flag(name: str, value: Any) -> None:
    if not isinstance(value, bool):
        raise InputError(f"{name} must be True or False, got {value!r}")


def _folder(out: Any) -> Path:
    """``out`` as an absolute path (the form every returned path takes)."""
    if not isinstance(out, (str, Path)) or not str(out):
        raise InputError(f"out must be a folder's path, got {out!r}")
    return Path(out).resolve()


def _plant(result: Any, t0: float) -> GeneratedPlant:
    return GeneratedPlant(
        Path(result.folder).resolve(),
        Path(result.ply_path).resolve(),
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
