"""The known-answer machinery (docs/known_answer.md): a model set's spec, its cache key,
the schedule table that makes a short run the prefix of a long one, a bit-for-bit rebuild
of a tiny spec loaded through ``generate``'s real loader, the whole check on every species,
and the gate's conventions on stub models. The accuracy itself is
tests/test_known_answer_accuracy.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from plantdreamer.errors import InputError
from plantdreamer.known_answer.build import (
    MANIFEST,
    build_models,
    cached_models,
    differing_files,
    file_hashes,
)
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
    assert differing_files(first, second) is None
    assert first["built_on"]["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    parts = load_components(str(tmp_path / "a" / "base"), str(tmp_path / "a" / "controlnet"))
    # The trained VAE's latents are scaled to unit spread, not by SD's 0.18215.
    scale = parts.vae.config.scaling_factor
    assert scale != pytest.approx(0.18215)
    assert scale == pytest.approx(first["figures"]["vae_scaling_factor"], rel=1e-5)


@pytest.mark.slow
@pytest.mark.parametrize("species", ["kale", "mint"])
def test_the_check_runs_for_every_species(tmp_path: Path, species: str) -> None:
    """Build, both runs and the scores end to end (a tiny spec: machinery, not accuracy)."""
    import dataclasses

    from plantdreamer.known_answer.build import untrained_models
    from plantdreamer.known_answer.check import known_answer

    spec = dataclasses.replace(TINY, species=species)
    models = cached_models(spec, tmp_path / "cache")
    untrained = untrained_models(spec, tmp_path / "cache")
    figures = known_answer(spec, models, untrained, tmp_path / "runs", steps=2, curve=[1])
    assert [p["steps"] for p in figures["curve"]] == [0, 1, 2]
    assert figures["psnr_true_init"] == 100.0  # the truth scores exactly on its own views
    for key in ("psnr_init", "psnr_final", "psnr_control_final", "psnr_true_final"):
        assert 0.0 < figures[key] <= 100.0, (key, figures)


def test_a_failed_verify_names_the_files_and_both_machines() -> None:
    """The committed manifest predates ``built_on``: its machine is said to be unrecorded."""
    old = {"sha256": {"a": "1", "b": "2"}}
    new = {"sha256": {"a": "1", "b": "3", "c": "4"},
           "built_on": {"cpu": "X", "numpy": "2.4.6", "torch_cpu_capability": "AVX512"}}  # fmt: skip
    said = differing_files(old, new)
    assert said is not None
    assert said.startswith("rebuilt models differ in b, c (built on an unrecorded machine; ")
    assert "rebuilt on cpu X, numpy 2.4.6, torch_cpu_capability AVX512)" in said
    assert "\n" not in said  # one error: line on the CLI
    assert differing_files(new, new) is None


def test_cache_reuses_a_built_folder(tmp_path: Path) -> None:
    folder = cached_models(TINY, tmp_path)
    stamp = (folder / MANIFEST).stat().st_mtime_ns
    assert cached_models(TINY, tmp_path) == folder
    assert (folder / MANIFEST).stat().st_mtime_ns == stamp


def test_corrected_targets_change_the_denoiser(tmp_path: Path) -> None:
    """corrected_prob > 0 trains on wrong-colour latents with the true latent's noise."""
    import dataclasses

    plain = build_models(TINY, tmp_path / "plain")["sha256"]
    fixed = build_models(dataclasses.replace(TINY, corrected_prob=1.0), tmp_path / "fix")
    unet = "base/unet/diffusion_pytorch_model.safetensors"
    assert fixed["sha256"][unet] != plain[unet]
    assert (
        fixed["sha256"]["base/vae/diffusion_pytorch_model.safetensors"]
        == plain["base/vae/diffusion_pytorch_model.safetensors"]
    )


@pytest.mark.parametrize("change", [{"vae_mask_weight": 0.0}, {"vae_recoloured_share": 0.0}])
def test_vae_recipe_settings_reach_the_vae(tmp_path: Path, change: dict) -> None:
    """The plant's pixel weight and the wrong-colour share are what make the encoder see
    colour (docs/known_answer.md): each changes the trained VAE."""
    import dataclasses

    vae = "base/vae/diffusion_pytorch_model.safetensors"
    plain = build_models(TINY, tmp_path / "plain")["sha256"][vae]
    other = build_models(dataclasses.replace(TINY, **change), tmp_path / "other")["sha256"][vae]
    assert other != plain


def test_colour_gap_is_the_relative_latent_distance() -> None:
    from plantdreamer.known_answer.gate import colour_gap
    from plantdreamer.known_answer.views import ViewSet

    data = ViewSet(
        images=torch.full((2, 3, 16, 16), 0.75),  # latent 0.5
        recoloured=torch.full((2, 3, 16, 16), 0.5),  # latent 0: gap 0.5 / 0.5
        recoloured_view=torch.arange(2),
        depth=torch.zeros(2, 1, 16, 16),
        prompts=["p"] * 2,
        alpha=torch.ones(2, 1, 16, 16),
    )
    assert colour_gap(_PoolVae(), data) == pytest.approx(1.0)


class _Encoded:
    def __init__(self, mean: torch.Tensor) -> None:
        self.latent_dist = type("Dist", (), {"mean": mean})()


class _PoolVae:
    """An 'encoder' that averages 8 x 8 pixels: latents are the image, scale 1."""

    config = type("Config", (), {"scaling_factor": 1.0})()

    def encode(self, x: torch.Tensor) -> _Encoded:
        return _Encoded(torch.nn.functional.avg_pool2d(x, 8))


class _ScaledUnet:
    """eps_text = k * z_t, eps_uncond = 0: the CFG direction is k * z_t."""

    def __init__(self, k: float, negative: torch.Tensor) -> None:
        self.k, self.negative = k, negative

    def __call__(
        self, z_t: torch.Tensor, t: torch.Tensor, encoder_hidden_states: torch.Tensor, **_: object
    ) -> object:
        text = (encoder_hidden_states != self.negative).flatten(1).any(1).view(-1, 1, 1, 1)
        return type("Out", (), {"sample": self.k * z_t * text})()


@pytest.mark.parametrize("k", [1.0, -1.0])
def test_gate_sign_follows_the_direction_sds_descends(k: float) -> None:
    """True views grey (latent 0), wrong ones white (latent 1): a CFG direction along +z_t
    makes SDS pull the latent back to 0, the gate's cosine near +1; the flipped one near -1."""
    from plantdreamer.guidance.config import SDS_DEFAULTS
    from plantdreamer.guidance.text import PromptEmbeddings
    from plantdreamer.guidance.tiny import tiny_models
    from plantdreamer.known_answer.gate import cfg_direction
    from plantdreamer.known_answer.views import ViewSet

    parts = tiny_models(0)
    negative = PromptEmbeddings(parts.tokenizer, parts.text_encoder, "cpu")(
        SDS_DEFAULTS.negative_prompt
    )
    parts.vae = _PoolVae()
    parts.controlnet = lambda *a, **kw: ([], None)
    parts.unet = _ScaledUnet(k, negative)
    data = ViewSet(
        images=torch.full((4, 3, 64, 64), 0.5),
        recoloured=torch.ones(4, 3, 64, 64),
        recoloured_view=torch.arange(4),
        depth=torch.zeros(4, 1, 64, 64),
        prompts=["a bean plant, front view"] * 4,
        alpha=torch.ones(4, 1, 64, 64),
    )
    gate = cfg_direction(parts, data, SDS_DEFAULTS.negative_prompt, timesteps=(100,))
    assert gate[0].cosine * k > 0.8
    # Through the pooling encoder the pixel step is the latent step spread over its pixels:
    # the same sign, nearly every channel of the plant moved the same way (z_t's noise
    # flips a few).
    assert gate[0].pixel_cosine * k > 0.8
    assert abs(gate[0].pixel_agreement - (k > 0)) < 0.05


@pytest.mark.slow
def test_gate_points_wrong_and_white_colours_at_the_truth(tmp_path: Path) -> None:
    """The committed models (generator version 6, VAE trained 1600 steps, bean seed 0) on
    16 unseen views: from the wrong colours they were trained on, the latent direction has
    cosine 0.63-0.87 and the pixel step SDS makes of it 0.30-0.35; from white, 0.74-0.85
    and 0.02-0.16 (t = 100 / 300 / 600 / 900), 0.09 on average. (Version 5 models, trained
    on views of a plant 7.7 times too small, turned the white pixel step away from the
    truth, -0.10 to -0.12: docs/known_answer.md.)"""
    import json

    from plantdreamer.known_answer.gate import gate_on_unseen_views
    from plantdreamer.known_answer.spec import KnownAnswerSpec

    spec = KnownAnswerSpec(**json.loads((MODELS / "manifest.json").read_text())["spec"])
    _, white = gate_on_unseen_views(MODELS, spec, tmp_path, flat_colour=1.0)
    _, wrong = gate_on_unseen_views(MODELS, spec, tmp_path)
    assert all(d.cosine > 0.5 and d.pixel_cosine > 0.1 for d in wrong)
    assert all(d.cosine > 0.5 for d in white)
    assert sum(d.pixel_cosine for d in white) / len(white) > 0.0


def _script():
    import sys

    scripts = str(Path(__file__).resolve().parents[1] / "scripts")
    if scripts not in sys.path:
        sys.path.insert(0, scripts)
    import known_answer as script

    return script


def test_the_script_passes_its_device_to_the_check(tmp_path: Path, monkeypatch, capsys) -> None:
    """``--device cpu`` reaches ``known_answer`` and the figures (the check itself stubbed:
    this is the argument path; the check's runs are the accuracy tests')."""
    import json

    from plantdreamer.known_answer import build, check

    seen = {}

    def fake_check(spec, trained, untrained, work, steps, curve, device="cpu", **settings):
        seen.update(device=device, trained=trained, steps=steps, settings=settings)
        return {"psnr_final": 1.0}

    monkeypatch.setattr(check, "known_answer", fake_check)
    monkeypatch.setattr(build, "untrained_models", lambda spec, cache: tmp_path)
    argv = ["--models", str(MODELS), "--steps", "3", "--device", "cpu"]
    assert _script().main([*argv, "--json", str(tmp_path / "ka.json")]) == 0
    assert seen == {"device": "cpu", "trained": MODELS, "steps": 3, "settings": {}}
    assert _script().main([*argv, "--vae-dtype", "bfloat16"]) == 0  # the VAE's precision
    assert seen["settings"] == {"vae_dtype": "bfloat16"}
    assert json.loads((tmp_path / "ka.json").read_text())["device"] == "cpu"


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA GPU is present")
def test_cuda_asked_for_without_a_gpu_is_one_clear_error(tmp_path: Path, capsys) -> None:
    from plantdreamer.known_answer.check import known_answer

    assert _script().main(["--models", str(MODELS), "--device", "cuda"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: device 'cuda' asked for, but torch sees no CUDA GPU"]
    with pytest.raises(InputError, match="device must be cpu or cuda"):
        known_answer(TINY, MODELS, MODELS, tmp_path, steps=1, device="tpu")
    with pytest.raises(InputError, match="torch sees no CUDA GPU"):
        known_answer(TINY, MODELS, MODELS, tmp_path, steps=1, device="cuda:0")
