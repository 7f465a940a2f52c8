"""Species LoRA training: rank-r adapters on the UNet attention projections, noise-prediction loss.

Standard text-to-image LoRA fine-tuning (as diffusers' ``train_text_to_image_lora.py``):
PEFT LoRA on ``to_q``, ``to_k``, ``to_v``, ``to_out.0`` of every UNet attention layer, the
VAE and text encoder frozen; each step encodes an augmented photo to latents, adds noise at a
uniform random timestep and regresses the noise (or the velocity for v-prediction models)
with a mean squared error. AdamW; gradient accumulation; fp16 autocast with a grad scaler on
a CUDA GPU. One seeded CPU generator drives every random choice (images, crops, flips, VAE
samples, noise, timesteps), so a run and its resumption are reproducible.

Outputs in ``out``: ``pytorch_lora_weights.safetensors`` (diffusers format), ``lora.json``
(the settings, losses and versions), ``checkpoints/`` and, with ``validate > 0``,
``validation/sample-NN.png``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import torch

from plantdreamer.atomic import write_json
from plantdreamer.errors import CheckpointError, InputError
from plantdreamer.guidance.lora_weights import LORA_WEIGHT_NAME
from plantdreamer.guidance.models import (
    DiffusionComponents,
    check_model_present,
    load_base_model,
    local_files_only,
    resolve_device,
)
from plantdreamer.lora.checkpoint import (
    CHECKPOINT_DIR,
    check_fingerprint,
    list_checkpoints,
    load_checkpoint,
    save_checkpoint,
)
from plantdreamer.lora.config import LoraTrainConfig
from plantdreamer.lora.dataset import load_examples, photo_sizes
from plantdreamer.lora.export import render_validation, save_lora_file
from plantdreamer.lora.objective import NoiseLoss
from plantdreamer.output_folder import claim_folder, tree
from plantdreamer.versions import package_versions

TARGET_MODULES = ("to_q", "to_k", "to_v", "to_out.0")
# What a training writes in its folder (output_folder.Owned): --overwrite deletes these only.
LORA_OUTPUTS = (
    "lora.json",
    LORA_WEIGHT_NAME,
    *tree("validation", re.compile(r"sample-\d{2,}\.png")),
    *tree(CHECKPOINT_DIR, re.compile(r"step-\d{6,}\.pt")),
)
ADAPTER = "default"


@dataclass
class LoraTrainResult:
    weights: Path
    metadata: Path
    losses: list[float] = field(default_factory=list)
    eval_loss_before: float = math.nan
    eval_loss_after: float = math.nan
    resumed_from: int = 0
    validation_images: list[Path] = field(default_factory=list)


def prepare_models(
    config: LoraTrainConfig,
    components: DiffusionComponents | Mapping[str, Any] | None,
    device: torch.device,
    weight_dtype: torch.dtype,
) -> DiffusionComponents:
    """Frozen VAE / text encoder / UNet on ``device`` with fresh LoRA adapters (float32)."""
    from peft import LoraConfig

    if components is None:
        offline = local_files_only([config.base_model])
        unet, vae, text_encoder, tokenizer, scheduler = load_base_model(
            config.base_model, weight_dtype, offline
        )
        parts = DiffusionComponents(unet, None, vae, text_encoder, tokenizer, scheduler)
    elif isinstance(components, Mapping):
        parts = DiffusionComponents(**{"controlnet": None, **components})
    else:
        parts = components
    for model in (parts.vae, parts.text_encoder, parts.unet):
        model.requires_grad_(False)
        model.to(device=device)
        if next(model.parameters()).dtype != weight_dtype:
            model.to(dtype=weight_dtype)
    parts.vae.eval()
    parts.text_encoder.eval()
    torch.manual_seed(config.seed)  # PEFT's initialisation of the A matrices
    parts.unet.add_adapter(
        LoraConfig(
            r=config.rank,
            lora_alpha=config.alpha if config.alpha is not None else config.rank,
            init_lora_weights="gaussian",
            target_modules=list(TARGET_MODULES),
        ),
        adapter_name=ADAPTER,
    )
    for p in parts.unet.parameters():
        if p.requires_grad:  # trainable LoRA weights stay float32 under fp16 weights
            p.data = p.data.float()
    parts.unet.train()
    return parts


def train_lora(
    config: LoraTrainConfig,
    components: DiffusionComponents | Mapping[str, Any] | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> LoraTrainResult:
    """Run (or resume) a training; ``progress(step, steps, loss)`` is called after each step.

    ``out`` is locked for the run; a new run needs it empty (or ``overwrite``), a resumed
    one needs a checkpoint there.
    """
    config.check()
    photo_sizes(config.images_dir, config.resolution)  # refused before anything loads
    out = Path(config.out_dir)
    if config.resume and config.overwrite:
        raise InputError("overwrite starts afresh; it cannot go with resume")
    if config.resume and not list_checkpoints(out):
        raise CheckpointError(
            f"nothing to resume: {out / CHECKPOINT_DIR} holds no checkpoint; "
            "run without --resume to start a new training"
        )
    if not config.resume and not config.overwrite and list_checkpoints(out):
        raise CheckpointError(
            f"{str(out)!r} holds checkpoints of an earlier run; pass --resume to continue it, "
            "--overwrite to start afresh, or choose another --out folder"
        )
    # Everything checked before anything in ``out`` is deleted: the device, the photos, the
    # base model (found, not loaded) and that no photo lies among the outputs.
    device = resolve_device(config.device)
    mixed = config.mixed_precision if config.mixed_precision is not None else device.type == "cuda"
    if mixed and device.type != "cuda":
        raise InputError("mixed precision needs a CUDA GPU; run without --mixed-precision")
    examples = load_examples(
        config.images_dir, config.species, config.resolution, config.caption_template
    )
    if components is None:
        check_model_present(config.base_model, "base")
    inputs = [e.path for e in examples]
    with claim_folder(out, overwrite=config.overwrite, owned=LORA_OUTPUTS,
                      allow_existing=config.resume, inputs=inputs):  # fmt: skip
        return _train(config, components, progress, examples, device, mixed)


def _train(
    config: LoraTrainConfig,
    components: DiffusionComponents | Mapping[str, Any] | None,
    progress: Callable[[int, int, float], None] | None,
    examples: list[Any],
    device: torch.device,
    mixed: bool,
) -> LoraTrainResult:
    weight_dtype = torch.float16 if mixed else torch.float32
    out = Path(config.out_dir)
    fingerprint = config.fingerprint(examples)
    parts = prepare_models(config, components, device, weight_dtype)
    objective = NoiseLoss(parts, device, weight_dtype)
    params = [p for p in parts.unet.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(params, lr=config.learning_rate, weight_decay=1e-2)
    scaler = torch.amp.GradScaler(device.type, enabled=mixed)
    generator = torch.Generator().manual_seed(config.seed)

    start, losses, eval_before = 0, [], math.nan
    if config.resume:
        from peft.utils import set_peft_model_state_dict

        path = list_checkpoints(out)[-1]
        state = load_checkpoint(path)
        if not isinstance(state["fingerprint"], dict):
            raise CheckpointError(f"checkpoint {str(path)!r}: damaged fingerprint")
        saved = LoraTrainConfig.typed_names(state["fingerprint"])  # older: field names
        check_fingerprint(path, saved, fingerprint)
        try:
            set_peft_model_state_dict(parts.unet, state["lora"], adapter_name=ADAPTER)
            optimizer.load_state_dict(state["optimizer"])
            if "scaler" in state:
                scaler.load_state_dict(state["scaler"])
            generator.set_state(state["generator"])
            start, losses = int(state["step"]), [float(v) for v in state["losses"]]
            eval_before = float(state.get("eval_loss_before", math.nan))
        except (KeyError, TypeError, ValueError, IndexError, RuntimeError) as exc:
            raise CheckpointError(
                f"checkpoint {str(path)!r} is damaged or incompatible ({type(exc).__name__}: {exc})"
            ) from exc
    if math.isnan(eval_before):
        eval_before = objective.evaluate(examples, config.resolution, config.seed)

    def snapshot(step: int) -> dict[str, Any]:
        from peft.utils import get_peft_model_state_dict

        lora = get_peft_model_state_dict(parts.unet, adapter_name=ADAPTER)
        return {
            "step": step,
            "lora": {k: v.detach().cpu() for k, v in lora.items()},
            "optimizer": optimizer.state_dict(),
            "scaler": scaler.state_dict(),
            "generator": generator.get_state(),
            "losses": losses,
            "fingerprint": fingerprint,
            "eval_loss_before": eval_before,
        }

    for step in range(start, config.steps):
        optimizer.zero_grad(set_to_none=True)
        step_loss = 0.0
        for _ in range(config.grad_accum):
            loss = objective.random_step(examples, config.batch_size, config.resolution, generator)
            if not torch.isfinite(loss):
                raise InputError(
                    f"training loss became {float(loss.detach())} at step {step}; lower --lr"
                )
            scaler.scale(loss / config.grad_accum).backward()
            step_loss += float(loss.detach()) / config.grad_accum
        scaler.step(optimizer)
        scaler.update()
        losses.append(step_loss)
        done = step + 1
        if done % config.checkpoint_every == 0 or done == config.steps:
            save_checkpoint(out, done, snapshot(done))
        if progress is not None:
            progress(done, config.steps, step_loss)

    rank_alpha = config.alpha if config.alpha is not None else config.rank
    parts.unet.eval()
    eval_after = objective.evaluate(examples, config.resolution, config.seed)
    weights = save_lora_file(out, parts.unet, config.rank, rank_alpha)
    samples: list[Path] = []
    if config.validate:
        prompt = config.caption_template.format(species=config.species)
        samples = render_validation(
            out,
            parts,
            prompt,
            config.validate,
            config.resolution,
            config.validation_steps,
            config.seed,
            device,
        )
    metadata = out / "lora.json"
    write_json(
        metadata,
        (
            {
                "format": "diffusers LoRA (unet.<module>.lora.down/up.weight), alpha folded in",
                "target_modules": list(TARGET_MODULES),
                "config": config.record(),
                "images": fingerprint["images"],
                "captions": sorted({e.caption for e in examples}),
                "steps_done": len(losses),
                "resumed_from_step": start,
                "final_loss_mean_last_50": sum(losses[-50:]) / max(1, len(losses[-50:])),
                "eval_loss_before": eval_before,
                "eval_loss_after": eval_after,
                "mixed_precision": mixed,
                "device": str(device),
                "versions": package_versions(),
                "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            }
        ),
    )
    return LoraTrainResult(weights, metadata, losses, eval_before, eval_after, start, samples)
