"""``--preset released``, second pass: the authors' structures, prompt, schedule, cameras,
erosion kernel, cull steps and downsampling band, checked through ``--print-config``."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.guidance.depth import DepthCleaning, kernel_size
from plantdreamer.pipeline.model.sampler import (
    area_uniform_elevation,
    legacy_area_uniform_elevation,
    mixed_elevation,
)
from plantdreamer.pipeline.settings.config import GenerateConfig
from plantdreamer.pipeline.settings.resolved import steps_of


def print_config(*args):
    """The one plant's resolved settings (``--print-config`` prints a list: a plant each)."""
    result = CliRunner().invoke(main, ["generate", *args, "--print-config"])
    assert result.exit_code == 0, result.output
    (shown,) = json.loads(result.output)
    return shown


def test_released_preset_with_bean_resolves_to_the_authors_run(tmp_path):
    out = tmp_path / "run"
    shown = print_config("--preset", "released", "--species", "bean", "--out", str(out))
    assert not out.exists()  # printed, not run
    assert shown["structure"] == "bean-released"
    cfg = GenerateConfig.from_dict(shown["config"])
    assert cfg.get("species") == "bean"
    assert shown["prompts"]["front"] == "A photo of bean plants, front view"
    assert shown["prompts"]["overhead"] == "A photo of bean plants, overhead view"
    assert shown["negative_prompt"].startswith("ugly, bad anatomy")
    assert shown["timesteps"] == [
        {"steps": [0, 500], "t_fraction": [0.02, 0.98], "t": [20, 980]},
        {"steps": [501, 3599], "t_fraction": [0.02, 0.55], "t": [20, 550]},
    ]
    assert steps_of(shown["cull_steps"]) == list(range(599, 3600, 100))  # 31, the last at 3599
    assert (cfg.get("elevation-sampling"), cfg.get("erosion-distance")) == (
        "mixed-full",
        "c2w-norm",
    )
    assert cfg.get("downsample-tolerance") == 0.25
    assert cfg.get("densify-prune-screen-px") == 1000.0


def test_released_names_keep_working_with_the_plants_name_in_the_prompt():
    for preset in ("released", "plantdreamer"):
        shown = print_config("--preset", preset, "--species", "kale-released")
        assert shown["structure"] == "kale-released"
        assert shown["prompts"]["side"].startswith(
            "A photo of kale plants" if preset == "released" else "a kale plant in a pot"
        )


def test_print_config_shows_the_prompt_of_a_loras_recorded_template(tmp_path):
    (tmp_path / "lora.json").write_text(
        json.dumps({"config": {"caption_template": "{species} leaves"}})
    )
    shown = print_config("--species", "mint-released", "--lora", str(tmp_path))
    assert GenerateConfig.from_dict(shown["config"]).get("prompt-template") == "{species} leaves"
    assert shown["prompts"]["back"] == "mint leaves, back view"


def test_our_preset_keeps_our_structures_and_cull_steps():
    shown = print_config("--species", "bean", "--guidance", "none")
    assert shown["structure"] == "bean"
    assert shown["prompts"] is None and shown["timesteps"] is None
    assert steps_of(shown["cull_steps"]) == list(range(600, 3600, 100))  # 30 rounds


def test_print_config_reports_bad_input_and_refuses_resume(tmp_path):
    bad = CliRunner().invoke(main, ["generate", "--species", "oak", "--print-config"])
    assert bad.exit_code != 0 and "unknown species 'oak'" in bad.output
    resumed = CliRunner().invoke(main, ["generate", "--resume", str(tmp_path), "--print-config"])
    assert resumed.exit_code == 2 and "--print-config" in resumed.output


def _ks_distance(samples, cdf):
    x = np.sort(samples)
    n = len(x)
    f = cdf(x)
    return max(np.max(np.arange(1, n + 1) / n - f), np.max(f - np.arange(n) / n))


def test_mixed_full_elevation_matches_threestudios_closed_form_over_10000_samples():
    low, high = -10.0, 80.0
    sl, sh = math.sin(math.radians(low)), math.sin(math.radians(high))

    def cdf(e):  # 50/50: uniform in degrees, and sin(elevation) uniform in [sin low, sin high]
        return 0.5 * (e - low) / (high - low) + 0.5 * (np.sin(np.radians(e)) - sl) / (sh - sl)

    rng = np.random.default_rng(0)
    full = np.array([mixed_elevation(rng, low, high) for _ in range(10_000)])
    rng = np.random.default_rng(0)
    legacy = np.array(
        [mixed_elevation(rng, low, high, legacy_area_uniform_elevation) for _ in range(10_000)]
    )
    # Kolmogorov-Smirnov: 1.95 / sqrt(n) is the 0.1% critical value.
    assert _ks_distance(full, cdf) < 1.95 / math.sqrt(10_000)
    assert _ks_distance(legacy, cdf) > 0.03  # the old mapping never reaches 62.7-80 degrees
    assert np.mean(full > 60.0) == pytest.approx(1 - cdf(60.0), abs=0.01)  # about 16%
    area = [area_uniform_elevation(np.random.default_rng(s), low, high) for s in range(200)]
    assert max(area) > 70.0 and min(area) >= low


def test_c2w_norm_erosion_switches_at_r_4_58_and_never_picks_3_px():
    camera, released = DepthCleaning(), DepthCleaning(distance="c2w-norm")
    edge = math.sqrt(21.0)  # sqrt(r^2 + 4) = 5
    assert [kernel_size(r, 768, camera) for r in (1.5, 4.5, 4.7)] == [3, 5, 5]
    assert [kernel_size(r, 768, released) for r in (1.5, edge - 1e-6, edge + 1e-6)] == [5, 5, 7]


def test_downsample_tolerance_is_the_released_band():
    from plantdreamer.cloud import PointCloud
    from plantdreamer.prepare import prepare_cloud

    rng = np.random.default_rng(0)
    cloud = PointCloud(positions=rng.normal(size=(1200, 3)).astype(np.float32))
    kept, _, _ = prepare_cloud(cloud, target=1000, sor_neighbors=0, tolerance=0.25)
    ours, _, _ = prepare_cloud(cloud, target=1000, sor_neighbors=0, tolerance=0.05)
    assert len(kept) == 1200  # below 1.25 x the target: not downsampled
    assert abs(len(ours) - 1000) <= 50


def test_screen_size_prune_removes_gaussians_wider_than_the_threshold_before_densifying():
    import torch

    from plantdreamer.pipeline.model.density_ops import DensifyStats, densify_and_prune
    from plantdreamer.pipeline.model.gaussian_model import GaussianModel
    from plantdreamer.pipeline.model.init import init_gaussians

    def model_and_stats():
        rng = np.random.default_rng(0)
        points = rng.normal(size=(20, 3)).astype(np.float32)
        model = GaussianModel(init_gaussians(points, np.full((20, 3), 0.5, np.float32), 0.5))
        stats = DensifyStats.zeros(20)
        radii = torch.full((1, 20), 30, dtype=torch.int32)
        radii[0, [3, 7]] = 1500  # two Gaussians wider than 1000 px on screen
        stats.update(torch.zeros(1, 20, 2), radii, 768, 768)
        return model, stats

    model, stats = model_and_stats()
    kept = torch.ones(20, dtype=torch.bool)
    kept[[3, 7]] = False
    expected = model.params["means"].detach()[kept].clone()
    counts = densify_and_prune(
        model, stats, 1.0, 1.0, 0.0, 1000, torch.Generator(), prune_screen_px=1000.0
    )
    assert counts["too_big"] == 2 and len(model) == 18
    torch.testing.assert_close(model.params["means"].detach(), expected)
    model, stats = model_and_stats()
    assert densify_and_prune(model, stats, 1.0, 1.0, 0.0, 1000, torch.Generator())["too_big"] == 0
    assert len(model) == 20  # ours by default: no screen-size prune
