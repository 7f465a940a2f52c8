"""``render --transforms``: views at a transforms.json's cameras, named from its frames, and
the record of what a render wrote.

The files take their names from the frames, so no pattern finds them: ``rendered_views.json``
records each file a render wrote with the SHA-256 of its contents, added as each is
written. ``--overwrite`` deletes an earlier render's file only when the record names it
with the digest it still has: proof that the render wrote it and nothing changed it since.
A record naming another file (a user's, a path outside the folder), or a file changed since,
deletes nothing; a record that is not the render's (unreadable, another shape) proves
nothing.
"""

from __future__ import annotations

import os
from pathlib import Path, PurePath

import click

from plantdreamer.errors import InputError

VIEWS_RECORD = "rendered_views.json"


def view_files(views, transforms: str) -> list[str]:
    """Where each camera of a transforms.json is written in --out: its image's file name as
    a PNG, or, when two frames share a name (``cam0/0001.png``, ``cam1/0001.png``), its
    path relative to the transforms.json; refused when even those collide."""
    from plantdreamer.eval.datasets import _transforms_file

    flat = [f"{view.name}.png" for view in views]
    if len(set(flat)) == len(flat):
        return flat
    root = _transforms_file(Path(transforms)).parent
    files: dict[str, int] = {}
    for i, view in enumerate(views):
        relative = PurePath(os.path.relpath(view.image_path, root))
        name = relative.with_name(f"{view.name}.png").as_posix()
        if ".." in relative.parts or name in files:
            j = files.get(name, flat.index(flat[i]))
            raise InputError(
                f"{transforms}: frames {j} and {i} would both be written as {name}; give "
                "the frames distinct file names"
            )
        files[name] = i
    return list(files)


def proven_views(out: Path) -> list[str]:
    """The files of ``out`` an earlier render recorded with the digest they still have."""
    import json

    from plantdreamer.digests import file_digest

    try:
        record = json.loads((out / VIEWS_RECORD).read_text(encoding="utf-8"))
        digests = record["sha256"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    if not isinstance(digests, dict):
        return []
    proven = []
    for name, digest in digests.items():
        parts = PurePath(name).parts if isinstance(name, str) else ()
        if not parts or PurePath(name).is_absolute() or ".." in parts or name == VIEWS_RECORD:
            continue
        path = out / name
        try:
            if path.is_symlink() or not path.is_file() or file_digest(path) != digest:
                continue
        except OSError:
            continue
        proven.append(PurePath(name).as_posix())
    return proven


def render_dataset_views(gaussians, views, files: list[str], out: Path, background) -> None:
    """Renders ``views`` into ``files`` of ``out``, each recorded with its digest once
    written (a stopped render's record names what it wrote)."""
    import numpy as np
    import torch

    from plantdreamer.atomic import write_image, write_json
    from plantdreamer.digests import file_digest
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel

    model = GaussianModel(gaussians)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, str] = {}
    for view, name in zip(views, files, strict=True):
        with torch.no_grad():
            rgb = model.render([view.camera], background)[0][0].numpy()
        image = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        write_image(out / name, image)
        written[name] = file_digest(out / name)
        write_json(out / VIEWS_RECORD, {"files": list(written), "sha256": written})
    click.echo(f"wrote {len(views)} views of {len(model)} Gaussians to {out}")
