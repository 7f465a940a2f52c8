"""What a ``generate`` request asks for, checked before torch is imported: its configs (one
per seed, the preset under the settings given) and, for each, every setting (types,
ranges, choices: ``GenerateConfig.validate``), the species (with the closest name when it
is mistyped), the device on this machine (``plantdreamer.devices``, whether or not a
guidance will use it) and the point cloud's file. The command line and the Python API
both call ``requested_configs``, so a mistake costs either a second, not torch's import;
``runtime.check_inputs`` runs ``check_config`` again where a run starts."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from plantdreamer.devices import check_device
from plantdreamer.errors import InputError
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.group_settings import parse_group_seeds
from plantdreamer.pipeline.settings.presets import resolve_config

__all__ = ["check_config", "check_species", "requested_configs", "seeds_of"]


def requested_configs(
    preset: str,
    settings: Mapping[str, Any],
    seeds: str | Iterable[int] | None = None,
    *,
    base: Mapping[str, Any] | None = None,
) -> list[GenerateConfig]:
    """The configs of a request, each checked (``check_config``): one, or with ``seeds``
    one per seed, the same settings otherwise. ``settings`` are those given by name (over
    the preset); ``base`` fills what neither gives (the command line's defaults)."""
    base = dict(base or {})
    if seeds is None:
        configs = [resolve_config(preset, dict(settings), base=base)]
    else:
        if "seed" in settings:
            raise InputError("give seed or seeds, not both")
        configs = [
            resolve_config(preset, {**settings, "seed": seed}, base=base)
            for seed in seeds_of(seeds, group=True)
        ]
    for cfg in configs:
        check_config(cfg)
    return configs


def seeds_of(seeds: str | Iterable[int], group: bool = False) -> list[int]:
    """Seeds in the one grammar (``plantdreamer.seeds``): ``"0-7,9"``, or a list of
    integers (read as the same text, so its limits and repeats are refused alike).
    ``group``: the plants train together, at most ``MAX_GROUP_PLANTS`` of them."""
    from plantdreamer.seeds import parse_seeds

    if isinstance(seeds, str):
        text = seeds
    else:
        try:
            listed = list(seeds)
        except TypeError:
            raise InputError(
                f"seeds must be text like '0-7' or a list of integers, got {seeds!r}"
            ) from None
        if not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in listed):
            raise InputError(f"seeds must be text like '0-7' or integers >= 0, got {listed!r}")
        text = ",".join(map(str, listed))
    return parse_group_seeds(text) if group else parse_seeds(text)


def check_config(cfg: GenerateConfig, *, device_here: bool = True) -> None:
    """InputError (or PlyError) for the first thing ``cfg`` cannot run with.
    ``device_here=False`` leaves the device to the machine that will run the plant (a
    cluster's worker: this machine may have no GPU)."""
    cfg.validate()
    check_species(cfg)
    if device_here:
        check_device(cfg.sds.device)
    if cfg.source.pointcloud is not None:
        from plantdreamer.io import check_ply_file

        check_ply_file(cfg.source.pointcloud, "point cloud")


def check_species(cfg: GenerateConfig) -> None:
    """An L-System's species must be registered (a point cloud's only names it in the
    prompts); the error names the closest registered one."""
    if cfg.source.pointcloud is not None:
        return
    from plantdreamer.lsystem.species import list_species, unknown_species

    if cfg.source.structure() not in list_species():
        raise unknown_species(cfg.source.species)
