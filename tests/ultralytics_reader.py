"""Reads YOLO datasets with Ultralytics' own parser, in a process of its own: importing
Ultralytics sets process-wide state (OMP_NUM_THREADS, numpy's and torch's print options,
warning filters) that the rest of the test session must not inherit. Offline: the caller
sets YOLO_CONFIG_DIR (a temporary folder) and YOLO_OFFLINE, and the network is closed here.

    python tests/ultralytics_reader.py OUT.pkl DATA.yaml SPLIT [DATA.yaml SPLIT ...]

OUT.pkl holds, per (yaml, split), what ``check_det_dataset`` made of the yaml (``nc``,
``names``, the split's folder) and per image what ``YOLODataset`` gives a trainer (file,
classes, polygons, image, one mask per polygon at image resolution), and the network calls
that were tried (tests/test_label_consumers.py wants none).
"""

from __future__ import annotations

import os
import pickle
import shutil
import socket
import sys
from pathlib import Path

network_calls: list[str] = []


def no_network(*args, **kwargs):
    network_calls.append(repr(args))
    raise OSError("the network is closed in the tests")


def read(yaml_file: str, split: str, hyp) -> dict:
    import numpy as np
    from PIL import Image
    from ultralytics.data import YOLODataset
    from ultralytics.data.utils import check_det_dataset

    data = check_det_dataset(yaml_file, autodownload=False)
    folder = Path(data[split])
    with Image.open(next(folder.glob("*.png"))) as first:
        size = max(first.size)  # square renders: no letterbox padding
    views = YOLODataset(
        img_path=str(folder), imgsz=size, augment=False, hyp=hyp, data=data, task="segment"
    )
    images = []
    for i, label in enumerate(views.labels):
        item = views[i]
        images.append(
            {
                "file": label["im_file"],
                "classes": label["cls"].reshape(-1).astype(int).tolist(),
                "polygons": [np.asarray(s, np.float64) for s in label["segments"]],
                "image": item["img"].numpy().transpose(1, 2, 0),
                "masks": item["masks"].numpy().astype(bool),
            }
        )
    return {"nc": data["nc"], "names": dict(data["names"]), "folder": str(folder), "images": images}


def main(out: str, pairs: list[tuple[str, str]]) -> None:
    config = Path(os.environ["YOLO_CONFIG_DIR"])
    assert os.environ.get("YOLO_OFFLINE") == "1"
    socket.getaddrinfo = no_network
    socket.create_connection = no_network
    socket.socket.connect = no_network
    from matplotlib import font_manager
    from ultralytics.cfg import get_cfg
    from ultralytics.utils import USER_CONFIG_DIR

    assert Path(USER_CONFIG_DIR).is_relative_to(config), USER_CONFIG_DIR
    # check_det_dataset looks for its plotting font here before it downloads one.
    shutil.copyfile(font_manager.findfont("DejaVu Sans"), Path(USER_CONFIG_DIR) / "Arial.ttf")
    # Masks at image resolution (mask_ratio 1), one per polygon (no overlap encoding).
    hyp = get_cfg(overrides={"mask_ratio": 1, "overlap_mask": False})
    results = {pair: read(*pair, hyp) for pair in pairs}
    with open(out, "wb") as f:
        pickle.dump({"results": results, "network_calls": network_calls}, f)


if __name__ == "__main__":
    args = sys.argv[1:]
    main(args[0], list(zip(args[1::2], args[2::2], strict=True)))
