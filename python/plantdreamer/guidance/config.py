"""The settings of SDS guidance: the one place their defaults are written.

``StableDiffusionDepthGuidance`` takes its keyword defaults from here, and the generation
config nests an ``SdsConfig``, so the CLI, ``run.json`` and the guidance agree. Imports
nothing heavy (the CLI reads it at start-up).
"""

from __future__ import annotations

from dataclasses import dataclass

from plantdreamer.settings import setting

# Names of the built-in timestep schedules (``schedules.BUILTIN_SCHEDULES``; a test checks).
SCHEDULES = ("paper", "released")


@dataclass
class SdsConfig:
    """Stable Diffusion 2.1 + depth ControlNet score distillation, as in the paper."""

    base_model: str = setting(
        "stabilityai/stable-diffusion-2-1-base", "Base model: a hub id or a local folder."
    )
    controlnet: str = setting(
        "thibaud/controlnet-sd21-depth-diffusers", "Depth ControlNet: a hub id or a local folder."
    )
    lora: str | None = setting(
        None, "Species LoRA: a folder or .safetensors file (diffusers format)."
    )
    guidance_scale: float = setting(100.0, "Classifier-free guidance scale.")
    conditioning_scale: float = 1.0  # ControlNet residual scale
    schedule: str = setting(
        "paper",
        f"Timestep schedule: {' or '.join(SCHEDULES)}, or a table like '0.2-0.98@600,0.075-0.15'.",
    )
    # Renders are resized to this before VAE encoding (a multiple of the VAE's factor, 8).
    resolution: int = setting(512, "Image size given to the VAE.", option="--sds-resolution")


SDS_DEFAULTS = SdsConfig()
