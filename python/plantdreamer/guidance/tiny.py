"""Tiny random-weight stand-ins for Stable Diffusion 2.1, its depth ControlNet and CLIP.

For tests, benchmarks and offline demos: the same diffusers / transformers classes as the real
models, with the real structure (VAE downsampling by 8, cross-attention UNet with linear
projections like SD 2.x, a ControlNet made from the UNet, a CLIP text encoder and a byte-level
BPE tokenizer), but under a megabyte of random weights, built entirely in-process.
Nothing is downloaded: the tokenizer's vocabulary is generated here.

``save_tiny_models(path)`` writes them in the hub's layout (``base/`` like
``stabilityai/stable-diffusion-2-1-base`` with ``model_index.json``, ``controlnet/`` like
``thibaud/controlnet-sd21-depth-diffusers``), so the real loading code can be tested on it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from plantdreamer.guidance.models import (
    DiffusionComponents,
    save_components,
    stable_diffusion_pipeline,
)

# Kept small but structurally faithful: 4 VAE blocks (factor 8) like SD's VAE.
TINY_TEXT_DIM = 32
TINY_MAX_TOKENS = 77


def _bytes_to_unicode() -> list[str]:
    """GPT-2/CLIP byte-to-printable-character table (the byte-level BPE alphabet)."""
    printable = (
        list(range(ord("!"), ord("~") + 1))
        + list(range(ord("¡"), ord("¬") + 1))
        + list(range(ord("®"), ord("ÿ") + 1))
    )
    chars = printable[:]
    n = 0
    for b in range(256):
        if b not in printable:
            printable.append(b)
            chars.append(256 + n)
            n += 1
    return [chr(c) for c in chars]


def tiny_vocab() -> dict[str, int]:
    """A character-level CLIP vocabulary (no merges): every byte, alone or word-final."""
    alphabet = _bytes_to_unicode()
    tokens = ["<|startoftext|>", "<|endoftext|>", *alphabet, *(c + "</w>" for c in alphabet)]
    return {t: i for i, t in enumerate(tokens)}


def tiny_tokenizer():  # type: ignore[no-untyped-def]
    """A CLIP byte-level BPE tokenizer over ``tiny_vocab`` (514 tokens, 77 positions)."""
    from transformers import CLIPTokenizer

    return CLIPTokenizer(
        vocab=tiny_vocab(),
        merges=[],
        model_max_length=TINY_MAX_TOKENS,
        bos_token="<|startoftext|>",
        eos_token="<|endoftext|>",
        unk_token="<|endoftext|>",
        pad_token="<|endoftext|>",
    )


def _unzero(module: torch.nn.Module, generator: torch.Generator, std: float = 0.05) -> None:
    """Randomise ControlNet's zero-initialised convolutions, so the tiny ControlNet responds
    to its conditioning the way a trained one does (a fresh one outputs exact zeros)."""
    with torch.no_grad():
        for p in module.parameters():
            if p.numel() and not p.any():
                p.copy_(torch.randn(p.shape, generator=generator) * std)


def tiny_models(seed: int = 0) -> DiffusionComponents:
    """A full tiny pipeline with seeded random weights (a few MB, float32, CPU)."""
    from diffusers import AutoencoderKL, ControlNetModel, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    unet = UNet2DConditionModel(
        sample_size=8,
        in_channels=4,
        out_channels=4,
        layers_per_block=1,
        block_out_channels=(16, 32),
        down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
        up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
        cross_attention_dim=TINY_TEXT_DIM,
        attention_head_dim=(2, 4),
        norm_num_groups=8,
        use_linear_projection=True,
    )
    controlnet = ControlNetModel.from_unet(unet, conditioning_embedding_out_channels=(8, 8, 16, 16))
    _unzero(controlnet, generator)
    vae = AutoencoderKL(
        in_channels=3,
        out_channels=3,
        down_block_types=("DownEncoderBlock2D",) * 4,
        up_block_types=("UpDecoderBlock2D",) * 4,
        block_out_channels=(8, 8, 16, 16),
        latent_channels=4,
        layers_per_block=1,
        norm_num_groups=4,
        sample_size=64,
    )
    tokenizer = tiny_tokenizer()
    text_encoder = CLIPTextModel(
        CLIPTextConfig(
            vocab_size=len(tokenizer),
            hidden_size=TINY_TEXT_DIM,
            intermediate_size=64,
            num_hidden_layers=2,
            num_attention_heads=2,
            max_position_embeddings=TINY_MAX_TOKENS,
            projection_dim=TINY_TEXT_DIM,
            bos_token_id=tokenizer.bos_token_id,
            eos_token_id=tokenizer.eos_token_id,
            pad_token_id=tokenizer.pad_token_id,
            hidden_act="gelu",
        )
    )
    # The scheduler configuration of stabilityai/stable-diffusion-2-1-base.
    scheduler = DDIMScheduler(
        num_train_timesteps=1000,
        beta_start=0.00085,
        beta_end=0.012,
        beta_schedule="scaled_linear",
        clip_sample=False,
        set_alpha_to_one=False,
        steps_offset=1,
        prediction_type="epsilon",
    )
    models: tuple[Any, ...] = (unet, controlnet, vae, text_encoder)
    for model in models:  # all torch modules; diffusers' stubs do not say so
        model.eval()
    return DiffusionComponents(
        unet=unet,
        controlnet=controlnet,
        vae=vae,
        text_encoder=text_encoder,
        tokenizer=tokenizer,
        scheduler=scheduler,
    )


def tiny_pipeline(seed: int = 0):  # type: ignore[no-untyped-def]
    """A diffusers ``StableDiffusionPipeline`` of tiny models (no safety checker)."""
    return stable_diffusion_pipeline(tiny_models(seed))


def save_tiny_models(path: str | Path, seed: int = 0) -> tuple[Path, Path]:
    """Write tiny models in the hub's folder layout; returns (base_model_dir, controlnet_dir)."""
    return save_components(tiny_models(seed), path)
