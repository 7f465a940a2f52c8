"""What configs become on this machine: their inputs checked, the settings left open decided
once (``resolve_plants``: render size, network precision, prompt template, overlap) and
the guidance of plants trained together built. Each decided value is written into the
config, so run.json and the checkpoints record the value used and a resume keeps it."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.train_config import AUTO_RESOLUTION

if TYPE_CHECKING:
    from plantdreamer.guidance.base import Guidance
    from plantdreamer.guidance.models import DiffusionComponents
    from plantdreamer.pipeline.settings.group_settings import GroupSettings


def check_inputs(cfg: GenerateConfig) -> None:
    """Fails fast on inputs that cannot work, before any model is loaded or any output
    deleted (the models themselves: ``check_models``): ``requested``' torch-free
    checks, then torch's own look at a device that is named or that a guidance uses."""
    from plantdreamer.pipeline.settings.requested import check_config

    check_config(cfg)
    if cfg.sds.device is not None or cfg.sds.guidance != "none":
        from plantdreamer.guidance.models import resolve_device

        resolve_device(cfg.sds.device)


def check_models(cfg: GenerateConfig) -> None:
    """The models a config's guidance loads are there, looked at without loading them: the
    LoRA file (its header: LoRA weights of a whole safetensors file; and the template it
    recorded), and the base model and ControlNet when they are local folders or paths, each
    weight file's header read (offline, hub ids must be in the Hugging Face cache).
    ModelNotFoundError or InputError naming what is missing. A LoRA given is checked even
    when no guidance loads it (a wrong path is a mistake either way)."""
    sds = cfg.sds
    if sds.lora is not None:
        from plantdreamer.guidance.lora_weights import find_lora_file, recorded_template
        from plantdreamer.guidance.weight_files import check_lora_weights

        check_lora_weights(find_lora_file(sds.lora))  # its header read: it will load
        recorded_template(sds.lora)
    if sds.guidance == "none":
        return
    from plantdreamer.guidance.models import check_model_present

    check_model_present(sds.base_model, "base")
    check_model_present(sds.controlnet, "controlnet")


def resolve_plants(cfgs: Sequence[GenerateConfig]) -> None:
    """Decides every setting left open, for plants trained together, from their configs,
    their count and the machine: the render size and the networks' precision (by the
    networks' device), the prompt template (a LoRA's recorded one, else the default) and
    ``overlap`` (on for a group whose guidance runs on CUDA). Each value is written into
    each config, so run.json, group.json and the checkpoints record the value used, a
    resume keeps it, and ``--print-config`` (which calls this too) shows it. Nothing
    downstream decides them again."""
    from plantdreamer.guidance.models import resolve_device

    first = cfgs[0]  # the settings decided here are shared (config.PER_PLANT aside)
    cuda = resolve_device(first.sds.device).type == "cuda"
    overlap = resolve_overlap(first.train.overlap, first.sds.guidance != "none" and cuda, len(cfgs))
    template = lora_template(first.sds.lora) if first.sds.prompt_template is None else None
    for cfg in cfgs:
        sds = cfg.sds
        if cfg.train.resolution is None:
            cfg.train.resolution = AUTO_RESOLUTION["cuda" if cuda else "cpu"]
        if sds.network_dtype == "auto":
            sds.network_dtype = "float16" if cuda else "float32"
        if sds.prompt_template is None:
            sds.prompt_template = template
        cfg.train.overlap = "on" if overlap else "off"


def resolve_overlap(setting: str, cuda_guidance: bool, plants: int) -> bool:
    """``overlap``'s ``auto``: on for a group whose guidance runs on CUDA. On the CPU the
    networks and the renders share the same cores, so the halves cannot hide each other."""
    if setting == "auto":
        return cuda_guidance and plants > 1
    return setting == "on"


def lora_template(lora: str | None) -> str:
    """The prompt template a LoRA recorded in its ``lora.json``, else the default."""
    from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE
    from plantdreamer.guidance.lora_weights import recorded_template

    recorded = recorded_template(lora) if lora is not None else None
    return recorded or DEFAULT_PROMPT_TEMPLATE


def build_guidance(group: GroupSettings, components: DiffusionComponents | None = None) -> Guidance:
    """The guidance of plants trained together (their settings resolved by
    ``resolve_plants``); missing weights raise ModelNotFoundError here, before anything is
    written. ``components``: the networks of its base model, ControlNet and LoRA, already
    loaded (LoRA applied) by an earlier guidance of a worker that keeps them between
    plants (``guidance.parts``)."""
    from plantdreamer.guidance.base import NoGuidance
    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance

    sds = group.sds
    if sds.guidance == "none":
        return NoGuidance()
    if sds.prompt_template is None or sds.network_dtype == "auto":
        raise RuntimeError("the settings are decided by runtime.resolve_plants first")
    return StableDiffusionDepthGuidance(
        base_model=sds.base_model,
        controlnet=sds.controlnet,
        lora=sds.lora if components is None else None,
        components=components,
        species=group.prompt_name,
        guidance_scale=sds.guidance_scale,
        conditioning_scale=sds.conditioning_scale,
        schedule=sds.schedule,
        total_steps=group.train.steps,
        seed=group.noise_seed,
        resolution=sds.resolution,
        negative_prompt=sds.negative_prompt,
        prompt_template=sds.prompt_template,
        control_resize=sds.control_resize,
        dtype=sds.network_dtype,
        vae_dtype=sds.vae_dtype,
        device=sds.device,
    )
