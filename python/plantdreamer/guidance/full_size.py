"""Full-size Stable Diffusion 2.1-base networks with random weights, built in-process.

For timing and memory work at the real model size without downloading anything: the same
diffusers / transformers classes as ``load_components`` returns, built from the published
configurations of ``stabilityai/stable-diffusion-2-1-base`` (UNet, VAE, OpenCLIP ViT-H text
encoder) and ``thibaud/controlnet-sd21-depth-diffusers`` (the depth ControlNet). The configs
are written out below because they are facts about those models (docs/full_size_models.md
lists the parameter counts they give). Weights are random, so images are noise; the
arithmetic per step is the real one.

The tokenizer is ``tiny.tiny_tokenizer`` (its ids are valid inputs of the 49408-token
embedding); tokenisation is not what is being timed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from plantdreamer.guidance.models import DiffusionComponents, save_components

# stabilityai/stable-diffusion-2-1-base, unet/config.json (keys diffusers needs).
UNET_CONFIG: dict[str, Any] = {
    "sample_size": 64,
    "in_channels": 4,
    "out_channels": 4,
    "center_input_sample": False,
    "flip_sin_to_cos": True,
    "freq_shift": 0,
    "down_block_types": (
        "CrossAttnDownBlock2D",
        "CrossAttnDownBlock2D",
        "CrossAttnDownBlock2D",
        "DownBlock2D",
    ),
    "mid_block_type": "UNetMidBlock2DCrossAttn",
    "up_block_types": (
        "UpBlock2D",
        "CrossAttnUpBlock2D",
        "CrossAttnUpBlock2D",
        "CrossAttnUpBlock2D",
    ),
    "only_cross_attention": False,
    "block_out_channels": (320, 640, 1280, 1280),
    "layers_per_block": 2,
    "downsample_padding": 1,
    "mid_block_scale_factor": 1,
    "act_fn": "silu",
    "norm_num_groups": 32,
    "norm_eps": 1e-5,
    "cross_attention_dim": 1024,
    "attention_head_dim": (5, 10, 20, 20),
    "dual_cross_attention": False,
    "use_linear_projection": True,
    "upcast_attention": False,
    "num_class_embeds": None,
}

# thibaud/controlnet-sd21-depth-diffusers, config.json: the UNet's encoder half (its values,
# as diffusers' ControlNetModel.from_unet copies them) plus the conditioning embedding (a
# 3-channel image at 8x the latent size).
_CONTROLNET_FROM_UNET = (
    "in_channels",
    "flip_sin_to_cos",
    "freq_shift",
    "down_block_types",
    "only_cross_attention",
    "block_out_channels",
    "layers_per_block",
    "downsample_padding",
    "mid_block_scale_factor",
    "act_fn",
    "norm_num_groups",
    "norm_eps",
    "cross_attention_dim",
    "attention_head_dim",
    "use_linear_projection",
    "upcast_attention",
    "num_class_embeds",
)
CONTROLNET_CONFIG: dict[str, Any] = {
    **{key: UNET_CONFIG[key] for key in _CONTROLNET_FROM_UNET},
    "conditioning_channels": 3,
    "controlnet_conditioning_channel_order": "rgb",
    "conditioning_embedding_out_channels": (16, 32, 96, 256),
    "global_pool_conditions": False,
}

# stabilityai/stable-diffusion-2-1-base, vae/config.json.
VAE_CONFIG: dict[str, Any] = {
    "in_channels": 3,
    "out_channels": 3,
    "down_block_types": ("DownEncoderBlock2D",) * 4,
    "up_block_types": ("UpDecoderBlock2D",) * 4,
    "block_out_channels": (128, 256, 512, 512),
    "layers_per_block": 2,
    "act_fn": "silu",
    "latent_channels": 4,
    "norm_num_groups": 32,
    "sample_size": 768,
    "scaling_factor": 0.18215,
}

# stabilityai/stable-diffusion-2-1-base, text_encoder/config.json (OpenCLIP ViT-H/14's text
# tower, 23 of its 24 layers: SD 2 takes the penultimate layer's output).
TEXT_ENCODER_CONFIG: dict[str, Any] = {
    "vocab_size": 49408,
    "hidden_size": 1024,
    "intermediate_size": 4096,
    "num_hidden_layers": 23,
    "num_attention_heads": 16,
    "max_position_embeddings": 77,
    "hidden_act": "gelu",
    "layer_norm_eps": 1e-5,
    "projection_dim": 512,
    "bos_token_id": 0,
    "eos_token_id": 2,
    "pad_token_id": 1,
}

# stabilityai/stable-diffusion-2-1-base, scheduler/scheduler_config.json (as in tiny.py).
SCHEDULER_CONFIG: dict[str, Any] = {
    "num_train_timesteps": 1000,
    "beta_start": 0.00085,
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "clip_sample": False,
    "set_alpha_to_one": False,
    "steps_offset": 1,
    "prediction_type": "epsilon",
}


def build_unet():  # type: ignore[no-untyped-def]
    from diffusers import UNet2DConditionModel

    return UNet2DConditionModel(**UNET_CONFIG)


def build_controlnet():  # type: ignore[no-untyped-def]
    from diffusers import ControlNetModel

    return ControlNetModel(**CONTROLNET_CONFIG)


def build_vae():  # type: ignore[no-untyped-def]
    from diffusers import AutoencoderKL

    return AutoencoderKL(**VAE_CONFIG)


def build_text_encoder():  # type: ignore[no-untyped-def]
    from transformers import CLIPTextConfig, CLIPTextModel

    return CLIPTextModel(CLIPTextConfig(**TEXT_ENCODER_CONFIG))


BUILDERS = {
    "unet": build_unet,
    "controlnet": build_controlnet,
    "vae": build_vae,
    "text_encoder": build_text_encoder,
}


def parameter_count(name: str) -> int:
    """Parameters of one network, counted on the meta device (no memory, no init time)."""
    with torch.device("meta"):
        model = BUILDERS[name]()
    return sum(p.numel() for p in model.parameters())


def full_size_models(seed: int = 0, device: str | torch.device = "cpu") -> DiffusionComponents:
    """All SDS networks at SD 2.1-base size with seeded random weights (float32 on
    ``device``; ``StableDiffusionDepthGuidance`` casts them). About 6.6 GB in float32."""
    from diffusers import DDIMScheduler

    from plantdreamer.guidance.tiny import tiny_tokenizer

    torch.manual_seed(seed)
    with torch.device(device):
        nets = {name: build() for name, build in BUILDERS.items()}
    for model in nets.values():
        model.eval()
    return DiffusionComponents(
        tokenizer=tiny_tokenizer(),
        scheduler=DDIMScheduler(**SCHEDULER_CONFIG),
        **nets,
    )


def save_full_size_models(
    path: str | Path, seed: int = 0, device: str | torch.device = "cpu"
) -> tuple[Path, Path]:
    """Write the full-size random-weight networks in the hub's folder layout (about 6.6 GB
    of float32 safetensors), so ``generate --base-model/--controlnet`` loads them through the
    real loading code. Returns (base_model_dir, controlnet_dir)."""
    return save_components(full_size_models(seed, device), path)
