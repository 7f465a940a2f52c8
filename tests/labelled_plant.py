"""A small generated bean (labelled views and label files), shared by the label tests."""

from __future__ import annotations

from pathlib import Path

from plantdreamer.pipeline import GenerateConfig, generate_plants

SETTINGS = dict(
    species="bean",
    seed=3,
    points=3000,
    resolution=96,
    eval_views=3,
    turntable_frames=2,
    turntable="none",
    steps=0,
    guidance="none",
)


def make_plant(out: Path, **settings) -> Path:
    generate_plants([GenerateConfig.of(**{**SETTINGS, **settings})], out, show_progress=False)
    return out
