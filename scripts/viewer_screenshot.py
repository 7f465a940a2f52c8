"""Makes docs/images/viewer_bean.png and viewer_bean_labels.png: `plantdreamer view` in
headless Chromium (software WebGL) on a 5000-Gaussian L-System bean (seed 1), coloured by
its colours and by its organ labels.

Run from the repository root: python scripts/viewer_screenshot.py
Needs the viewer extra (viser) and Debian's chromium.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from PIL import Image  # noqa: E402

from headless_browser import HeadlessChromium, find_chromium  # noqa: E402
from plantdreamer.viewer.scene import load_scene  # noqa: E402
from plantdreamer.viewer.server import start_viewer  # noqa: E402
from viewer_plants import shows_plant, write_labelled_plant_ply  # noqa: E402

# Closes the "software WebGL" notice that a browser without a GPU shows.
CLOSE_NOTICES = "document.querySelectorAll('.mantine-Notification-closeButton')" + (
    ".forEach(b => b.click())"
)


def screenshot(scene, rgbs, show_labels: bool, port: int = 8093):
    chromium = find_chromium()
    if chromium is None:
        raise SystemExit("no Chromium: apt-get install chromium")
    viewer = start_viewer(scene, port, show_labels)
    try:
        with HeadlessChromium(chromium, viewer.url) as browser:
            deadline = time.monotonic() + 240
            while shows_plant(browser.screenshot(), rgbs) is not None:
                if time.monotonic() > deadline:
                    raise SystemExit("the plant did not appear")
                time.sleep(2)
            browser.evaluate(CLOSE_NOTICES)
            time.sleep(3)  # the notice's closing animation and a few more frames
            return browser.screenshot()
    finally:
        viewer.stop()


def main() -> None:
    out = ROOT / "docs" / "images"
    with tempfile.TemporaryDirectory() as tmp:
        ply = Path(tmp) / "bean.ply"
        rgbs = write_labelled_plant_ply(ply)
        scene = load_scene(ply)
        Image.fromarray(screenshot(scene, rgbs, False)).save(out / "viewer_bean.png")
        labels = screenshot(scene, scene.label_rgbs(), True)
        Image.fromarray(labels).save(out / "viewer_bean_labels.png")
    print(f"wrote {out / 'viewer_bean.png'} and {out / 'viewer_bean_labels.png'}")


if __name__ == "__main__":
    main()
