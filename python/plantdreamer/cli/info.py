"""``plantdreamer info``: what this installation has (versions, threads, accelerator)."""

from __future__ import annotations

import click


@click.command()
def info() -> None:
    """Show versions, CPU threads, the blending kernel and whether a CUDA GPU is usable."""
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
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "not available",
    }
    width = max(map(len, rows))
    for key, value in rows.items():
        click.echo(f"{key:<{width}}  {value}")
