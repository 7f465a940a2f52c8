"""``plantdreamer info``: what this installation has (versions, threads, accelerator), and
with ``--check`` whether the weights, LoRAs and extras a run needs are present."""

from __future__ import annotations

import click

from plantdreamer.cli.options import config_options
from plantdreamer.pipeline.settings.config import GenerateConfig


@click.command()
@click.option(
    "--check",
    is_flag=True,
    help="Also say whether the diffusion weights, the LoRAs given and the optional extras "
    "are present, without downloading anything; exit 1 when a model or LoRA is missing.",
)
@config_options(GenerateConfig, ("base-model", "controlnet"))
@click.option(
    "--lora",
    "loras",
    multiple=True,
    metavar="PATH",
    help="A species LoRA (folder or .safetensors file) to check; repeat for several.",
)
def info(check: bool, base_model: str, controlnet: str, loras: tuple[str, ...]) -> None:
    """Show versions, CPU threads, the blending kernel, CUDA devices and network dtypes;
    with --check, whether the weights, LoRAs and optional extras are present."""
    import torch

    from plantdreamer import _core

    core = _core.info()
    rows = {
        "plantdreamer": core["version"],
        "native core": core["core_version"]
        + (" (debug build: slow)" if core["debug_build"] else ""),
        "cpu threads": str(core["threads"]),
        "blending kernel": core["blend_kernel"],
        "torch": torch.__version__,
    }
    rows.update(device_rows())
    missing = False
    if check:
        from plantdreamer.install_check import extra_rows, lora_row, model_row

        for what, ident, kind in (("base model", base_model, "base"),
                                  ("depth ControlNet", controlnet, "controlnet")):  # fmt: skip
            found, text = model_row(ident, kind)
            rows[what] = text
            missing |= not found
        for path in loras or (None,):
            found, text = lora_row(path)
            rows[f"LoRA {path}" if path else "LoRA"] = text
            missing |= not found
        rows.update(extra_rows())
    width = max(map(len, rows))
    for key, value in rows.items():
        click.echo(f"{key:<{width}}  {value}")
    if missing:
        raise SystemExit(1)


def device_rows() -> dict[str, str]:
    """One row per CUDA device (name, memory) and the dtype each network runs in on the
    default device (``generate --device`` picks another)."""
    import torch

    from plantdreamer.guidance.models import network_dtypes, resolve_device

    rows: dict[str, str] = {}
    if torch.cuda.is_available():
        for i in range(torch.cuda.device_count()):
            p = torch.cuda.get_device_properties(i)
            rows[f"cuda:{i}"] = f"{p.name}, {p.total_memory / 2**30:.1f} GiB"
    else:
        rows["cuda"] = "not available"
    device = resolve_device(None)
    for name, dtype in network_dtypes(device).items():
        rows[f"{name} dtype ({device.type})"] = str(dtype).removeprefix("torch.")
    return rows
