"""The known-answer machinery (docs/known_answer.md): a model set's spec, its cache key,
the schedule table that makes a short run the prefix of a long one, and a bit-for-bit
rebuild of a tiny spec loaded through ``generate``'s real loader. The accuracy gate itself
(>= 3 dB from noise in 100 steps) is not here yet: docs/known_answer.md, "Status".
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
