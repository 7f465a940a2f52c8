"""The settings of SDS guidance: the one place their defaults are written.

``SdsConfig`` is the guidance section of ``GenerateConfig`` (its fields are the CLI options),
and ``StableDiffusionDepthGuidance`` takes its keyword defaults from ``SDS_DEFAULTS``, so the
CLI, ``run.json`` and the guidance agree. Imports nothing heavy (the CLI reads it at start-up).
"""

from __future__ import annotations

from dataclasses import dataclass

from plantdreamer.settings import setting

# Names of the built-in timestep schedules (``schedules.BUILTIN_SCHEDULES``; a test checks).
SCHEDULES = ("paper", "released")
# Depth normalisation rules (``guidance/depth.py``) and control-image resampling.
DEPTH_RULES = ("stretch", "released", "stretch-lift")
RESIZE_MODES = ("bilinear", "nearest")
# Where the depth map of the initial Gaussians is rendered: at the SDS size the ControlNet
# reads, or at the training render's size and then resized (the released code).
DEPTH_SIZES = ("sds", "render")
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


GUIDANCES = ("sds", "none")
NETWORK_DTYPES = ("auto", "float32", "float16")


@dataclass
class SdsConfig:
    """Stable Diffusion 2.1 + depth ControlNet score distillation, as in the paper: the
    guidance section of a generation config (``plantdreamer generate --help``)."""

    guidance: str = setting("sds", "Guidance: SDS, or none (no optimisation).", choices=GUIDANCES)
    base_model: str = setting(
        "stabilityai/stable-diffusion-2-1-base", "Base model: a hub id or a local folder."
    )
    controlnet: str = setting(
        "thibaud/controlnet-sd21-depth-diffusers", "Depth ControlNet: a hub id or a local folder."
    )
    lora: str | None = setting(
        None, "Species LoRA: a folder or .safetensors file (diffusers format)."
    )
    # Classifier-free guidance, standard form (see sds.py).
    guidance_scale: float = setting(100.0, "Classifier-free guidance scale.")
    conditioning_scale: float = setting(1.0, "ControlNet residual scale.")
    schedule: str = setting(
        "paper",
        f"Timestep schedule: {' or '.join(SCHEDULES)}, or a table like '0.2-0.98@600,0.075-0.15'.",
    )
    # Renders are resized to this before VAE encoding.
    resolution: int = setting(512, "Image size given to the VAE.", option="--sds-resolution")
    prompt_template: str | None = setting(
        None,
        "Prompt with a {species} field.",
        default_text=f"the LoRA's lora.json, else '{DEFAULT_PROMPT_TEMPLATE}'",
    )
    negative_prompt: str = setting(
        RELEASED_NEGATIVE_PROMPT, "The unconditional CFG prompt.", default_text="the authors'"
    )
    depth_rule: str = setting("stretch", "Depth-map normalisation.", choices=DEPTH_RULES)
    erosion_distance: str = setting(
        "camera",
        "Depth erosion kernel chosen from the camera distance r, or from the camera-to-world "
        "matrix's norm sqrt(r^2 + 4) (released: 5 px below r = 4.58, never 3 px).",
        choices=EROSION_DISTANCES,
    )
    depth_size: str = setting(
        "sds",
        "Size the depth conditioning is rendered and cleaned at: sds (the ControlNet's own "
        "size, --sds-resolution; no resize) or render (the training render's size, then "
        "resized by --control-resize, as the released code). docs/scaling.md measures both.",
        choices=DEPTH_SIZES,
    )
    control_resize: str = setting(
        "bilinear",
        "Resizing of the depth control image (with --depth-size render).",
        choices=RESIZE_MODES,
    )
    network_dtype: str = setting(
        "auto", "UNet and ControlNet precision (auto: float16 on CUDA).", choices=NETWORK_DTYPES
    )
    # float32 on every device until GPU figures choose otherwise (docs/full_size_models.md).
    vae_dtype: str = setting(
        "float32",
        "VAE precision (its backward pass makes the render gradients).",
        choices=VAE_DTYPES,
    )
    device: str | None = setting(
        None, "Where the networks run: cpu, cuda or cuda:N (default: CUDA when usable, else CPU)."
    )


# The guidance's own keyword defaults (a template is always set there).
SDS_DEFAULTS = SdsConfig(prompt_template=DEFAULT_PROMPT_TEMPLATE)
