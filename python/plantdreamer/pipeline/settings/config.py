"""Every setting of a generation run: sections owned by the modules that read them.

``GenerateConfig`` joins the sections (brush's ``#[clap(flatten)]``): ``source``
(``source.py``), ``init`` (``init.py``), ``train`` (``train_config.py``), ``sds``
(``guidance/config.py``), ``density`` (``density.py``) and ``outputs`` (``outputs.py``). Each
setting has one name (``plantdreamer.settings``): the CLI option, the spec key, the ``--set``
key, the ``--resume`` key and the key it is saved under. ``run.json``, ``group.json`` and each
checkpoint store ``to_dict()`` (``{"points": 2000, "densify-every": 100, ...}``, brush saves
its flags' names too) and ``from_dict`` (``from_record``) reads it back, or a record of an
earlier version, so a run continues with exactly the settings it started with.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from plantdreamer import settings
from plantdreamer.errors import InputError
from plantdreamer.guidance.config import SdsConfig
from plantdreamer.pipeline.model.density import DensityConfig
from plantdreamer.pipeline.model.init import InitConfig
from plantdreamer.pipeline.model.source import SourceConfig
from plantdreamer.pipeline.outputs import OutputsConfig
from plantdreamer.pipeline.settings.train_config import TrainConfig
from plantdreamer.settings import option_prefix, setting

MAX_RESOLUTION = 8192  # largest training / evaluation render side
# Where ours, the paper and the authors' released code differ (docs/fidelity.md);
# pipeline/settings/presets.py holds each preset's values.
PRESET_NAMES = ("plantdreamer", "released", "paper")
# The settings in which plants trained together (a group, a dataset's packed unit) may
# differ; they share every other one (``shared_settings``).
PER_PLANT = ("seed", "pointcloud")


@dataclass
class GenerateConfig:
    preset: str = setting(
        "plantdreamer",
        "Base settings: ours, the authors' released code or the paper's stated values "
        "(docs/fidelity.md); options given override them.",
        choices=PRESET_NAMES,
    )
    seed: int = setting(0, "Seed of the plant, cameras and noise.")
    source: SourceConfig = field(default_factory=SourceConfig, metadata=option_prefix(""))
    init: InitConfig = field(default_factory=InitConfig, metadata=option_prefix(""))
    train: TrainConfig = field(default_factory=TrainConfig, metadata=option_prefix(""))
    sds: SdsConfig = field(default_factory=SdsConfig, metadata=option_prefix(""))
    density: DensityConfig = field(default_factory=DensityConfig, metadata=option_prefix(""))
    outputs: OutputsConfig = field(default_factory=OutputsConfig, metadata=option_prefix(""))

    @classmethod
    def of(cls, **values: Any) -> GenerateConfig:
        """A config from settings by name (``_`` for ``-``): ``of(species="bean", points=500)``."""
        return cls.from_settings(values)

    @classmethod
    def from_settings(cls, values: Mapping[str, Any]) -> GenerateConfig:
        try:
            return _build(cls, settings.names_to_tree(cls, values))
        except ValueError as exc:
            raise InputError(str(exc)) from None

    def settings(self) -> dict[str, Any]:
        """Every setting by its one name."""
        return {s.name: settings.value_at(self, s.path) for s in settings.walk(type(self))}

    def shared_settings(self) -> dict[str, Any]:
        """Every setting but the ``PER_PLANT`` ones: what plants trained together share."""
        return {k: v for k, v in self.settings().items() if k not in PER_PLANT}

    def get(self, name: str) -> Any:
        try:
            return settings.value_of(self, name)
        except ValueError as exc:
            raise InputError(str(exc)) from None

    def validate(self) -> None:
        try:
            settings.check_types(self)  # a spec or --set can give any TOML value
            settings.check_choices(self)
        except ValueError as exc:
            raise InputError(str(exc)) from None
        self._check_numbers()
        for section in (self.source, self.train, self.density, self.outputs):
            section.validate()
        if self.source.species is None and self.source.pointcloud is None:
            raise InputError("give an input: a species (L-System) or a point cloud")
        if self.train.steps < 0 or self.source.points < 0 or self.outputs.eval_views < 0:
            raise InputError("steps, points and views must not be negative")
        dens = self.density
        if self.train.checkpoint_every <= 0 or dens.densify.every <= 0 or dens.cull.every <= 0:
            raise InputError("checkpoint, densify and cull intervals must be positive")
        tolerance = self.source.downsample_tolerance
        if not 0.0 < tolerance < 1.0:
            raise InputError(f"downsample tolerance must be in (0, 1), got {tolerance}")
        screen = dens.densify.prune_screen_px
        if screen is not None and not (math.isfinite(screen) and screen > 0):
            raise InputError(f"screen-size prune must be a positive pixel count, got {screen}")
        if not 0.0 < dens.densify.split_std <= 4.0:
            raise InputError(f"split std must be in (0, 4], got {dens.densify.split_std}")
        if self.sds.prompt_template is not None:
            from plantdreamer.guidance.prompts import check_template

            check_template(self.sds.prompt_template)

    def _check_numbers(self) -> None:
        """Numbers in range and counts that fit in memory (their types and finiteness are
        ``settings.check_types``'): no run starts on values it would silently garble."""
        from plantdreamer.cloud import check_point_count

        if not 0 <= self.seed < 2**32:
            raise InputError(f"seed must be in 0..{2**32 - 1}, got {self.seed}")
        if self.source.points != 0 or self.source.pointcloud is None:  # 0: the cloud whole
            check_point_count(self.source.points, "points")
        if self.sds.guidance_scale < 0:
            raise InputError(f"guidance scale must be >= 0, got {self.sds.guidance_scale}")
        if not 0.0 <= self.train.background <= 1.0:
            raise InputError(
                f"background must be a grey level in [0, 1], got {self.train.background}"
            )
        for name in ("resolution", "sds-resolution"):
            size = self.get(name)
            if size is not None and not 8 <= size <= MAX_RESOLUTION:
                raise InputError(f"{name} must be in 8..{MAX_RESOLUTION}, got {size}")

    def to_dict(self) -> dict[str, Any]:
        """Every setting by its one name, plain values only (lists, numbers, strings,
        None): the saved form of run.json, group.json and checkpoints."""
        return _plain(self.settings())

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> GenerateConfig:
        """The config a record holds, in any saved form (``from_record``)."""
        return from_record(data)


def check_shared(cfgs: Sequence[GenerateConfig]) -> None:
    """InputError unless the plants share every setting but the ``PER_PLANT`` ones."""
    shared = [c.shared_settings() for c in cfgs]
    if any(s != shared[0] for s in shared[1:]):
        differ = sorted({k for s in shared[1:] for k in s if s[k] != shared[0][k]})
        raise InputError(
            f"plants trained together share every setting but {' and '.join(PER_PLANT)}; "
            f"these differ: {', '.join(differ)}"
        )


# Settings added after records were written, each with the value that does what the
# versions before it did: a record without the setting means that value, not today's
# default, so an older run resumes with the same bits.
RECORDED_BEFORE: dict[str, Any] = {"depth-size": "render"}


def from_record(data: Mapping[str, Any]) -> GenerateConfig:
    """The config a run.json, group.json or checkpoint recorded: settings by name (this
    version), the sections of the versions up to 689da5e (``{"source": {"points": ...}}``), or
    the flat fields before them; a setting the record predates takes its
    ``RECORDED_BEFORE`` value. The one reader of saved configs: resume, ``render`` and
    the dataset driver all come through here."""
    if isinstance(data.get("source"), Mapping):  # no setting is named "source"
        cfg = _build(GenerateConfig, data)
    else:
        cfg = from_flat_dict(data)
    absent = {k: v for k, v in RECORDED_BEFORE.items() if k not in _recorded_names(data)}
    return GenerateConfig.from_settings({**cfg.settings(), **absent}) if absent else cfg


def _recorded_names(data: Mapping[str, Any]) -> set[str]:
    """The names a record holds: its keys, and its sections' keys (where a section's field
    is named after itself, as the ones ``RECORDED_BEFORE`` holds)."""
    names = {settings.canonical(k) for k in data}
    for section in data.values():
        if isinstance(section, Mapping):
            names |= {settings.canonical(k) for k in section}
    return names


def from_flat_dict(data: Mapping[str, Any]) -> GenerateConfig:
    """A config from a flat record: settings by name, or the fields of the first versions
    (top-level fields, ``densify``, ``cull``, ``lr`` and ``cameras`` nested once, ``_`` for
    ``-``, ``n_points``): each key maps to one name."""
    values: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            values.update({f"{key}-{k}": v for k, v in value.items()})
        else:
            values[key] = value
    renamed = {"n-points": "points", "n_points": "points"}
    return GenerateConfig.from_settings(
        {renamed.get(k, settings.canonical(k)): v for k, v in values.items()}
    )


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _build(cls: Any, data: Mapping[str, Any]) -> Any:
    """``cls`` from ``to_dict`` output; nested configs recursively, lists back to tuples."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(data) - set(fields)
    if unknown:
        raise InputError(f"unknown config keys: {', '.join(sorted(unknown))}")
    values = {}
    for name, value in data.items():
        default = _default(fields[name])
        if dataclasses.is_dataclass(default) and isinstance(value, dict):
            value = _build(type(default), value)
        elif isinstance(default, tuple) and isinstance(value, list):
            value = tuple(value)
        values[name] = value
    return cls(**values)


def _default(f: dataclasses.Field) -> Any:
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return f.default
