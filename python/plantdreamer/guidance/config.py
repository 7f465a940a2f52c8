"""The settings of SDS guidance: the one place their defaults are written.

``StableDiffusionDepthGuidance`` takes its keyword defaults from ``SDS_DEFAULTS``, and the
generation config's guidance fields default to the same values, so the CLI, ``run.json``
and the guidance agree. Imports nothing heavy (the CLI reads it at start-up).
"""

from __future__ import annotations

from dataclasses import dataclass

# Names of the built-in timestep schedules (``schedules.BUILTIN_SCHEDULES``; a test checks).
SCHEDULES = ("paper", "released")


@dataclass(frozen=True)
class SdsConfig:
    """Stable Diffusion 2.1 + depth ControlNet score distillation, as in the paper."""

    base_model: str = "stabilityai/stable-diffusion-2-1-base"
    controlnet: str = "thibaud/controlnet-sd21-depth-diffusers"
    lora: str | None = None
    guidance_scale: float = 100.0  # classifier-free guidance (standard form, see sds.py)
    conditioning_scale: float = 1.0  # ControlNet residual scale
    schedule: str = "paper"
    resolution: int = 512  # renders are resized to this before VAE encoding


SDS_DEFAULTS = SdsConfig()
