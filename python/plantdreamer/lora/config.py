"""The settings of a LoRA training run: one declaration each, the dataclass field that is
also the ``plantdreamer lora train`` option (``plantdreamer.settings``). Torch-free, so the
CLI builds its options from it at start-up."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from plantdreamer import settings
from plantdreamer.errors import InputError
from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE, SDS_DEFAULTS
from plantdreamer.settings import setting


@dataclass
class LoraTrainConfig:
    """Settings of one training run (``plantdreamer lora train --help`` lists them)."""

    images_dir: str
    species: str = setting("bean", "Plant species name.")
    base_model: str = setting(
        SDS_DEFAULTS.base_model, "Hub id or local folder of the Stable Diffusion model."
    )
    out: str | None = setting(None, "Output folder.", default_text="lora/<species>")
    rank: int = setting(4, "LoRA rank.")
    alpha: int | None = setting(None, "LoRA alpha.", default_text="the rank")
    steps: int = setting(1500, "Optimiser steps.")
    resolution: int = setting(512, "Training crop size (px).")
    learning_rate: float = setting(1e-4, "AdamW learning rate.", option="--lr")
    batch_size: int = setting(1, "Images per optimiser step.")
    grad_accum: int = setting(1, "Gradient accumulation steps.")
    seed: int = setting(0, "Seed of the image order, crops, flips and noise.")
    caption_template: str = setting(
        DEFAULT_PROMPT_TEMPLATE,
        "Caption for images without a <name>.txt beside them; recorded in lora.json, it is "
        "generate's --prompt-template with this LoRA.",
        option="--prompt-template",
    )
    checkpoint_every: int = setting(500, "Steps between checkpoints.")
    resume: bool = setting(False, "Continue from the latest checkpoint in --out.")
    overwrite: bool = setting(False, "Replace the outputs of an earlier run in --out.")
    mixed_precision: bool | None = setting(
        None, "fp16 autocast.", default_text="on with a CUDA GPU, off on the CPU"
    )
    device: str | None = setting(None, "torch device.", default_text="cuda if available")
    validate: int = setting(0, "Sample images to render after training.")
    validation_steps: int = 25

    @property
    def out_dir(self) -> str:
        return self.out if self.out is not None else f"lora/{self.species}"

    @classmethod
    def from_settings(cls, images_dir: str, values: dict[str, Any]) -> LoraTrainConfig:
        """A config from the photo folder and settings by name (``batch-size``, ``lr``)."""
        known = settings.by_name(cls)
        try:
            fields = {known[settings.canonical(k)].path[-1]: v for k, v in values.items()}
        except KeyError as exc:
            raise InputError(settings.unknown_message(exc.args[0], list(known))) from None
        return cls(images_dir, **fields)

    def record(self) -> dict[str, Any]:
        """``lora.json``'s ``config``: every setting under the name typed for it (``lr`` for
        ``--lr``), the photo folder and the output folder used."""
        values = {s.name: settings.value_at(self, s.path) for s in settings.walk(type(self))}
        return {"images-dir": self.images_dir, **values, "out": self.out_dir,
                "validation-steps": self.validation_steps}  # fmt: skip

    @classmethod
    def typed_names(cls, saved: Mapping[str, Any]) -> dict[str, Any]:
        """A record's keys under the typed names: older ``lora.json`` files and checkpoints
        saved the field names (``learning_rate``, ``caption_template``)."""
        names = {s.path[-1]: s.name for s in settings.walk(cls)}
        names.update(images_dir="images-dir", validation_steps="validation-steps")
        return {names.get(key, key): value for key, value in saved.items()}

    def check(self) -> None:
        from plantdreamer.output_folder import check_name

        check_name(self.species, "--species")  # the default --out is lora/<species>
        try:
            settings.check_types(self)  # integers are integers, numbers finite
        except ValueError as exc:
            raise InputError(str(exc)) from None
        if not 0 <= self.seed < 2**32:
            raise InputError(f"seed must be in 0..{2**32 - 1}, got {self.seed}")
        positive = {
            "rank": self.rank,
            "steps": self.steps,
            "resolution": self.resolution,
            "batch_size": self.batch_size,
            "grad_accum": self.grad_accum,
            "checkpoint_every": self.checkpoint_every,
            "alpha": self.rank if self.alpha is None else self.alpha,  # 0: an all-zero adapter
        }
        bad = [f"{k}={v}" for k, v in positive.items() if v <= 0]
        if bad or not self.learning_rate > 0 or self.validate < 0:
            raise InputError(f"settings must be positive: {', '.join(bad) or 'learning_rate'}")
        if self.resolution % 8:
            raise InputError(f"resolution must be a multiple of 8, got {self.resolution}")
        from plantdreamer.lora.dataset import check_caption_template

        check_caption_template(self.caption_template)

    def fingerprint(self, examples: Sequence[Any]) -> dict[str, Any]:
        """What a resumed run must share with its checkpoint (``steps`` may grow)."""
        keys = ["species", "base-model", "rank", "alpha", "resolution", "lr", "batch-size",
                "grad-accum", "seed", "prompt-template"]  # fmt: skip
        record = self.record()
        fp: dict[str, Any] = {k: record[k] for k in keys}
        fp["images"] = [e.path.name for e in examples]
        return fp
