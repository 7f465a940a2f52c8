"""`plantdreamer view`: what the browser is sent (colours, covariances, labels), the server's
start and stop, and its one-line errors. The real-browser check is test_viewer_browser.py."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import urllib.request

import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.cloud import PointCloud
from plantdreamer.gaussians import Gaussians, sh_dc_to_rgb
from plantdreamer.io import read_splat_ply, write_ply, write_splat_ply
from plantdreamer.viewer.scene import (
    LABEL_COLORS,
    UNLABELLED_COLOR,
    covariances,
    load_scene,
    scene_from_gaussians,
)
from plantdreamer.viewer.server import check_port_free
from viewer_plants import shows_plant, write_labelled_plant_ply


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_covariances_are_rotated_squared_scales(random_gaussians):
    g = random_gaussians(64, degree=1)
    cov = covariances(g).astype(np.float64)
    np.testing.assert_allclose(cov, cov.transpose(0, 2, 1), atol=1e-12)
    # Eigenvalues are the squared scales, whatever the rotation.
    eig = np.sort(np.linalg.eigvalsh(cov), axis=1)
    want = np.sort(np.exp(2.0 * g.log_scales.astype(np.float64)), axis=1)
    np.testing.assert_allclose(eig, want, rtol=1e-4, atol=1e-10)
    # A 90-degree turn about z (w = x = cos 45, unnormalised on purpose) swaps x and y.
    one = Gaussians(
        means=np.zeros((1, 3), np.float32),
        quats=np.array([[2.0, 0.0, 0.0, 2.0]], np.float32),
        log_scales=np.log(np.array([[1.0, 2.0, 3.0]], np.float32)),
        opacity_logits=np.zeros(1, np.float32),
        sh=np.zeros((1, 1, 3), np.float32),
    )
    np.testing.assert_allclose(covariances(one)[0], np.diag([4.0, 1.0, 9.0]), atol=1e-5)


def test_scene_colours_opacities_and_labels(tmp_path):
    rgbs = write_labelled_plant_ply(tmp_path / "bean.ply", n=800)
    scene = load_scene(tmp_path / "bean.ply")
    g = read_splat_ply(tmp_path / "bean.ply")
    assert len(scene) == 800 and scene.name == "bean.ply"
    np.testing.assert_allclose(scene.rgbs, np.clip(sh_dc_to_rgb(g.sh[:, 0]), 0, 1))
    np.testing.assert_allclose(scene.rgbs, rgbs, atol=1e-6)
    np.testing.assert_allclose(scene.opacities[:, 0], 0.9, atol=1e-6)
    assert scene.labels is not None and set(np.unique(scene.labels)) <= {1, 2, 3, 4}
    assert (scene.labels == 1).sum() > 100  # leaves
    colours = scene.label_rgbs()
    for label, colour in LABEL_COLORS.items():
        np.testing.assert_allclose(
            colours[scene.labels == label],
            np.float32(colour)[None].repeat((scene.labels == label).sum(), 0),
        )


def test_unknown_and_missing_labels_get_the_unlabelled_colour(tmp_path, random_gaussians):
    g = random_gaussians(4)
    scene = scene_from_gaussians(g, "x.ply", np.array([-1, 0, 2, 9], np.int32))
    colours = scene.label_rgbs()
    np.testing.assert_allclose(colours[[0, 3]], np.float32([UNLABELLED_COLOR] * 2))
    np.testing.assert_allclose(colours[1], LABEL_COLORS[0])
    np.testing.assert_allclose(colours[2], LABEL_COLORS[2])
    # A file without a label property: no labels, and the toggle has nothing to show.
    write_splat_ply(tmp_path / "plain.ply", g)
    plain = load_scene(tmp_path / "plain.ply")
    assert plain.labels is None
    with pytest.raises(ValueError):
        plain.label_rgbs()


def test_pixel_check_can_fail(tmp_path):
    rgbs = write_labelled_plant_ply(tmp_path / "bean.ply", n=500)
    blank = np.full((400, 600, 3), 255, dtype=np.uint8)
    assert "centre" in shows_plant(blank, rgbs)
    corner = blank.copy()
    corner[:90, :90] = (rgbs[0] * 255).astype(np.uint8)
    assert shows_plant(corner, rgbs) is not None
    centred = blank.copy()
    patch = rgbs[:100].reshape(10, 10, 3).repeat(10, axis=0).repeat(10, axis=1)
    centred[150:250, 250:350] = (patch * 255).astype(np.uint8)
    assert shows_plant(centred, rgbs) is None
    blue = blank.copy()
    blue[150:250, 250:350] = (40, 60, 220)  # something in the middle, not in plant colours
    assert shows_plant(blue, rgbs) is not None


def test_non_splat_ply_is_one_error_line(tmp_path):
    cloud = PointCloud(positions=np.random.default_rng(0).normal(size=(10, 3)).astype(np.float32))
    write_ply(tmp_path / "cloud.ply", cloud)
    result = CliRunner().invoke(main, ["view", str(tmp_path / "cloud.ply")])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "not a 3DGS PLY" in lines[0]


def test_missing_viser_says_what_to_install(tmp_path, monkeypatch, random_gaussians):
    write_splat_ply(tmp_path / "g.ply", random_gaussians(5))
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser -> ImportError
    result = CliRunner().invoke(main, ["view", str(tmp_path / "g.ply")])
    assert result.exit_code == 1
    assert result.output.startswith("error: the viewer needs viser")
    assert "pip install 'plantdreamer[viewer]'" in result.output


viser = pytest.importorskip("viser", reason="the viewer extra is not installed")


def test_port_in_use_is_refused(tmp_path, random_gaussians):
    write_splat_ply(tmp_path / "g.ply", random_gaussians(5))
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = CliRunner().invoke(main, ["view", str(tmp_path / "g.ply"), "--port", str(port)])
    assert result.exit_code == 1
    assert result.output.strip() == (
        f"error: port {port} on 127.0.0.1 is in use; choose another with --port"
    )


def test_server_serves_the_page_and_gui(tmp_path):
    from plantdreamer.viewer.server import start_viewer

    write_labelled_plant_ply(tmp_path / "bean.ply", n=300)
    scene = load_scene(tmp_path / "bean.ply")
    port = free_port()
    viewer = start_viewer(scene, port, show_labels=True)
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
        assert viewer.server.get_host() == "127.0.0.1" and viewer.url.endswith(f":{port}")
        handles = viewer.controls
        assert handles["File"].value == "bean.ply"
        assert handles["Gaussians"].value == "300"
        assert handles["Colour by"].value == "organ labels" and not handles["Colour by"].disabled
    finally:
        viewer.stop()
    check_port_free(port)  # stopped: nothing listens there any more


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# SIGINT with an inherited "ignore" is how a shell starts a background job.
@pytest.mark.parametrize(
    ("stop_signal", "preexec"),
    [(signal.SIGINT, None), (signal.SIGINT, _ignore_sigint), (signal.SIGTERM, None)],
    ids=["ctrl-c", "ctrl-c-in-a-background-job", "sigterm"],
)
def test_a_stop_signal_stops_the_viewer_cleanly(tmp_path, random_gaussians, stop_signal, preexec):
    write_splat_ply(tmp_path / "g.ply", random_gaussians(50))
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "plantdreamer", "view", str(tmp_path / "g.ply"), "--labels",
         "--port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, preexec_fn=preexec,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        lines = []
        for line in proc.stdout:
            lines.append(line)
            if "press Ctrl-C" in line:
                break
        text = "".join(lines)
        assert "note: g.ply has no 'label' property; showing colours" in text
        assert f"viewing g.ply (50 Gaussians) at http://127.0.0.1:{port}" in text
        # A connection closed before any request (browsers open such speculative ones) is
        # not an error for the user: no traceback.
        socket.create_connection(("127.0.0.1", port), timeout=30).close()
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as page:
            assert page.status == 200
        proc.send_signal(stop_signal)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, out
    assert "viewer stopped" in out and "Traceback" not in out


def test_a_signal_sent_the_moment_the_viewer_says_press_ctrl_c_stops_it_cleanly(
    tmp_path, random_gaussians
):
    """A script that stops the viewer as soon as it says it is up: SIGTERM from inside the
    very echo of "press Ctrl-C to stop" (the handlers were installed after it, once)."""
    write_splat_ply(tmp_path / "g.ply", random_gaussians(50))
    script = (
        "import os, signal, sys\n"
        "from plantdreamer.viewer.server import view_file\n"
        "def echo(line):\n"
        "    print(line, flush=True)\n"
        "    if 'press Ctrl-C' in line:\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "view_file(sys.argv[1], int(sys.argv[2]), echo=echo)\n"
    )
    args = [sys.executable, "-c", script, str(tmp_path / "g.ply"), str(free_port())]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines()[-2:] == ["press Ctrl-C to stop", "viewer stopped"]


def test_non_finite_gaussians_are_dropped_with_a_warning(tmp_path, random_gaussians):
    from types import SimpleNamespace

    from plantdreamer.viewer.server import _frame_camera

    g = random_gaussians(3000)
    g.means[:10] = np.nan
    g.sh[10, 0, 1] = np.inf
    write_splat_ply(tmp_path / "nan.ply", g)
    with pytest.warns(UserWarning, match="11 of 3000 Gaussians have NaN or Inf"):
        scene = load_scene(tmp_path / "nan.ply")
    assert len(scene) == 2989 and np.isfinite(scene.centers).all()
    camera = SimpleNamespace()
    _frame_camera(camera, scene)
    assert np.isfinite(camera.position).all() and np.isfinite(camera.look_at).all()
    g.means[:] = np.nan
    write_splat_ply(tmp_path / "all_nan.ply", g)
    result = CliRunner().invoke(main, ["view", str(tmp_path / "all_nan.ply")])
    assert result.exit_code == 1 and "no Gaussian has finite parameters" in result.output


def test_a_float_label_column_with_whole_values_is_shown(tmp_path, random_gaussians):
    from plantdreamer import _core
    from plantdreamer.io import read_ply_columns

    write_splat_ply(tmp_path / "int.ply", random_gaussians(5))
    cols = read_ply_columns(tmp_path / "int.ply")
    cols["label"] = np.array([1, 2, 3, 4, -1], np.float32)
    fields = [([k], v) for k, v in cols.items()]
    _core.write_ply_vertex(str(tmp_path / "float.ply"), fields, True, [])
    scene = load_scene(tmp_path / "float.ply")
    assert scene.labels is not None and scene.labels.tolist() == [1, 2, 3, 4, -1]


def _http_status(port: int, host: str, path: str = "/", extra: str = "") -> int:
    """The status of a raw GET to 127.0.0.1:port sent with ``Host: host``."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as conn:
        conn.sendall(f"GET {path} HTTP/1.1\r\nHost: {host}\r\n{extra}\r\n".encode())
        return int(conn.recv(1024).split(b" ", 2)[1])


def test_only_loopback_hosts_and_the_viewers_own_page_are_answered(tmp_path, random_gaussians):
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    from plantdreamer.viewer.server import LoopbackGuard, start_viewer

    write_splat_ply(tmp_path / "g.ply", random_gaussians(50))
    port = free_port()
    viewer = start_viewer(load_scene(tmp_path / "g.ply"), port)
    own = f"127.0.0.1:{port}"
    socket_url, protocol = f"ws://{own}", f"viser-v{viser.__version__}"
    try:
        for host in (own, f"localhost:{port}", f"127.1.2.3:{port}", f"[::1]:{port}"):
            assert _http_status(port, host) == 200, host
        for host in ("evil.example", f"evil.example:{port}", f"127.0.0.1:{port + 1}",
                     f"192.0.2.1:{port}", f"127.0.0.1.evil.example:{port}"):  # fmt: skip
            assert _http_status(port, host) == 403, host
        with connect(socket_url, origin=f"http://{own}", subprotocols=[protocol]) as ws:
            assert ws.subprotocol == protocol and ws.recv(timeout=10)  # the scene arrives
        for origin in ("http://evil.example", f"http://localhost:{port}", "null", None):
            with pytest.raises(InvalidStatus, match="403"):
                connect(socket_url, origin=origin, subprotocols=[protocol], open_timeout=10)
        # A WebSocket whose Host is foreign (DNS rebinding), with a matching Origin.
        upgrade = ("Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n"
                   "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n")  # fmt: skip
        rebound = f"evil.example:{port}"
        assert _http_status(port, rebound, extra=upgrade + f"Origin: http://{rebound}\r\n") == 403
    finally:
        viewer.stop()
    assert not LoopbackGuard(80).allowed_host("[::1]:8080")
    assert LoopbackGuard(80).allowed_host("[::1]") and LoopbackGuard(80).allowed_host("localhost")
