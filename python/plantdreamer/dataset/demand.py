"""What a dataset's worker asks of a machine (CPUs, GPUs, custom resources), and whether
a machine holds it: the same arithmetic for the local pool (``local_pool.py``), a local
Ray and a Ray cluster's nodes (``engine.py``). Torch-free and Ray-free: every refusal here
comes before anything starts."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from plantdreamer.errors import InputError
from plantdreamer.pipeline.settings.config import GenerateConfig

# CPUs a plant takes unless --cpus-per-plant says otherwise. With SDS the diffusion model
# runs on the GPU but rendering (the native rasterizer) stays on the CPU.
DEFAULT_CPUS = {"sds": 2.0, "none": 1.0}
DEFAULT_GPUS = {"sds": 1.0, "none": 0.0}
# Resources Ray counts itself; a plant asks for them with their own options.
_BUILT_IN_RESOURCES = {"CPU": "--cpus-per-plant", "GPU": "--gpus-per-plant"}
_RAY_OWNED_RESOURCES = ("memory", "object_store_memory")
RESOURCE_PRECISION = 1e-4  # Ray's finest fraction of a resource
_ADVICE = "use --cpus-per-plant / --gpus-per-plant / --plants-per-gpu"
LOCAL_MORE = ", or --address to run on a Ray cluster"  # the way out of a refusal here


@dataclass(frozen=True)
class Demand:
    """Resources of one worker (a plant, or a packed group of plants); its rasterizer
    gets ``threads`` threads, torch its plants' ``torch-threads`` (the same bits whatever
    the worker's CPU share)."""

    cpus: float
    gpus: float
    custom: tuple[tuple[str, float], ...] = field(default=())

    @property
    def threads(self) -> int:
        return max(1, math.floor(self.cpus))

    def thread_env(self) -> dict[str, str]:
        """The worker's thread counts, as environment variables its libraries read."""
        return {"RAYON_NUM_THREADS": str(self.threads), "OMP_NUM_THREADS": str(self.threads)}

    def needs(self) -> dict[str, float]:
        return {"CPU": self.cpus, "GPU": self.gpus, **dict(self.custom)}

    def describe(self) -> str:
        parts = [f"{self.cpus:g} CPU", f"{self.gpus:g} GPU"]
        parts += [f"{v:g} {k}" for k, v in self.custom]
        return ", ".join(parts)


def custom_resources(given: dict[str, str]) -> dict[str, float]:
    """``--resource NAME=AMOUNT`` values, checked before anything starts: positive finite
    amounts of resources that are not Ray's own."""
    out = {}
    for name, text in given.items():
        if name in _BUILT_IN_RESOURCES:
            raise InputError(f"--resource {name}: use {_BUILT_IN_RESOURCES[name]} for {name}")
        if name in _RAY_OWNED_RESOURCES or name.startswith("node:"):
            raise InputError(f"--resource {name}: Ray manages {name!r} itself")
        try:
            amount = float(text)
        except ValueError:
            raise InputError(f"--resource {name}={text}: the amount must be a number") from None
        if not (math.isfinite(amount) and amount >= RESOURCE_PRECISION):
            raise InputError(
                f"--resource {name}={text}: the amount must be a number >= {RESOURCE_PRECISION}"
            )
        out[name] = amount
    return out


def plant_demand(
    cfg: GenerateConfig,
    cpus_per_plant: float | None,
    gpus_per_plant: float | None,
    custom: dict[str, float],
    plants_per_gpu: int = 1,
) -> Demand:
    """What one worker asks for: a plant's GPUs and ``plants_per_gpu`` plants' CPUs (a
    packed group renders its plants in parallel on the host)."""
    cpus = cpus_per_plant if cpus_per_plant is not None else DEFAULT_CPUS[cfg.sds.guidance]
    gpus = gpus_per_plant if gpus_per_plant is not None else DEFAULT_GPUS[cfg.sds.guidance]
    if not (math.isfinite(cpus) and math.isfinite(gpus)) or cpus < 1 or gpus < 0:
        raise InputError("a plant needs at least 1 CPU and a non-negative number of GPUs")
    return Demand(cpus * plants_per_gpu, gpus, tuple(sorted(custom.items())))


def fits(demand: Demand, node: dict[str, float]) -> int:
    """Workers of ``demand`` that fit on a machine with these resources."""
    need = demand.needs()
    return min((math.floor(node.get(k, 0.0) / v + 1e-9) for k, v in need.items() if v), default=1)


def node_text(resources: dict[str, float]) -> str:
    keys = [k for k in sorted(resources) if not k.startswith(("node:", "memory", "object_"))]
    return ", ".join(f"{resources[k]:g} {k}" for k in keys)


def check_fits(demands: set[Demand], nodes: list[dict[str, float]], where: str, more: str) -> None:
    """InputError naming the first demand no node of ``nodes`` holds. ``where``: "this
    machine" (one node) or "Ray" (a cluster's nodes); ``more``: the way out beyond
    smaller demands."""
    for demand in sorted(demands, key=lambda d: (d.cpus, d.gpus, d.custom)):
        if not any(fits(demand, node) for node in nodes):
            has = "; ".join(node_text(n) for n in nodes)
            subject = "this machine cannot" if where == "this machine" else f"no {where} node can"
            held = "it has" if where == "this machine" else "nodes have"
            raise InputError(
                f"{subject} run a worker needing {demand.describe()} ({held}: {has}); "
                f"{_ADVICE}{more}"
            )
