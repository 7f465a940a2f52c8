"""`plantdreamer view` in a real browser: headless Chromium (software WebGL) must show the
plant. Chromium is Debian's `chromium` package; `make test` installs it when run as root."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from headless_browser import HeadlessChromium, find_chromium
from plantdreamer.viewer.server import check_port_free
from viewer_plants import shows_plant, write_labelled_plant_ply

pytest.importorskip("viser", reason="the viewer extra is not installed (pip install viser)")

pytestmark = pytest.mark.slow

CHROMIUM = find_chromium()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ViewerProcess:
    """`plantdreamer view PLY --port N` in a child process; stopped with Ctrl-C (SIGINT)."""

    def __init__(self, ply: Path, port: int, *extra: str) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "plantdreamer", "view", str(ply), "--port", str(port), *extra],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line)
            if "press Ctrl-C" in line:
                return
        raise AssertionError(f"the viewer exited early: {''.join(self.lines)}")

    def interrupt(self) -> tuple[int, str]:
        self.process.send_signal(signal.SIGINT)
        out, _ = self.process.communicate(timeout=60)
        return self.process.returncode, "".join(self.lines) + out

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.communicate(timeout=60)


def wait_for_plant(browser: HeadlessChromium, rgbs: np.ndarray, timeout_s: float = 240.0):
    """The first screenshot that shows the plant, or the last one and why it does not."""
    deadline = time.monotonic() + timeout_s
    while True:
        image = browser.screenshot()
        problem = shows_plant(image, rgbs)
        if problem is None or time.monotonic() > deadline:
            return image, problem
        time.sleep(2.0)


@pytest.mark.skipif(
    CHROMIUM is None,
    reason="no Chromium found: install Debian's chromium (`make test` does when run as root)",
)
def test_browser_shows_the_plant(tmp_path):
    ply = tmp_path / "bean.ply"
    rgbs = write_labelled_plant_ply(ply)
    port = free_port()
    viewer = ViewerProcess(ply, port)
    try:
        assert f"http://127.0.0.1:{port}" in "".join(viewer.lines)
        with HeadlessChromium(CHROMIUM, f"http://127.0.0.1:{port}") as browser:
            image, problem = wait_for_plant(browser, rgbs)
        shot = Path(os.environ.get("PLANTDREAMER_SCREENSHOT", tmp_path / "viewer.png"))
        Image.fromarray(image).save(shot)
        assert problem is None, f"{problem} (screenshot: {shot})"
        code, out = viewer.interrupt()
        assert code == 0, out
        assert "viewer stopped" in out and "Traceback" not in out
    finally:
        viewer.kill()
    check_port_free(port)  # the server really stopped: nothing listens there any more
