"""Writing a trained LoRA: the diffusers-format safetensors file, and validation samples.

The file is what ``StableDiffusionDepthGuidance(lora=...)`` and diffusers'
``pipe.load_lora_weights`` read: keys ``unet.<module>.lora.down.weight`` / ``.lora.up.weight``
for to_q, to_k, to_v and to_out.0 of every UNet attention layer (the authors' layout). The
diffusers format has no per-file alpha, so the LoRA scale alpha / rank is folded into the
up matrices: the file means exactly W + up @ down.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from plantdreamer.atomic import atomic_path, write_image
from plantdreamer.guidance.lora_weights import LORA_WEIGHT_NAME


def lora_state_dict(unet: Any, rank: int, alpha: float) -> dict[str, torch.Tensor]:
    """The UNet's LoRA weights in diffusers' layout (no prefix), scale folded in, float32 CPU."""
    from diffusers.utils import convert_state_dict_to_diffusers
    from peft.utils import get_peft_model_state_dict

    peft_sd = get_peft_model_state_dict(unet)
    scale = alpha / rank
    folded = {
        k: (v * scale if ".lora_B." in k else v).detach().to("cpu", torch.float32).contiguous()
        for k, v in peft_sd.items()
    }
    return convert_state_dict_to_diffusers(folded)


def save_lora_file(out: Path, unet: Any, rank: int, alpha: float) -> Path:
    from diffusers.loaders import StableDiffusionLoraLoaderMixin

    out.mkdir(parents=True, exist_ok=True)
    layers: dict[str, torch.nn.Module | torch.Tensor] = dict(lora_state_dict(unet, rank, alpha))
    path = out / LORA_WEIGHT_NAME
    with atomic_path(path) as tmp:
        StableDiffusionLoraLoaderMixin.save_lora_weights(
            save_directory=str(tmp.parent),
            unet_lora_layers=layers,
            weight_name=tmp.name,
            safe_serialization=True,
        )
    return path


@torch.no_grad()
def render_validation(
    out: Path,
    parts: Any,
    prompt: str,
    count: int,
    resolution: int,
    steps: int,
    seed: int,
    device: torch.device,
) -> list[Path]:
    """``count`` text-to-image samples with the trained LoRA, for a person to look at."""
    from diffusers import DDIMScheduler, StableDiffusionPipeline

    unet_mode = parts.unet.training
    parts.unet.eval()
    pipe: Any = StableDiffusionPipeline(  # diffusers types its pipelines loosely
        vae=parts.vae,
        text_encoder=parts.text_encoder,
        tokenizer=parts.tokenizer,
        unet=parts.unet,
        scheduler=DDIMScheduler.from_config(parts.scheduler.config),
        safety_checker=None,
        feature_extractor=None,
        requires_safety_checker=False,
    )
    pipe.set_progress_bar_config(disable=True)
    folder = out / "validation"
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(count):
        generator = torch.Generator(device="cpu").manual_seed(seed + i)
        image = pipe(
            prompt,
            height=resolution,
            width=resolution,
            num_inference_steps=steps,
            generator=generator,
        ).images[0]
        path = folder / f"sample-{i:02d}.png"
        write_image(path, image)
        paths.append(path)
    parts.unet.train(unet_mode)
    return paths
