"""Diffusion guidance: score distillation (SDS) with Stable Diffusion + depth ControlNet + LoRA.

Importing this package needs only torch; diffusers / transformers load when models are built.

- ``base``: the ``Guidance`` protocol, ``GuidanceOutput``, ``NoGuidance``, ``PhotometricGuidance``
- ``sds``: ``StableDiffusionDepthGuidance``
- ``schedules``: timestep schedules (paper, released code, user tables) and the clamp ramp
- ``prompts``: view-dependent prompts
- ``depth``: depth-map cleaning and the per-pose ``DepthConditioner``
- ``models``: loading from the hub or local folders, ``ModelNotFoundError`` messages
- ``lora_weights``: species LoRA files
- ``tiny``: tiny random-weight models for tests and benchmarks
"""

from plantdreamer.guidance.base import Guidance, GuidanceOutput, NoGuidance, PhotometricGuidance
from plantdreamer.guidance.depth import DepthCleaning, DepthConditioner, clean_depth
from plantdreamer.guidance.prompts import view_prompt
from plantdreamer.guidance.schedules import TimestepSchedule, make_schedule
from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
from plantdreamer.guidance.tiny import save_tiny_models, tiny_models

__all__ = [
    "DepthCleaning",
    "DepthConditioner",
    "Guidance",
    "GuidanceOutput",
    "NoGuidance",
    "PhotometricGuidance",
    "StableDiffusionDepthGuidance",
    "TimestepSchedule",
    "clean_depth",
    "make_schedule",
    "save_tiny_models",
    "tiny_models",
    "view_prompt",
]
