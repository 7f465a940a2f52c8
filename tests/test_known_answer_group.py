"""A plant trained in a group (``generate --seeds``, one guidance call for the group per
step) meets the known answer as the plant made alone does (docs/known_answer.md).

Measured with generator version 6 models (masked PSNR, dB, 16 held-out views, 100 steps
at 64 px, CFG 100, the committed bean seed-0 models; the companion is bean seed 1000,
guided by the same models): alone 11.40 -> 14.13; in a group of 2, 11.40 -> 14.18. The seeds'
spread of the plain run's final PSNR is 2.5 dB (14.13 / 15.43 / 16.67 for seeds 0 / 1 / 2;
the issue's criterion): a plant made in a group must not fall more than half of it below
the plant made alone. That criterion is loose: with version 5 models, each render guided
with the other plant's depth and view prompt (a mix-up within the batch) still passed.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from plantdreamer.known_answer.build import MANIFEST
from plantdreamer.known_answer.spec import CHECK_STEPS, KnownAnswerSpec

MODELS = Path(__file__).parent / "data" / "known_answer" / "bean_s0_r64"
ALONE_FINAL_DB = 14.13  # tests/test_known_answer_accuracy.py's run of the same models
HALF_SEED_SPREAD_DB = 1.25
MIN_GAIN_DB = 2.0  # as for the plant made alone


@pytest.mark.slow
def test_a_plant_trained_in_a_group_meets_the_known_answer(tmp_path: Path) -> None:
    from plantdreamer.known_answer.check import Truth, step_curve

    spec = KnownAnswerSpec(**json.loads((MODELS / MANIFEST).read_text())["spec"])
    truth = Truth.of(spec, tmp_path)
    scores = step_curve(
        spec, truth, MODELS, tmp_path / "runs", [0, CHECK_STEPS], color_init="noise", group=2
    )
    first, last = scores[0].masked_psnr, scores[-1].masked_psnr
    print(f"in a group of 2: {first:.2f} -> {last:.2f} dB")
    assert last - first >= MIN_GAIN_DB
    assert last >= ALONE_FINAL_DB - HALF_SEED_SPREAD_DB
