"""``make demo``: the main job on the known-answer models, scored against the plant's truth.

    python -m plantdreamer.known_answer.demo OUT -- plantdreamer generate ... --out OUT

runs the ``generate`` command after ``--`` (SDS through the committed known-answer models,
tests/data/known_answer/), times it, then scores the run's ``plant.ply`` and its starting
Gaussians (the same run with 0 steps) with ``plantdreamer eval``'s masked PSNR on the
plant's held-out true views, as the known-answer check does (``known_answer.check``). It
prints ``masked PSNR: A dB -> B dB in S s``, and writes ``demo.json`` (``psnr_start``,
``psnr_end``, ``seconds``, ``steps``) and ``demo.png`` (start, end and truth side by side
on three held-out views) into OUT. Those two are the demo's own files: they go before the
command runs, so a failed rerun never leaves an earlier score beside another run (or
beside nothing); anything else in OUT that generate does not write is left alone.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

DEMO_JSON = "demo.json"
DEMO_PNG = "demo.png"
PICTURE_VIEWS = 3  # held-out views in the picture, one per row
PICTURE_SCALE = 3  # pixels per rendered pixel: 64 px views shown at 192 px


def main(argv: list[str] | None = None) -> int:
    from plantdreamer.errors import PlantDreamerError

    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) < 3 or args[1] != "--":
        print(
            "usage: python -m plantdreamer.known_answer.demo OUT -- plantdreamer generate ...",
            file=sys.stderr,
        )
        return 2
    out, command = Path(args[0]), args[2:]
    for name in (DEMO_JSON, DEMO_PNG):  # the score of the run about to be replaced
        (out / name).unlink(missing_ok=True)
    t0 = time.perf_counter()
    code = subprocess.call(command)
    seconds = time.perf_counter() - t0
    if code != 0:
        return code
    try:
        figures = score(out, seconds)
    except (PlantDreamerError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(
        f"masked PSNR: {figures['psnr_start']:.2f} dB -> {figures['psnr_end']:.2f} dB "
        f"in {figures['seconds']:.1f} s"
    )
    return 0


def score(out: Path, seconds: float) -> dict[str, Any]:
    """Scores the ``generate`` run in ``out`` against its plant's true views; writes
    ``demo.json`` and ``demo.png`` there and returns the figures."""
    import json

    from plantdreamer.atomic import write_json
    from plantdreamer.errors import InputError
    from plantdreamer.io import read_splat_ply
    from plantdreamer.known_answer import views
    from plantdreamer.known_answer.check import Truth
    from plantdreamer.pipeline import generate_plants
    from plantdreamer.pipeline.settings.config import GenerateConfig, from_record

    run_json = out / "run.json"
    if not run_json.is_file():
        raise InputError(f"{out} holds no finished generate run (no run.json)")
    cfg = from_record(json.loads(run_json.read_text())["config"])
    spec = _spec_of(cfg)
    ply = out / "plant.ply"
    with tempfile.TemporaryDirectory() as tmp:
        truth = Truth.of(spec, Path(tmp))
        start_cfg = GenerateConfig.from_settings({**cfg.settings(), "steps": 0,
                                                  "guidance": "none", "eval_views": 0,
                                                  "turntable": "none"})  # fmt: skip
        start_run = generate_plants([start_cfg], Path(tmp) / "start", show_progress=False)[0]
        start_ply = Path(start_run.ply_path)
        figures = {
            "psnr_start": truth.score(start_ply),
            "psnr_end": truth.score(ply),
            "seconds": round(seconds, 1),
            "steps": cfg.train.steps,
        }
        start = views.in_generate_frame(read_splat_ply(start_ply), start_ply)
    end = views.in_generate_frame(read_splat_ply(ply), ply)
    _write_picture(out / DEMO_PNG, spec, [start, end, truth.gaussians])
    write_json(out / DEMO_JSON, figures)
    return figures


def _spec_of(cfg: Any) -> Any:
    """The plant ``cfg`` grows, at its size: what its true views are rendered from."""
    from plantdreamer.errors import InputError
    from plantdreamer.known_answer.spec import KnownAnswerSpec

    species, resolution = cfg.source.species, cfg.train.resolution
    if species is None or resolution is None:
        raise InputError("the demo scores an L-System plant (--species) at a set --resolution")
    return KnownAnswerSpec(
        species=species, seed=cfg.seed, resolution=resolution, points=cfg.source.points
    )


def _write_picture(path: Path, spec: Any, plants: list[Any]) -> None:
    """Rows: held-out views; columns: ``plants`` (start, end, truth), enlarged."""
    import numpy as np
    from PIL import Image

    from plantdreamer.atomic import write_image
    from plantdreamer.known_answer import views

    cameras = views.sample_cameras(spec, views.HELD_OUT_VIEWS, views.HELD_OUT_STREAM)
    cameras = cameras[:PICTURE_VIEWS]
    columns = [views.render(g, cameras)[0].numpy() for g in plants]  # [V, H, W, 3] each
    grid = np.concatenate([np.concatenate(list(c), axis=0) for c in columns], axis=1)
    image = Image.fromarray(np.round(grid * 255.0).astype(np.uint8))
    size = (image.width * PICTURE_SCALE, image.height * PICTURE_SCALE)
    write_image(path, image.resize(size, Image.Resampling.NEAREST))


if __name__ == "__main__":
    raise SystemExit(main())
