"""``plantdreamer info``: what this installation has (versions, threads, accelerator)."""

from __future__ import annotations

import click


@click.command()
def info() -> None:
    """Show versions, CPU threads, the blending kernel, CUDA devices and network dtypes."""
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
    width = max(map(len, rows))
    for key, value in rows.items():
        click.echo(f"{key:<{width}}  {value}")


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
