"""Runs an Ultralytics command line (docs/datasets.md's ``yolo segment train ...``) in a process of
its own, with the network closed, and records the network calls that were tried. The
caller sets YOLO_CONFIG_DIR (a temporary folder) and YOLO_OFFLINE, as docs/datasets.md does; a
font is put where Ultralytics looks for its Arial.ttf first, as docs/datasets.md says
(otherwise it asks github.com for it once, and carries on without it offline).

    python tests/ultralytics_train.py OUT.json yolo segment train data=... [key=value ...]
"""

from __future__ import annotations

import json
import os
import socket
import sys

network_calls: list[str] = []


def no_network(*args, **kwargs):
    network_calls.append(repr(args))
    raise OSError("the network is closed in the tests")


def main(out: str, command: list[str]) -> None:
    assert os.environ.get("YOLO_OFFLINE") == "1" and os.environ.get("YOLO_CONFIG_DIR")
    socket.getaddrinfo = no_network
    socket.create_connection = no_network
    socket.socket.connect = no_network
    import shutil
    from pathlib import Path

    from matplotlib import font_manager
    from ultralytics.cfg import entrypoint
    from ultralytics.utils import USER_CONFIG_DIR

    shutil.copyfile(font_manager.findfont("DejaVu Sans"), Path(USER_CONFIG_DIR) / "Arial.ttf")
    entrypoint(" ".join(command))  # the command line, with its program name
    with open(out, "w") as f:
        json.dump({"network_calls": network_calls}, f)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
