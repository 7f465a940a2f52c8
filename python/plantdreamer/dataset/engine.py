"""Ray for the dataset: joining or starting an instance, and what each plant asks of it.

Without an address, Ray starts on this machine and stops with the command: every process
it starts listens on 127.0.0.1 only (no dashboard), token authentication on, the token file
readable by its owner alone; a start that cannot promise this is refused. With
``--address auto|HOST:PORT`` the command joins an existing cluster and leaves it running.
"""

from __future__ import annotations

import ipaddress
import logging
import math
import os
import signal
import stat
import tempfile
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer.errors import InputError
from plantdreamer.pipeline.settings.config import GenerateConfig

RAY_MISSING = (
    "`plantdreamer dataset` runs on Ray, which is not installed; install it with "
    "`pip install 'plantdreamer[cluster]'` (or `pip install 'ray>=2.9'`)"
)
# CPUs a plant takes unless --cpus-per-plant says otherwise. With SDS the diffusion model
# runs on the GPU but rendering (the native rasterizer) stays on the CPU.
DEFAULT_CPUS = {"sds": 2.0, "none": 1.0}
DEFAULT_GPUS = {"sds": 1.0, "none": 0.0}
LOCAL_HOST = "127.0.0.1"
# Where Ray logs, on every local start, that it turned token authentication on by itself
# ("Set RAY_AUTH_MODE=disabled to opt out"): the instance is ours, on 127.0.0.1, and stops
# with the command, so the warning only tells a user about a choice that is not theirs.
RAY_AUTH_LOGGER = "ray._private.authentication.authentication_token_setup"
# Ray swaps a node address of 127.0.0.1 for the machine's outward one (its gRPC servers then
# listen on every interface, its runtime-env agent on that address) unless this is off; it
# is read when ``ray`` is imported, and by the processes Ray starts.
RAY_CLUSTER_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
RAY_AUTH_MODE_ENV = "RAY_AUTH_MODE"
# Where Ray reads its token (the first set wins), else ~/.ray/auth_token, which
# ray.init would write readable by every user.
RAY_TOKEN_ENVS = ("RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")
CHOOSE_RAY = (
    "start Ray yourself (e.g. `ray start --head --node-ip-address 127.0.0.1`) and pass "
    "--address to use it as it is"
)


def import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise InputError(RAY_MISSING) from None
    return ray


@dataclass(frozen=True)
class Demand:
    """Ray resources of one worker (a plant, or a packed group of plants); its rasterizer
    gets ``threads`` threads, torch its plants' ``torch-threads`` (the same bits whatever
    the worker's CPU share)."""

    cpus: float
    gpus: float
    custom: tuple[tuple[str, float], ...] = field(default=())

    @property
    def threads(self) -> int:
        return max(1, math.floor(self.cpus))

    def actor_options(self, max_retries: int, extra_env: dict[str, str]) -> dict[str, Any]:
        """A worker actor's options: a lost worker is restarted and its unit run again (up
        to ``max_retries`` times, resuming from the checkpoints); a plant's own error never
        is."""
        env = {"RAYON_NUM_THREADS": str(self.threads), "OMP_NUM_THREADS": str(self.threads)}
        return {
            "num_cpus": self.cpus,
            "num_gpus": self.gpus,
            "resources": dict(self.custom),
            "max_restarts": -1,
            "max_task_retries": max_retries,
            "runtime_env": {"env_vars": {**env, **extra_env}},
        }

    def describe(self) -> str:
        parts = [f"{self.cpus:g} CPU", f"{self.gpus:g} GPU"]
        parts += [f"{v:g} {k}" for k, v in self.custom]
        return ", ".join(parts)


# Resources Ray counts itself; a plant asks for them with their own options.
_BUILT_IN_RESOURCES = {"CPU": "--cpus-per-plant", "GPU": "--gpus-per-plant"}
_RAY_OWNED_RESOURCES = ("memory", "object_store_memory")
RESOURCE_PRECISION = 1e-4  # Ray's finest fraction of a resource


def custom_resources(given: dict[str, str]) -> dict[str, float]:
    """``--resource NAME=AMOUNT`` values, checked before Ray starts: positive finite amounts
    of resources that are not Ray's own."""
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


def connect(address: str | None, local_cpus: int | None) -> bool:
    """Starts or joins Ray; True when this call started it (and should stop it)."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    common: dict[str, Any] = {"log_to_driver": False, "logging_level": "WARNING"}
    # ray.init installs a SIGTERM handler that exits at once (status 1, a native stack
    # dump, no checkpoints); the caller's handler, which stops cleanly, is put back.
    previous = signal.getsignal(signal.SIGTERM)
    try:
        if address is None:
            _check_token_auth()
            with _quiet_logger(RAY_AUTH_LOGGER), _loopback_node(ray):
                ray.init(
                    address="local",
                    num_cpus=local_cpus or os.cpu_count() or 1,
                    include_dashboard=False,
                    _node_ip_address=LOCAL_HOST,
                    **common,
                )
            node = ray.util.get_node_ip_address()
            if not is_loopback(node):
                ray.shutdown()
                raise InputError(
                    f"the local Ray would listen on {node}, not on this machine alone; "
                    + CHOOSE_RAY
                )
        else:
            try:
                ray.init(address=address, **common)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise InputError(f"cannot join the Ray cluster at {address}: {exc}") from None
    except SystemExit:  # SIGTERM while Ray starts, through Ray's handler: a clean stop
        ray.shutdown()
        raise KeyboardInterrupt from None
    finally:
        if threading.current_thread() is threading.main_thread() and previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return True


def is_loopback(host: str) -> bool:
    """127.0.0.0/8 or ::1, also as an IPv4-mapped IPv6 address (``::ffff:127.0.0.1``)."""
    try:
        ip = ipaddress.ip_address(host.strip("[]"))
    except ValueError:
        return False
    mapped = getattr(ip, "ipv4_mapped", None)
    return (mapped or ip).is_loopback


@contextmanager
def _loopback_node(ray: Any) -> Iterator[None]:
    """Within the block, Ray keeps 127.0.0.1 as the node's address, in this process and the
    ones it starts (which inherit the environment); a later join of a remote cluster from
    this process finds both as they were."""
    from ray._private import ray_constants  # the switch, when ray was imported before

    env, switch = os.environ.get(RAY_CLUSTER_ENV), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[RAY_CLUSTER_ENV] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = switch
        if env is None:
            os.environ.pop(RAY_CLUSTER_ENV, None)
        else:
            os.environ[RAY_CLUSTER_ENV] = env


def _check_token_auth() -> None:
    """Token authentication stays on for the local Ray: processes that run any code they are
    sent listen on loopback, where every user of the machine reaches them. A mode other than
    token in the environment is refused, not passed on; the default token file is made (or
    kept) readable by its owner alone."""
    mode = os.environ.get(RAY_AUTH_MODE_ENV)
    if mode is not None and mode.lower() != "token":
        raise InputError(
            f"{RAY_AUTH_MODE_ENV}={mode} would start the local Ray without token "
            "authentication (any user of this machine could run code as you); unset it or "
            f"set {RAY_AUTH_MODE_ENV}=token, or {CHOOSE_RAY}"
        )
    if not any(os.environ.get(name) for name in RAY_TOKEN_ENVS):
        private_token(Path.home() / ".ray" / "auth_token")


def private_token(path: Path) -> None:
    """Makes Ray's token file at ``path`` (a new random token, mode 0600) unless it exists;
    one that other users can read is made 0600, with a warning."""
    if path.exists():
        mode = stat.S_IMODE(path.stat().st_mode)
        if mode & 0o077:
            path.chmod(0o600)
            warnings.warn(
                f"the Ray token file {path} was readable by other users (mode {mode:o}); "
                "made it 0600",
                stacklevel=2,
            )
        return
    import secrets

    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=".auth_token.", dir=path.parent)  # mode 0600
    try:
        with os.fdopen(fd, "w") as f:
            f.write(secrets.token_hex(32))  # Ray's own kind of token: 256 random bits
            f.flush()
            os.fsync(f.fileno())
        os.link(name, path)  # never over a token another start wrote meanwhile
    except FileExistsError:
        pass
    finally:
        os.unlink(name)


@contextmanager
def _quiet_logger(name: str) -> Iterator[None]:
    """The logger ``name`` passes only errors within the block."""
    logger = logging.getLogger(name)
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def check_feasible(demands: set[Demand]) -> None:
    """Fails now, with the reason, if no node could ever run a worker (Ray would wait)."""
    nodes = _alive_nodes()
    for demand in demands:
        if not any(_fits(demand, node) for node in nodes):
            raise InputError(
                f"no Ray node can run a worker needing {demand.describe()} (nodes have: "
                + "; ".join(_node_text(n) for n in nodes)
                + "); use --cpus-per-plant / --gpus-per-plant / --plants-per-gpu or add nodes"
            )


def capacity(demand: Demand) -> int:
    """How many workers of ``demand`` the cluster's live nodes hold at once."""
    return sum(_fits(demand, node) for node in _alive_nodes())


def _alive_nodes() -> list[dict[str, float]]:
    return [n["Resources"] for n in import_ray().nodes() if n.get("Alive")]


def _fits(demand: Demand, node: dict[str, float]) -> int:
    """Workers of ``demand`` that fit on a node with these resources."""
    need = {"CPU": demand.cpus, "GPU": demand.gpus, **dict(demand.custom)}
    return min((math.floor(node.get(k, 0.0) / v + 1e-9) for k, v in need.items() if v), default=1)


def _node_text(resources: dict[str, float]) -> str:
    keys = [k for k in sorted(resources) if not k.startswith(("node:", "memory", "object_"))]
    return ", ".join(f"{resources[k]:g} {k}" for k in keys)
