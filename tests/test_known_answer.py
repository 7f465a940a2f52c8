"""The known answer for SDS (docs/known_answer.md): tiny models trained on a plant's true
views, the real ``generate`` from noise colours, ``plantdreamer eval``'s masked PSNR on
held-out true views.

The committed models (tests/data/known_answer/bean_s0_r64, made by
``python scripts/known_answer.py --build ...``, checked bit for bit by ``--verify``) make the
slow test fast enough for CI. Its thresholds are figures measured on three plants (bean,
seeds 0, 1, 2; ``python scripts/known_answer.py --seed N --steps 100``): see
THRESHOLDS_MEASURED below.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from plantdreamer.errors import InputError
from plantdreamer.known_answer.build import MANIFEST, build_models, cached_models, file_hashes
from plantdreamer.known_answer.check import schedule_table
from plantdreamer.known_answer.spec import KnownAnswerSpec

MODELS = Path(__file__).parent / "data" / "known_answer" / "bean_s0_r64"

# A spec small enough to build in seconds: it checks the machinery, not the accuracy.
TINY = KnownAnswerSpec(
    points=2000, train_views=8, recoloured_views=4, vae_steps=2, denoiser_steps=2, batch=4
)


@pytest.mark.parametrize("steps", [100, 400, 3600])
def test_schedule_table_is_the_builtin_schedule(steps: int) -> None:
    from plantdreamer.guidance.schedules import make_schedule, parse_schedule

    table = schedule_table("paper", steps)
    assert parse_schedule(table) == make_schedule("paper", steps)


def test_spec_checks_its_values_and_keys_on_them() -> None:
    with pytest.raises(InputError, match="multiple of 8"):
        KnownAnswerSpec(resolution=60)
    with pytest.raises(InputError, match="probabilities"):
        KnownAnswerSpec(uncond_prob=1.5)
    keys = {
        KnownAnswerSpec().key(),
        KnownAnswerSpec(seed=1).key(),
        KnownAnswerSpec(vae_steps=1).key(),
    }
    assert len(keys) == 3


def test_models_are_made_bit_for_bit_and_load_through_the_real_loader(tmp_path: Path) -> None:
    from plantdreamer.guidance.models import load_components

    first = build_models(TINY, tmp_path / "a")
    second = build_models(TINY, tmp_path / "b")
    assert first["sha256"] == second["sha256"]
    assert first["sha256"] == file_hashes(tmp_path / "a")
    parts = load_components(str(tmp_path / "a" / "base"), str(tmp_path / "a" / "controlnet"))
    # The trained VAE's latents are scaled to unit spread, not by SD's 0.18215.
    scale = parts.vae.config.scaling_factor
    assert scale != pytest.approx(0.18215)
    assert scale == pytest.approx(first["figures"]["vae_scaling_factor"], rel=1e-5)


def test_cache_reuses_a_built_folder(tmp_path: Path) -> None:
    folder = cached_models(TINY, tmp_path)
    stamp = (folder / MANIFEST).stat().st_mtime_ns
    assert cached_models(TINY, tmp_path) == folder
    assert (folder / MANIFEST).stat().st_mtime_ns == stamp
