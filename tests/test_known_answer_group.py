"""A plant trained in a group (``generate --seeds``, one guidance call for the group per
step) meets the known answer as the plant made alone does (docs/known_answer.md), and the
test fails when the group's renders are guided with each other's conditioning.

Measured with generator version 6 models, the VAE trained 1600 steps (masked PSNR, dB,
16 held-out views, 100 steps at 64 px, CFG 100, each bean seed with its own models, seed
0's the committed ones; the companion is bean seed 1000, guided by the same models), seeds
0 / 1 / 2:

- alone: 11.40 -> 15.61 / 16.91 / 16.80 (the seeds' spread, 1.3 dB, is the issue's
  criterion, looser than what a group changes);
- in a group of 2: 15.35 / 16.99 / 16.93, so group minus alone -0.26 / +0.08 / +0.13;
- mixed up (each render guided with the other plant's depth and view prompt, a one-off
  script): 14.54 / 16.08 / 13.84, group minus alone -1.07 / -0.83 / -2.96.

The tolerance, 0.5 dB either way, sits between the worst right seed (0.26) and the
mildest mix-up (0.83). The plant made alone runs in the same test, so the comparison
holds on a machine whose floating point rounds differently.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import pytest

from plantdreamer.known_answer.spec import CHECK_STEPS, KnownAnswerSpec

MODELS = Path(__file__).parent / "data" / "known_answer" / "bean_s0_r64"
GROUP_TOLERANCE_DB = 0.5
MIN_GAIN_DB = 3.0  # as for the plant made alone


class _MixedUp:
    """The group's guidance with the batch's depth maps and cameras (so its view prompts)
    reversed: each render guided as the other plant."""

    def __init__(self, guidance: Any) -> None:
        self.guidance = guidance

    def __getattr__(self, name: str) -> Any:
        return getattr(self.guidance, name)

    def launch(self, images: Any, depth: Any, cameras: Sequence[Any], step: int) -> Any:
        return self.guidance.launch(images, depth.flip(0), list(cameras)[::-1], step)

    def __call__(self, images: Any, depth: Any, cameras: Sequence[Any], step: int) -> Any:
        return self.launch(images, depth, cameras, step).result()


class Plant(NamedTuple):
    spec: KnownAnswerSpec
    truth: Any  # known_answer.check.Truth
    start_db: float  # masked PSNR of the noise-coloured start
    alone_db: float  # masked PSNR of the plant made alone, CHECK_STEPS from noise
    work: Path


@pytest.fixture(scope="module")
def plant(known_answer_plant, tmp_path_factory: pytest.TempPathFactory) -> Plant:
    """The plant made alone is the session's baseline run (conftest.known_answer_plant)."""
    ka = known_answer_plant
    work = tmp_path_factory.mktemp("known_answer_group")
    return Plant(ka.spec, ka.truth, ka.init_db, ka.final_db, work)


def _in_group(plant: Plant, name: str) -> tuple[float, float]:
    """The start (a 0-step run trains no group: the plant's own start) and the plant's
    masked PSNR after CHECK_STEPS in a group of 2."""
    from plantdreamer.known_answer.check import step_curve

    (scores,) = step_curve(
        plant.spec,
        plant.truth,
        MODELS,
        plant.work / name,
        [CHECK_STEPS],
        color_init="noise",
        group=2,
    )
    return plant.start_db, scores.masked_psnr


@pytest.mark.slow
def test_a_plant_trained_in_a_group_meets_the_known_answer(plant: Plant) -> None:
    first, last = _in_group(plant, "group")
    print(f"in a group of 2: {first:.2f} -> {last:.2f} dB; alone {plant.alone_db:.2f}")
    assert last - first >= MIN_GAIN_DB
    assert abs(last - plant.alone_db) <= GROUP_TOLERANCE_DB


@pytest.mark.slow
def test_the_group_check_fails_when_the_renders_are_mixed_up(plant: Plant, monkeypatch) -> None:
    import plantdreamer.pipeline.runs.entry as entry

    build = entry.build_guidance
    monkeypatch.setattr(entry, "build_guidance", lambda group, **kw: _MixedUp(build(group, **kw)))
    _, last = _in_group(plant, "mixed_up")
    print(f"mixed up: {last:.2f} dB; alone {plant.alone_db:.2f}")
    assert abs(last - plant.alone_db) > GROUP_TOLERANCE_DB
