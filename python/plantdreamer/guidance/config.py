"""The settings of SDS guidance: the one place their defaults are written.

``StableDiffusionDepthGuidance`` takes its keyword defaults from ``SDS_DEFAULTS``, and the
generation config's guidance fields default to the same values, so the CLI, ``run.json``
and the guidance agree. Imports nothing heavy (the CLI reads it at start-up).
"""

from __future__ import annotations

from dataclasses import dataclass

# Names of the built-in timestep schedules (``schedules.BUILTIN_SCHEDULES``; a test checks).
SCHEDULES = ("paper", "released")
# Depth normalisation rules (``guidance/depth.py``) and control-image resampling.
DEPTH_RULES = ("stretch", "released", "stretch-lift")
RESIZE_MODES = ("bilinear", "nearest")
# What picks the depth erosion kernel: the camera distance, or the released code's
# Frobenius norm of the 4x4 camera-to-world matrix (``guidance/depth.py``).
EROSION_DISTANCES = ("camera", "c2w-norm")
# Precisions the VAE may run in (encode and its backward, which makes the render gradients).
VAE_DTYPES = ("float32", "bfloat16", "float16")

PAPER_PROMPT_TEMPLATE = "a {species} plant in a pot"
RELEASED_PROMPT_TEMPLATE = "A photo of {species} plants"
# Generation and LoRA training share one template unless a LoRA records its own.
DEFAULT_PROMPT_TEMPLATE = PAPER_PROMPT_TEMPLATE
# The authors' released negative prompt (their generation config), word for word.
RELEASED_NEGATIVE_PROMPT = (
    "ugly, bad anatomy, blurry, pixelated obscure, unnatural colors, poor lighting, dull, "
    "and unclear, cropped, lowres, low quality, artifacts, duplicate, morbid, mutilated, "
    "poorly drawn face, deformed, dehydrated, bad proportions, unfocused"
)


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
    negative_prompt: str = RELEASED_NEGATIVE_PROMPT  # the unconditional CFG branch
    prompt_template: str = DEFAULT_PROMPT_TEMPLATE  # with a {species} field
    control_resize: str = "bilinear"  # of the depth control image: bilinear or nearest
    # float32 on every device until GPU figures choose otherwise (docs/full_size_models.md).
    vae_dtype: str = "float32"


SDS_DEFAULTS = SdsConfig()
