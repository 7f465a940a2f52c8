"""Serves a SplatScene to the browser with viser until Ctrl-C.

Only this module imports viser (the optional ``viewer`` extra). The server listens on
127.0.0.1 only and answers only requests whose ``Host`` is a loopback name with its port,
and WebSockets from its own page (a web page elsewhere in the browser, or a DNS-rebound
site, could otherwise read the model); the page shows the splats with viser's orbit
camera, the file name, the Gaussian count and a colours / organ-labels toggle.
"""

from __future__ import annotations

import contextlib
import io
import ipaddress
import logging
import math
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.stop_signals import stop_signals_handled
from plantdreamer.viewer import DEFAULT_PORT, HOST
from plantdreamer.viewer.scene import LABEL_NAMES, SplatScene

INSTALL_HINT = "pip install 'plantdreamer[viewer]' (or: pip install viser)"
COLOR_MODES = ("colours", "organ labels")
CAMERA_FOVY_DEG = 50.0


def import_viser() -> Any:
    """The viser module, or PlantDreamerError saying what to install."""
    try:
        import viser
    except ImportError:
        raise PlantDreamerError(
            f"the viewer needs viser, which is not installed: {INSTALL_HINT}"
        ) from None
    return viser


def check_port_free(port: int, host: str = HOST) -> None:
    """InputError when something already listens on ``host:port`` (viser would move on)."""
    if not 1 <= port <= 65535:
        raise InputError(f"port must be in 1..65535, got {port}")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        # The same option the server sets, so a port in TIME_WAIT is not reported as busy.
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError:
            raise InputError(
                f"port {port} on {host} is in use; choose another with --port"
            ) from None


def _not_a_failed_handshake(record: logging.LogRecord) -> bool:
    # Browsers open speculative connections and close them unused; the websocket library
    # logs each as an error with a traceback. Nothing failed for the user: drop them.
    return not record.getMessage().startswith("opening handshake failed")


LOOPBACK_NAMES = ("localhost", "[::1]")


class LoopbackGuard:
    """Refuses (403) a request whose ``Host`` is not a loopback name with the viewer's port,
    and a WebSocket whose ``Origin`` is not the page at that ``Host``.

    viser 1.1.1 has no option for either: inside ``ViserServer()`` it starts one
    ``websockets.asyncio.server.serve`` for its page and its socket, with its file server as
    the ``process_request`` hook. ``installed()`` wraps ``serve`` while the constructor runs
    (it returns once the server listens), so this check runs before viser's hook.
    """

    def __init__(self, port: int) -> None:
        self.port = port
        self.in_place = False

    def allowed_host(self, host: str) -> bool:
        name, _, port = host.rpartition(":")
        if host.endswith("]") or ":" not in host:  # no port: http's own, as browsers send it
            name, port = host, "80"
        if port != str(self.port):
            return False
        return name.lower() in LOOPBACK_NAMES or (
            name.startswith("127.") and _is_ipv4_loopback(name)
        )

    def refusal(self, connection: Any, request: Any) -> Any:
        hosts = request.headers.get_all("Host")
        if len(hosts) != 1 or not self.allowed_host(hosts[0]):
            return connection.respond(403, "Host not allowed\n")
        if "Upgrade" in request.headers and request.headers.get_all("Origin") != [
            f"http://{hosts[0]}"
        ]:
            return connection.respond(403, "Origin not allowed\n")
        return None

    @contextlib.contextmanager
    def installed(self) -> Any:
        import websockets.asyncio.server as ws

        serve = ws.serve

        def guarded_serve(*args: Any, process_request: Any = None, **kwargs: Any) -> Any:
            def checked(connection: Any, request: Any) -> Any:
                refused = self.refusal(connection, request)
                if refused is not None or process_request is None:
                    return refused
                return process_request(connection, request)

            self.in_place = True
            return serve(*args, process_request=checked, **kwargs)

        ws.serve = guarded_serve  # type: ignore[misc,assignment]
        try:
            yield
        finally:
            ws.serve = serve  # type: ignore[misc]


def _is_ipv4_loopback(name: str) -> bool:
    try:
        return ipaddress.IPv4Address(name).is_loopback
    except ValueError:
        return False


@dataclass
class RunningViewer:
    """A started viewer: its viser server and its GUI controls by label."""

    server: Any
    controls: dict[str, Any]

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.server.get_port()}"

    def stop(self) -> None:
        with contextlib.redirect_stdout(io.StringIO()):  # viser's own "stopped" line
            self.server.stop()


def start_viewer(
    scene: SplatScene, port: int = DEFAULT_PORT, show_labels: bool = False
) -> RunningViewer:
    """Starts a viser server showing ``scene`` on HOST:port; ``.stop()`` ends it."""
    viser = import_viser()
    check_port_free(port)
    handshake_log = logging.getLogger("websockets.server")
    if _not_a_failed_handshake not in handshake_log.filters:
        handshake_log.addFilter(_not_a_failed_handshake)
    guard = LoopbackGuard(port)
    with contextlib.redirect_stdout(io.StringIO()), guard.installed():  # viser's banner
        server = viser.ViserServer(host=HOST, port=port, label="plantdreamer", verbose=False)
    viewer = RunningViewer(server, {})
    if not guard.in_place:  # a viser that no longer serves through websockets.serve
        viewer.stop()
        raise PlantDreamerError("this viser version cannot be limited to this machine's pages")
    if server.get_port() != port:  # taken between the check and the bind
        viewer.stop()
        raise InputError(f"port {port} on {HOST} is in use; choose another with --port")
    server.scene.set_up_direction("+z")  # plants are z up
    _frame_camera(server.initial_camera, scene)
    nodes = {"colours": _add_splats(server, "/splats/colours", scene, scene.rgbs, True)}
    if scene.labels is not None:
        nodes["organ labels"] = _add_splats(
            server, "/splats/labels", scene, scene.label_rgbs(), False
        )
    viewer.controls.update(_add_gui(server, scene, nodes, show_labels))
    return viewer


def view_file(
    path: str, port: int = DEFAULT_PORT, show_labels: bool = False, echo: Callable = print
) -> None:
    """Serves the splat PLY at ``path`` until Ctrl-C: the whole ``plantdreamer view``."""
    view_files([path], port, show_labels, echo)


def view_files(
    paths: list[str], port: int = DEFAULT_PORT, show_labels: bool = False, echo: Callable = print
) -> None:
    """Serves the splat PLYs at ``paths`` side by side (a group's plants) until Ctrl-C."""
    from plantdreamer.viewer.scene import load_scene, side_by_side

    import_viser()  # say what to install before reading a large file
    scenes = [load_scene(path) for path in paths]
    if len(scenes) > 1:  # each plant.ply named by its folder
        scenes = [replace(s, name=Path(p).parent.name) for s, p in zip(scenes, paths, strict=True)]
    scene = side_by_side(scenes)
    if show_labels and scene.labels is None:
        echo(f"note: {scene.name} has no 'label' property; showing colours")
    serve_until_stopped(scene, port, show_labels, echo)
    echo("viewer stopped")


def serve_until_stopped(
    scene: SplatScene, port: int, show_labels: bool, echo: Callable, poll_s: float = 0.2
) -> None:
    """Starts the viewer, says where, and blocks until Ctrl-C or SIGTERM (stop_signals); then
    stops it. The handlers are in place before it starts, so a signal sent the moment
    "press Ctrl-C" shows (or while it starts) stops it cleanly."""
    stop = threading.Event()
    with stop_signals_handled(lambda _sig, _frame: stop.set()):
        viewer = start_viewer(scene, port, show_labels)
        try:
            echo(f"viewing {scene.name} ({len(scene):,} Gaussians) at {viewer.url}")
            echo("press Ctrl-C to stop")
            while not stop.wait(poll_s):
                pass
        finally:
            viewer.stop()


def _frame_camera(camera: Any, scene: SplatScene) -> None:
    """Looks at the bounding box centre from where the whole box fits the view."""
    lo, hi = scene.bounds()
    center = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-3)
    distance = 1.15 * radius / math.sin(math.radians(CAMERA_FOVY_DEG) / 2.0)
    azimuth, elevation = math.radians(-60.0), math.radians(20.0)
    direction = np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            math.sin(elevation),
        ]
    )
    camera.fov = math.radians(CAMERA_FOVY_DEG)
    camera.near = distance * 1e-3
    camera.far = distance * 100.0
    camera.look_at = tuple(float(v) for v in center)
    camera.position = tuple(float(v) for v in center + distance * direction)


def _add_splats(server: Any, name: str, scene: SplatScene, rgbs: np.ndarray, visible: bool):
    return server.scene.add_gaussian_splats(
        name,
        centers=scene.centers,
        covariances=scene.covariances,
        rgbs=rgbs,
        opacities=scene.opacities,
        visible=visible,
    )


def _add_gui(
    server: Any, scene: SplatScene, nodes: dict[str, Any], show_labels: bool
) -> dict[str, Any]:
    gui = server.gui
    name = gui.add_text("File", initial_value=scene.name, disabled=True)
    count = gui.add_text("Gaussians", initial_value=f"{len(scene):,}", disabled=True)
    has_labels = "organ labels" in nodes
    mode = gui.add_dropdown(
        "Colour by",
        COLOR_MODES,
        initial_value="organ labels" if show_labels and has_labels else "colours",
        disabled=not has_labels,
    )
    if not has_labels:
        gui.add_markdown("*No organ labels in this file (no `label` vertex property).*")
    else:
        legend = ", ".join(f"{i} {n}" for i, n in LABEL_NAMES.items())
        gui.add_markdown(f"Organ classes: {legend}; -1 none.")

    @mode.on_update
    def _(_event: Any) -> None:
        for key, node in nodes.items():
            node.visible = key == mode.value

    for key, node in nodes.items():
        node.visible = key == mode.value
    return {"File": name, "Gaussians": count, "Colour by": mode}
