"""Loading Stable Diffusion, the depth ControlNet and their parts with diffusers.

Models come from a Hugging Face hub id (served from the local cache, downloaded only when
the hub can be reached) or from a local folder laid out like the hub repository. Anything
missing -- offline with an empty cache, a wrong id, a partial folder -- raises
``ModelNotFoundError`` naming what was looked for and how to provide it. No call here can
hang on the network: when ``HF_HUB_OFFLINE`` is set, or a short HTTP probe finds the hub
unreachable, everything is loaded with ``local_files_only=True``.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from plantdreamer.errors import InputError, ModelNotFoundError
from plantdreamer.guidance.config import SDS_DEFAULTS

DEFAULT_BASE_MODEL = SDS_DEFAULTS.base_model
DEFAULT_CONTROLNET = SDS_DEFAULTS.controlnet

# Subfolders of a diffusers Stable Diffusion repository we need, with their config file.
_BASE_PARTS = {
    "unet": "config.json",
    "vae": "config.json",
    "text_encoder": "config.json",
    "tokenizer": None,  # vocab.json + merges.txt, or tokenizer.json
    "scheduler": "scheduler_config.json",
}
_WEIGHT_SUFFIXES = (".safetensors", ".bin")


@dataclass
class DiffusionComponents:
    """The models SDS needs; any diffusers/transformers objects of the right kind."""

    unet: Any
    controlnet: Any
    vae: Any
    text_encoder: Any
    tokenizer: Any
    scheduler: Any

    def prepare(
        self, device: torch.device, dtype: torch.dtype, vae_dtype: torch.dtype | None = None
    ) -> DiffusionComponents:
        """Move the networks to ``device``/``dtype`` (the VAE to ``vae_dtype`` if given),
        eval mode, frozen (in place)."""
        for model in (self.unet, self.controlnet, self.vae, self.text_encoder):
            target = vae_dtype if (model is self.vae and vae_dtype is not None) else dtype
            model.to(device=device)
            if next(model.parameters()).dtype != target:  # loaded models already match
                model.to(dtype=target)
            model.eval()
            model.requires_grad_(False)
        if device.type == "cuda":  # NHWC convolutions: 18.1 -> 16.1 ms (bench_networks.py)
            for model in (self.unet, self.controlnet):
                model.to(memory_format=torch.channels_last)
        return self


def stable_diffusion_pipeline(parts: DiffusionComponents):  # type: ignore[no-untyped-def]
    """A diffusers ``StableDiffusionPipeline`` of ``parts`` (no safety checker)."""
    from diffusers import StableDiffusionPipeline

    return StableDiffusionPipeline(
        vae=parts.vae,
        text_encoder=parts.text_encoder,
        tokenizer=parts.tokenizer,
        unet=parts.unet,
        scheduler=parts.scheduler,
        safety_checker=None,
        feature_extractor=None,
        requires_safety_checker=False,
    )


def save_components(parts: DiffusionComponents, path: str | Path) -> tuple[Path, Path]:
    """Write ``parts`` in the hub's folder layout under ``path``: ``base/`` like
    ``stabilityai/stable-diffusion-2-1-base`` and ``controlnet/`` like
    ``thibaud/controlnet-sd21-depth-diffusers``. Returns (base_model_dir, controlnet_dir)."""
    root = Path(path)
    base, control = root / "base", root / "controlnet"
    stable_diffusion_pipeline(parts).save_pretrained(base)
    parts.controlnet.save_pretrained(control)
    return base, control


def resolve_device(device: str | torch.device | None) -> torch.device:
    """The device the networks run on: CUDA when usable, else the CPU, unless given.

    A device that cannot work (a typo, ``cuda`` without a usable GPU, ``cuda:3`` on a
    one-GPU machine) raises InputError naming it, before any model is built.
    """
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        resolved = torch.device(device)
    except (RuntimeError, TypeError, ValueError):
        raise InputError(f"unknown device {device!r}; use cpu, cuda or cuda:N") from None
    if resolved.type == "cpu":
        return resolved
    if resolved.type != "cuda":
        raise InputError(f"device {device!r} is not supported; use cpu, cuda or cuda:N")
    if not torch.cuda.is_available():
        raise InputError(f"device {device!r}: no usable CUDA GPU on this machine")
    count = torch.cuda.device_count()
    if resolved.index is not None and resolved.index >= count:
        raise InputError(f"device {device!r}: this machine has {count} CUDA device(s)")
    return resolved


def make_cuda_deterministic() -> None:
    """Process-wide settings under which the CUDA networks give bit-identical results run to
    run (same seed, same inputs): a fixed cuBLAS workspace (read when cuBLAS first runs),
    deterministic cuDNN algorithms and no autotuning, and PyTorch's deterministic kernels
    where it has them (a warning, not an error, for any op without one). SDS backpropagates
    through the VAE encoder, so its attention also runs on the math kernel
    (``deterministic_attention``)."""
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.backends.cudnn.benchmark = False
    torch.backends.cudnn.deterministic = True
    torch.use_deterministic_algorithms(True, warn_only=True)


def deterministic_attention(device: torch.device):  # type: ignore[no-untyped-def]
    """A context in which scaled-dot-product attention on CUDA takes the math kernel, whose
    backward has a fixed summation order (the fused kernels' backward may not)."""
    from contextlib import nullcontext

    if device.type != "cuda":
        return nullcontext()
    from torch.nn.attention import SDPBackend, sdpa_kernel

    return sdpa_kernel(SDPBackend.MATH)


# The VAE encoder is the one network SDS backpropagates through; its backward pass in fp16
# can overflow into the render gradients (tests/test_half_precision.py shows a case).
DEFAULT_VAE_DTYPE: torch.dtype = getattr(torch, SDS_DEFAULTS.vae_dtype)


def network_dtypes(device: torch.device) -> dict[str, torch.dtype]:
    """The dtype each SDS network runs in on ``device`` with the default settings."""
    dtype = resolve_dtype(None, device)
    return {"unet": dtype, "controlnet": dtype, "text_encoder": dtype, "vae": DEFAULT_VAE_DTYPE}


def resolve_dtype(dtype: torch.dtype | str | None, device: torch.device) -> torch.dtype:
    """fp16 on CUDA, fp32 elsewhere, unless given."""
    if dtype is None:
        return torch.float16 if device.type == "cuda" else torch.float32
    if isinstance(dtype, str):
        resolved = getattr(torch, dtype, None)
        if not isinstance(resolved, torch.dtype):
            raise ValueError(f"unknown dtype {dtype!r}")
        return resolved
    return dtype


def hub_offline() -> bool:
    """True when the user asked for offline mode (read at call time, not import time)."""
    value = os.environ.get("HF_HUB_OFFLINE") or os.environ.get("TRANSFORMERS_OFFLINE") or ""
    return value.strip().lower() in {"1", "true", "yes", "on"}


def hub_reachable(timeout: float = 3.0) -> bool:
    """Whether the hub's API answers (HTTP 200 with JSON) within ``timeout`` seconds.

    An HTTP request rather than a TCP connect: sandboxes and proxies often accept any TCP
    connection. Runs in a daemon thread, so a slow DNS lookup cannot block past the timeout.
    """
    import json
    import urllib.request

    endpoint = os.environ.get("HF_ENDPOINT", "https://huggingface.co").rstrip("/")
    result: list[bool] = []

    def probe() -> None:
        try:
            with urllib.request.urlopen(f"{endpoint}/api/models?limit=1", timeout=timeout) as r:
                result.append(r.status == 200 and isinstance(json.loads(r.read(65536)), list))
        except (OSError, ValueError):
            result.append(False)

    thread = threading.Thread(target=probe, daemon=True)
    thread.start()
    thread.join(timeout + 0.5)
    return bool(result and result[0])


def local_files_only(identifiers: list[str]) -> bool:
    """Whether loading must stay on this machine (offline, unreachable hub, local folders)."""
    if all(Path(i).is_dir() for i in identifiers):
        return True
    return hub_offline() or not hub_reachable()


def _has_weights(folder: Path) -> bool:
    return folder.is_dir() and any(p.suffix in _WEIGHT_SUFFIXES for p in folder.iterdir())


def missing_base_parts(folder: Path) -> list[str]:
    """What a local Stable Diffusion folder lacks (empty if it looks complete)."""
    missing = []
    for part, config in _BASE_PARTS.items():
        sub = folder / part
        if part == "tokenizer":
            if not ((sub / "tokenizer.json").is_file() or (sub / "vocab.json").is_file()):
                missing.append("tokenizer/vocab.json (or tokenizer.json)")
            continue
        if config is not None and not (sub / config).is_file():
            missing.append(f"{part}/{config}")
        if part != "scheduler" and not _has_weights(sub):
            missing.append(f"{part}/ weights (*.safetensors or *.bin)")
    return missing


def missing_controlnet_parts(folder: Path) -> list[str]:
    missing = []
    if not (folder / "config.json").is_file():
        missing.append("config.json")
    if not _has_weights(folder):
        missing.append("weights (diffusion_pytorch_model.safetensors or .bin)")
    return missing


def how_to_provide(identifier: str, what: str, option: str) -> str:
    """The remedy sentence of a ModelNotFoundError."""
    name = identifier.rstrip("/").split("/")[-1] or "model"
    local = f"models/{name}"
    return (
        f"to provide the {what}, download it on a machine with internet access "
        f"(`hf download {identifier} --local-dir {local}`; older huggingface_hub: "
        f"`huggingface-cli download ...`), copy the folder here and pass `{option} {local}`, "
        "or point HF_HOME at a Hugging Face cache that holds it"
    )


def model_not_found(
    identifier: str, what: str, option: str, offline: bool, detail: str = ""
) -> ModelNotFoundError:
    path = Path(identifier)
    if path.exists():
        where = f"local folder {str(path)!r} is incomplete"
    elif offline:
        where = (
            f"{identifier!r} is neither a local folder nor in the Hugging Face cache, and the hub "
            "is not reachable (offline)"
        )
    else:
        where = f"{identifier!r} is neither a local folder nor a loadable hub repository"
    msg = f"{what} not found: {where}"
    if detail:
        msg += f" ({detail})"
    return ModelNotFoundError(f"{msg}; {how_to_provide(identifier, what, option)}")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:300] if text else type(exc).__name__


def _load_errors() -> tuple[type[BaseException], ...]:
    from huggingface_hub.errors import HFValidationError

    return (OSError, HFValidationError)


# The file at the top of each kind of model's snapshot: it finds the snapshot in the cache.
MODEL_MARKERS = {"base": "unet/config.json", "controlnet": "config.json"}


def check_model_present(identifier: str, kind: str) -> None:
    """Raises ModelNotFoundError when the ``kind`` ("base" or "controlnet") model cannot be
    there, found without loading it or reaching the network: a local folder that lacks a
    part, a path that does not exist, or (offline) a hub id the cache does not hold."""
    what, option = (
        ("Stable Diffusion base model", "--base-model")
        if kind == "base"
        else ("depth ControlNet", "--controlnet")
    )
    from plantdreamer.guidance.weight_files import damaged_model_files

    folder = Path(identifier)
    if folder.is_dir():
        missing = missing_base_parts(folder) if kind == "base" else missing_controlnet_parts(folder)
        if missing:
            raise model_not_found(identifier, what, option, True, "missing " + ", ".join(missing))
        if damaged := damaged_model_files(folder, kind):
            raise model_not_found(identifier, what, option, True, "; ".join(damaged))
        return
    if folder.exists():
        raise model_not_found(identifier, what, option, True, "it is a file, not a folder")
    # A hub id is "owner/name"; anything else that names no folder is a path that is not there.
    parts = identifier.split("/")
    if identifier.startswith((".", "/", "~")) or len(parts) != 2 or not all(parts):
        raise model_not_found(identifier, what, option, False, "no such folder")
    if hub_offline():
        from huggingface_hub import try_to_load_from_cache

        marker = MODEL_MARKERS[kind]
        found = try_to_load_from_cache(identifier, marker)
        if not isinstance(found, str):
            raise model_not_found(identifier, what, option, True)
        snapshot = Path(found).parents[len(Path(marker).parts) - 1]
        if damaged := damaged_model_files(snapshot, kind):
            raise model_not_found(identifier, what, option, True, "; ".join(damaged))


def load_base_model(
    base_model: str, dtype: torch.dtype, offline: bool, vae_dtype: torch.dtype | None = None
) -> tuple[Any, Any, Any, Any, Any]:
    """(unet, vae, text_encoder, tokenizer, scheduler) of a Stable Diffusion repository."""
    from diffusers import AutoencoderKL, DDIMScheduler, UNet2DConditionModel
    from transformers import CLIPTextModel, CLIPTokenizer

    what, option = "Stable Diffusion base model", "--base-model"
    folder = Path(base_model)
    if folder.is_dir():
        missing = missing_base_parts(folder)
        if missing:
            raise model_not_found(
                base_model, what, option, offline, "missing " + ", ".join(missing)
            )
    elif folder.exists():
        raise model_not_found(base_model, what, option, offline, "it is a file, not a folder")
    try:
        tokenizer = CLIPTokenizer.from_pretrained(
            base_model, subfolder="tokenizer", local_files_only=offline
        )
        text_encoder = CLIPTextModel.from_pretrained(
            base_model, subfolder="text_encoder", dtype=dtype, local_files_only=offline
        )
        vae = AutoencoderKL.from_pretrained(
            base_model, subfolder="vae", dtype=vae_dtype or dtype, local_files_only=offline
        )
        unet = UNet2DConditionModel.from_pretrained(
            base_model, subfolder="unet", dtype=dtype, local_files_only=offline
        )
        # DDIM's configuration carries the training noise schedule (alphas_cumprod), which is
        # all SDS needs; the repository's own scheduler class does not matter.
        scheduler = DDIMScheduler.from_pretrained(
            base_model, subfolder="scheduler", local_files_only=offline
        )
    except _load_errors() as exc:
        raise model_not_found(base_model, what, option, offline, _first_line(exc)) from exc
    return unet, vae, text_encoder, tokenizer, scheduler


def load_controlnet(controlnet: str, dtype: torch.dtype, offline: bool) -> Any:
    from diffusers import ControlNetModel

    what, option = "depth ControlNet", "--controlnet"
    folder = Path(controlnet)
    if folder.is_dir():
        missing = missing_controlnet_parts(folder)
        if missing:
            raise model_not_found(
                controlnet, what, option, offline, "missing " + ", ".join(missing)
            )
    try:
        return ControlNetModel.from_pretrained(controlnet, dtype=dtype, local_files_only=offline)
    except _load_errors() as exc:
        raise model_not_found(controlnet, what, option, offline, _first_line(exc)) from exc


def load_components(
    base_model: str = DEFAULT_BASE_MODEL,
    controlnet: str = DEFAULT_CONTROLNET,
    dtype: torch.dtype = torch.float32,
    offline: bool | None = None,
    vae_dtype: torch.dtype | None = None,
) -> DiffusionComponents:
    """Load every model SDS needs (on the CPU, in ``dtype``); see the module docstring."""
    if offline is None:
        offline = local_files_only([str(base_model), str(controlnet)])
    unet, vae, text_encoder, tokenizer, scheduler = load_base_model(
        str(base_model), dtype, offline, vae_dtype
    )
    control = load_controlnet(str(controlnet), dtype, offline)
    return DiffusionComponents(
        unet=unet,
        controlnet=control,
        vae=vae,
        text_encoder=text_encoder,
        tokenizer=tokenizer,
        scheduler=scheduler,
    )
