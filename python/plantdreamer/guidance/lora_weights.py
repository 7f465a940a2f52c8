"""Species LoRA files: finding them and loading them into the UNet (and text encoder).

The file format is diffusers' LoRA format, a safetensors file usually named
``pytorch_lora_weights.safetensors`` with keys such as
``unet.down_blocks.0.attentions.0.transformer_blocks.0.attn1.to_q.lora.down.weight``
(rank 4 for the authors' files). Loading goes through diffusers'
``StableDiffusionLoraLoaderMixin`` (the same code as ``pipe.load_lora_weights``), after
normalising the key variants seen in the wild:

- new diffusers / PEFT keys (``...to_q.lora_A.weight``) and ``...to_q.lora.down.weight``;
- the older attention-processor layout (``...attn1.processor.to_q_lora.down.weight``);
- keys without the ``unet.`` prefix (a bare UNet state dict);
- kohya-ss keys (``lora_unet_...``), converted by diffusers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from plantdreamer.errors import InputError, ModelNotFoundError

LORA_WEIGHT_NAME = "pytorch_lora_weights.safetensors"
UNET_PREFIX = "unet."
TEXT_ENCODER_PREFIX = "text_encoder."


def find_lora_file(lora: str | Path) -> Path:
    """The safetensors file of a LoRA given as a file or a folder that holds one."""
    path = Path(lora)
    if path.is_file():
        if path.suffix != ".safetensors":
            raise InputError(f"LoRA file must be a .safetensors file, got {str(path)!r}")
        return path
    if path.is_dir():
        named = path / LORA_WEIGHT_NAME
        if named.is_file():
            return named
        candidates = sorted(path.glob("*.safetensors"))
        if len(candidates) == 1:
            return candidates[0]
        found = ", ".join(p.name for p in candidates) or "no .safetensors file"
        raise ModelNotFoundError(
            f"LoRA folder {str(path)!r} has no {LORA_WEIGHT_NAME} ({found}); pass the file itself "
            "with --lora PATH.safetensors, or train one with `plantdreamer lora train`"
        )
    raise ModelNotFoundError(
        f"LoRA {str(path)!r} not found: give a .safetensors file or a folder holding "
        f"{LORA_WEIGHT_NAME} (the authors' files are lora/<species>/{LORA_WEIGHT_NAME} in "
        "their repository), or train one with `plantdreamer lora train`"
    )


def read_lora_file(path: str | Path) -> dict[str, torch.Tensor]:
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        return load_file(str(path))
    except (SafetensorError, OSError, ValueError) as exc:
        raise InputError(f"cannot read LoRA file {str(path)!r}: {exc}") from exc


def normalise_lora_keys(
    state_dict: dict[str, torch.Tensor],
) -> tuple[dict[str, torch.Tensor], dict[str, float] | None]:
    """Keys in the ``unet.`` / ``text_encoder.`` prefixed diffusers layout, plus kohya alphas."""
    from diffusers.loaders import StableDiffusionLoraLoaderMixin

    if not state_dict:
        raise InputError("LoRA file is empty")
    if not all("lora" in k for k in state_dict):
        bad = next(k for k in state_dict if "lora" not in k)
        raise InputError(f"not a LoRA file: key {bad!r} does not name a LoRA weight")
    state_dict, alphas = StableDiffusionLoraLoaderMixin.lora_state_dict(dict(state_dict))
    out: dict[str, torch.Tensor] = {}
    for key, value in state_dict.items():
        key = key.replace(".processor.", ".")
        if not key.startswith((UNET_PREFIX, TEXT_ENCODER_PREFIX)):
            key = UNET_PREFIX + key
        out[key] = value
    return out, alphas


_DOWN_SUFFIXES = (".lora.down.weight", ".lora_A.weight", "_lora.down.weight", ".lora_down.weight")


def lora_module_names(keys: list[str]) -> set[str]:
    """The distinct layers a LoRA state dict adapts (one 'down'/'A' matrix per layer)."""
    names = set()
    for key in keys:
        for suffix in _DOWN_SUFFIXES:
            if key.endswith(suffix):
                names.add(key[: -len(suffix)])
                break
    return names


def count_lora_layers(model: torch.nn.Module) -> int:
    from peft.tuners.tuners_utils import BaseTunerLayer

    return sum(isinstance(m, BaseTunerLayer) for m in model.modules())


def load_lora(
    unet: Any,
    lora: str | Path | dict[str, torch.Tensor],
    text_encoder: Any = None,
    adapter_name: str = "species",
    scale: float = 1.0,
) -> int:
    """Attach a LoRA to ``unet`` (and ``text_encoder`` if the file has its keys).

    Returns the number of UNet layers that received a LoRA. Raises ``InputError`` if the file
    does not fit the model (another base model's LoRA) and ``ModelNotFoundError`` if missing.
    """
    from diffusers.loaders import StableDiffusionLoraLoaderMixin as Loader

    raw = lora if isinstance(lora, dict) else read_lora_file(find_lora_file(lora))
    state_dict, alphas = normalise_lora_keys(raw)
    unet_keys = [k for k in state_dict if k.startswith(UNET_PREFIX)]
    if not unet_keys:
        raise InputError("LoRA file has no UNet weights")
    before = count_lora_layers(unet)
    try:
        Loader.load_lora_into_unet(state_dict, alphas, unet, adapter_name=adapter_name)
        if text_encoder is not None and any(k.startswith(TEXT_ENCODER_PREFIX) for k in state_dict):
            Loader.load_lora_into_text_encoder(
                state_dict, alphas, text_encoder, adapter_name=adapter_name
            )
    except (RuntimeError, ValueError, KeyError) as exc:
        raise InputError(
            f"LoRA does not fit this base model ({str(exc).splitlines()[0][:200]}); "
            "was it trained for Stable Diffusion 2.1?"
        ) from exc
    added = count_lora_layers(unet) - before
    expected = len(lora_module_names(unet_keys))
    if added != expected:
        raise InputError(
            f"LoRA names {expected} UNet layers but {added} of this base model matched "
            f"(e.g. {unet_keys[0]!r}); was it trained for Stable Diffusion 2.1?"
        )
    if scale != 1.0:
        unet.set_adapters([adapter_name], weights=[scale])
    return added


def recorded_template(lora: str | Path) -> str | None:
    """The caption template a LoRA was trained with, from the ``lora.json`` that
    ``plantdreamer lora train`` writes beside its weights; None if there is none."""
    import json

    path = Path(lora)
    meta = (path if path.is_dir() else path.parent) / "lora.json"
    if not meta.is_file():
        return None
    try:
        config = json.loads(meta.read_text())["config"]
        # Saved under the typed name; files before it under the field's, caption_template.
        template = config["prompt-template" if "prompt-template" in config else "caption_template"]
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{meta} has no readable config.prompt-template: {exc}") from None
    return str(template)
