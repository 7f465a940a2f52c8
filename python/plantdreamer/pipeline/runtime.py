"""What a config becomes on this machine: its inputs checked, the settings left open decided
(render size, network precision, prompt template; for plants trained together, overlap) and
its guidance built. Each decided value is written into the config, so run.json and the
checkpoints record the value used and a resume keeps it."""

from __future__ import annotations

import torch

from plantdreamer.guidance.base import Guidance
from plantdreamer.guidance.models import DiffusionComponents
from plantdreamer.pipeline.config import GenerateConfig
from plantdreamer.pipeline.train_config import AUTO_RESOLUTION


def check_inputs(cfg: GenerateConfig) -> None:
    """Fails fast on inputs that cannot work, before any model is loaded or any output
    deleted (the models themselves: ``check_models``): ``requested``' torch-free
    checks, then torch's own look at a device that is named or that a guidance uses."""
    from plantdreamer.pipeline.requested import check_config

    check_config(cfg)
    if cfg.sds.device is not None or cfg.sds.guidance != "none":
        from plantdreamer.guidance.models import resolve_device

        resolve_device(cfg.sds.device)


def check_models(cfg: GenerateConfig) -> None:
    """The models a config's guidance loads are there, looked at without loading them: the
    LoRA file (and the template it recorded), and the base model and ControlNet when they
    are local folders or paths (offline, hub ids must be in the Hugging Face cache).
    ModelNotFoundError or InputError naming what is missing. A LoRA given is checked even
    when no guidance loads it (a wrong path is a mistake either way)."""
    sds = cfg.sds
    if sds.lora is not None:
        from plantdreamer.guidance.lora_weights import find_lora_file, recorded_template

        find_lora_file(sds.lora)
        recorded_template(sds.lora)
    if sds.guidance == "none":
        return
    from plantdreamer.guidance.models import check_model_present

    check_model_present(sds.base_model, "base")
    check_model_present(sds.controlnet, "controlnet")


def resolve_runtime(cfg: GenerateConfig) -> None:
    """Fills the settings decided by the machine or the inputs, so run.json and the
    checkpoints record the values used: the training resolution, the network precision and
    the prompt template (a LoRA's recorded template, else the default)."""
    sds = cfg.sds
    # The networks' device (checked by check_inputs): CUDA when usable unless one is named.
    cuda = torch.cuda.is_available() if sds.device is None else sds.device.startswith("cuda")
    if cfg.train.resolution is None:
        cfg.train.resolution = AUTO_RESOLUTION["cuda" if cuda else "cpu"]
    if sds.network_dtype == "auto":
        sds.network_dtype = "float16" if cuda else "float32"
    if sds.prompt_template is None:
        sds.prompt_template = lora_template(sds.lora)


def resolve_overlap(setting: str, device: torch.device, plants: int) -> bool:
    """``overlap``'s ``auto``: on for a group whose guidance runs on CUDA. On the CPU the
    networks and the renders share the same cores, so the halves cannot hide each other."""
    if setting == "auto":
        return device.type == "cuda" and plants > 1
    return setting == "on"


def record_overlap(cfgs: list[GenerateConfig], device: torch.device) -> None:
    """Decides ``overlap`` for plants trained together by a guidance on ``device``, and
    writes the value used (``on`` or ``off``) into each plant's config."""
    on = resolve_overlap(cfgs[0].train.overlap, device, len(cfgs))
    for cfg in cfgs:
        cfg.train.overlap = "on" if on else "off"


def lora_template(lora: str | None) -> str:
    """The prompt template a LoRA recorded in its ``lora.json``, else the default."""
    from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE
    from plantdreamer.guidance.lora_weights import recorded_template

    recorded = recorded_template(lora) if lora is not None else None
    return recorded or DEFAULT_PROMPT_TEMPLATE


def build_guidance(cfg: GenerateConfig, components: DiffusionComponents | None = None) -> Guidance:
    """The guidance a config asks for; missing weights raise ModelNotFoundError here,
    before anything is written. ``components``: the networks of this config's base model,
    ControlNet and LoRA, already loaded (LoRA applied) by an earlier guidance of a worker
    that keeps them between plants (``guidance.parts``)."""
    from plantdreamer.guidance.base import NoGuidance
    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance

    sds = cfg.sds
    if sds.guidance == "none":
        return NoGuidance()
    return StableDiffusionDepthGuidance(
        base_model=sds.base_model,
        controlnet=sds.controlnet,
        lora=sds.lora if components is None else None,
        components=components,
        species=cfg.source.plant_name(),
        guidance_scale=sds.guidance_scale,
        conditioning_scale=sds.conditioning_scale,
        schedule=sds.schedule,
        total_steps=cfg.train.steps,
        seed=cfg.seed,
        resolution=sds.resolution,
        negative_prompt=sds.negative_prompt,
        prompt_template=sds.prompt_template or lora_template(sds.lora),
        control_resize=sds.control_resize,
        dtype=None if sds.network_dtype == "auto" else sds.network_dtype,
        vae_dtype=sds.vae_dtype,
        device=sds.device,
    )
