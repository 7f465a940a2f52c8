"""The devices a run may name (``--device``), checked without torch.

``check_device`` refuses a device that cannot work with the same words as the check after
torch loads (``guidance.models.resolve_device``), but in milliseconds: a typo, a device type
other than the CPU or CUDA, ``cuda`` on a machine without a CUDA GPU, ``cuda:3`` on a
one-GPU machine. The GPUs are counted through NVIDIA's management library (NVML, loaded
with ctypes; no CUDA context is made, so a process that forks later is unharmed), limited
by ``CUDA_VISIBLE_DEVICES`` as the CUDA runtime reads it. A machine whose driver lists GPUs
that torch still cannot use (a CPU-only torch build) passes here and is refused, in the
same words, when torch loads.
"""

from __future__ import annotations

import ctypes
import os
import re

from plantdreamer.errors import InputError

__all__ = ["check_device", "cuda_device_count", "parse_device", "visible_gpu_ids"]

DEVICE_PATTERN = re.compile(r"(?P<type>[a-z_]+)(?::(?P<index>\d+))?")
# Device types torch knows besides the two a run can use (``torch.device`` accepts them).
OTHER_TORCH_DEVICES = frozenset(
    {"mps", "xpu", "xla", "meta", "hip", "ipu", "hpu", "mtia", "lazy", "vulkan", "mkldnn",
     "opengl", "opencl", "ideep", "fpga", "ve", "maia", "privateuseone"}
)  # fmt: skip
NVML_LIBRARY = "libnvidia-ml.so.1"


def parse_device(device: str) -> tuple[str, int | None]:
    """``cpu``, ``cuda`` or ``cuda:N`` as (type, index); InputError for anything else,
    in ``resolve_device``'s words."""
    match = DEVICE_PATTERN.fullmatch(device) if isinstance(device, str) else None
    if match is None or match["type"] not in {"cpu", "cuda"} | OTHER_TORCH_DEVICES:
        raise InputError(f"unknown device {device!r}; use cpu, cuda or cuda:N")
    if match["type"] not in ("cpu", "cuda"):
        raise InputError(f"device {device!r} is not supported; use cpu, cuda or cuda:N")
    index = match["index"]
    return match["type"], None if index is None else int(index)


def check_device(device: str | None) -> None:
    """Refuses a device this machine cannot run (None: the run picks CUDA when usable)."""
    if device is None:
        return
    kind, index = parse_device(device)
    if kind == "cpu":
        return
    count = cuda_device_count()
    if count == 0:
        raise InputError(f"device {device!r}: no usable CUDA GPU on this machine")
    if index is not None and index >= count:
        raise InputError(f"device {device!r}: this machine has {count} CUDA device(s)")


def cuda_device_count() -> int:
    """The CUDA GPUs this process may use: those the driver lists (NVML), as many as
    ``CUDA_VISIBLE_DEVICES`` lets through; 0 without NVIDIA's driver."""
    return len(visible_gpu_ids())


def visible_gpu_ids() -> list[str]:
    """The ``CUDA_VISIBLE_DEVICES`` entries of the GPUs this process may use, in the
    CUDA runtime's order (device 0 first); without the variable, ``0`` to ``N-1``."""
    present = _nvml_device_count()
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    if visible is None:
        return [str(i) for i in range(present)]
    ids: list[str] = []
    for entry in (e.strip() for e in visible.split(",")):
        # As the CUDA runtime reads it: the list ends at the first entry that names no
        # device (an index out of range, a negative number, a repeat, anything else).
        if entry.isdigit() and int(entry) < present and entry not in ids:
            ids.append(entry)
        elif entry.startswith(("GPU-", "MIG-")) and entry not in ids and len(ids) < present:
            ids.append(entry)
        else:
            break
    return ids


def _nvml_device_count() -> int:
    try:
        nvml = ctypes.CDLL(NVML_LIBRARY)
    except OSError:
        return 0  # no NVIDIA driver on this machine
    if nvml.nvmlInit_v2() != 0:
        return 0
    try:
        count = ctypes.c_uint(0)
        return int(count.value) if nvml.nvmlDeviceGetCount_v2(ctypes.byref(count)) == 0 else 0
    finally:
        nvml.nvmlShutdown()
