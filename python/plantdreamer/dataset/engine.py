"""Ray for the dataset: joining a cluster, or starting a private Ray on this machine.

With ``--address auto|HOST:PORT`` the command joins an existing cluster and leaves it
running. With ``--address local`` it starts a Ray on this machine and stops it with the
command: every process it starts listens on 127.0.0.1 only (no dashboard), token
authentication on, the token checked first (``ray_token.py``); a start that cannot promise
this is refused. Without an address no Ray starts: plants run on the local pool
(``local_pool.py``; ``workers.py`` says why). Whatever Ray raises while it starts or is
joined becomes one line (``RayStartError``), never its traceback.
"""

from __future__ import annotations

import ipaddress
import logging
import os
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from plantdreamer.dataset.demand import Demand, check_fits, fits
from plantdreamer.dataset.ray_token import CHOOSE_RAY, check_token
from plantdreamer.dataset.tasks import first_line
from plantdreamer.errors import InputError, PlantDreamerError

RAY_MISSING = (
    "`plantdreamer dataset --address` runs on Ray, which is not installed; install it with "
    "`pip install 'plantdreamer[cluster]'` (or `pip install 'ray>=2.9'`), or leave out "
    "--address to run on this machine without Ray"
)
LOCAL_RAY = "local"  # --address local: a private Ray on this machine (Ray's own word)
LOCAL_HOST = "127.0.0.1"
JOIN_PROBE_S = 5.0  # how long a cluster's address may take to answer before a join
# Where Ray logs, on every local start, that it turned token authentication on by itself
# ("Set RAY_AUTH_MODE=disabled to opt out"): the instance is ours, on 127.0.0.1, and stops
# with the command, so the warning only tells a user about a choice that is not theirs.
RAY_AUTH_LOGGER = "ray._private.authentication.authentication_token_setup"
# Ray swaps a node address of 127.0.0.1 for the machine's outward one (its gRPC servers then
# listen on every interface, its runtime-env agent on that address) unless this is off; it
# is read when ``ray`` is imported, and by the processes Ray starts.
RAY_CLUSTER_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


class RayStartError(PlantDreamerError):
    """Ray could not be started or joined; the message is Ray's first line."""


def import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise InputError(RAY_MISSING) from None
    return ray


def connect(address: str, local_cpus: int | None, local_gpus: int = 0) -> bool:
    """Starts (``address`` "local") or joins Ray; True when this call started it (and
    should stop it)."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    common: dict[str, Any] = {"log_to_driver": False, "logging_level": "WARNING"}
    # ray.init installs a SIGTERM handler that exits at once (status 1, a native stack
    # dump, no checkpoints); the caller's handler, which stops cleanly, is put back.
    previous = signal.getsignal(signal.SIGTERM)
    try:
        if address == LOCAL_RAY:
            check_token(local=True)
            try:
                with _quiet_logger(RAY_AUTH_LOGGER), _loopback_node(ray):
                    ray.init(
                        address="local",
                        num_cpus=local_cpus or os.cpu_count() or 1,
                        num_gpus=local_gpus,
                        include_dashboard=False,
                        _node_ip_address=LOCAL_HOST,
                        **common,
                    )
            except (KeyboardInterrupt, SystemExit, PlantDreamerError):
                raise
            except Exception as exc:  # Ray's own start-up failure: its first line
                ray.shutdown()
                raise RayStartError(f"the local Ray did not start ({first_line(exc)})") from None
            node = ray.util.get_node_ip_address()
            if not is_loopback(node):
                ray.shutdown()
                raise InputError(
                    f"the local Ray would listen on {node}, not on this machine alone; "
                    + CHOOSE_RAY
                )
        else:
            check_token(local=False)
            try:
                ray.init(address=address, **common)
            except (KeyboardInterrupt, SystemExit, PlantDreamerError):
                raise
            except Exception as exc:
                ray.shutdown()
                raise RayStartError(
                    f"cannot join the Ray cluster at {address} ({first_line(exc)})"
                ) from None
    except SystemExit:  # SIGTERM while Ray starts, through Ray's handler: a clean stop
        ray.shutdown()
        raise KeyboardInterrupt from None
    finally:
        if threading.current_thread() is threading.main_thread() and previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return True


def check_reachable(address: str) -> None:
    """Something answers at the cluster's address (``auto`` as Ray finds it): Ray's own
    join waits minutes on an address where nothing listens."""
    import socket

    try:
        from ray._private.services import canonicalize_bootstrap_address, parse_address

        written = canonicalize_bootstrap_address(address) if address == "auto" else address
        parsed = parse_address(written or "")
    except Exception:  # an address Ray reads otherwise (ray://): Ray's join says
        return
    if parsed is None:
        return
    host, port = parsed
    try:
        socket.create_connection((host, int(port)), timeout=JOIN_PROBE_S).close()
    except (OSError, ValueError) as exc:
        raise RayStartError(
            f"cannot join the Ray cluster at {address}: nothing answers at {host}:{port} "
            f"({getattr(exc, 'strerror', None) or exc}); start the cluster or check --address"
        ) from None


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
    """Fails now, with the reason, if no node of the cluster could ever run a worker (Ray
    would wait)."""
    check_fits(demands, _alive_nodes(), "Ray", " or add nodes")


def capacity(demand: Demand) -> int:
    """How many workers of ``demand`` the cluster's live nodes hold at once."""
    return sum(fits(demand, node) for node in _alive_nodes())


def alive_nodes() -> int:
    return len(_alive_nodes())


def _alive_nodes() -> list[dict[str, float]]:
    return [n["Resources"] for n in import_ray().nodes() if n.get("Alive")]
