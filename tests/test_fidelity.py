"""Presets and the authors' released variants of each step (docs/fidelity.md)."""

import dataclasses
import json
import math

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.errors import InputError
from plantdreamer.guidance.config import RELEASED_NEGATIVE_PROMPT
from plantdreamer.guidance.depth import DepthCleaning, clean_depth, normalise_depth
from plantdreamer.pipeline import GenerateConfig, resolve_config
from plantdreamer.pipeline.model.culling import large_gaussian_mask
from plantdreamer.pipeline.model.density_ops import DensifyStats, densify_and_prune, random_cap_mask
from plantdreamer.pipeline.model.gaussian_model import GaussianModel
from plantdreamer.pipeline.model.init import neighbour_spacing
from plantdreamer.pipeline.model.sampler import legacy_area_uniform_elevation, mixed_elevation

# -- presets ------------------------------------------------------------------------------


def test_presets_resolve_to_the_documented_values():
    ours = resolve_config("plantdreamer")
    assert dataclasses.asdict(ours) == dataclasses.asdict(GenerateConfig())
    released = resolve_config("released")
    expected = {
        "preset": "released",
        "negative-prompt": RELEASED_NEGATIVE_PROMPT,
        "prompt-template": "A photo of {species} plants",
        "depth-rule": "released",
        "points": 300_000,
        "mesh-sor": True,
        "sor-after-voxel": True,
        "elevation-sampling": "mixed-full",
        "structures": "released",
        "erosion-distance": "c2w-norm",
        "downsample-tolerance": 0.25,
        "network-dtype": "float32",
        "depth-size": "render",
        "control-resize": "nearest",
        "init-scale": "rms",
        "init-shape": "sphere",
        "schedule": "released",
        "guidance-scale": 101.0,
    }
    assert {k: released.get(k) for k in expected} == expected
    assert (
        released.get("cull-threshold"),
        released.get("cull-volume"),
        released.get("cull-offset"),
    ) == (7.0, "double-exp", 1)
    assert (released.get("densify-split-std"), released.get("densify-cap-rule")) == (
        0.5,
        "random",
    )
    # untouched
    assert released.get("densify-max-gaussians") == ours.get("densify-max-gaussians")
    paper = resolve_config("paper")
    assert (paper.get("schedule"), paper.get("cull-threshold"), paper.get("cull-volume")) == (
        "paper",
        3.0,
        "log",
    )
    assert paper.get("prompt-template") == "a {species} plant in a pot"
    # Our own defaults where the released code differs.
    assert (ours.get("cull-threshold"), ours.get("cull-volume"), ours.get("depth-rule")) == (
        3.0,
        "log",
        "stretch",
    )
    assert ours.get("negative-prompt") == RELEASED_NEGATIVE_PROMPT
    assert ours.get("depth-size") == "sds"


def test_every_preset_is_a_choice_of_the_preset_setting():
    from plantdreamer.pipeline.settings.config import PRESET_NAMES
    from plantdreamer.pipeline.settings.presets import PRESETS

    assert tuple(PRESETS) == PRESET_NAMES


def test_explicit_options_override_the_preset():
    cfg = resolve_config("released", {"cull-threshold": 5.0, "points": 2000})
    assert (cfg.density.cull.threshold, cfg.source.points, cfg.density.cull.volume) == (
        5.0,
        2000,
        "double-exp",
    )


def test_bad_preset_and_choices_are_input_errors():
    with pytest.raises(InputError, match="unknown preset"):
        resolve_config("authors")
    with pytest.raises(InputError, match="depth rule"):
        GenerateConfig.of(species="bean", depth_rule="flat").validate()
    with pytest.raises(InputError, match="species"):
        GenerateConfig.of(species="bean", prompt_template="a plant").validate()


# -- culling ------------------------------------------------------------------------------


def _culled_by_hand(volumes, c):
    v = np.asarray(volumes, dtype=np.float64)
    return v > v.mean() + c * v.std(ddof=1)


def test_double_exp_culling_volume_is_exp_of_activated_scales():
    rng = np.random.default_rng(0)
    log_s = np.log(rng.uniform(0.01, 0.05, (200, 3)))
    log_s[:3] = np.log([0.9, 0.8, 0.7])[:, None]  # three large Gaussians
    s = np.exp(log_s)
    single = np.sqrt((s**2).sum(axis=1))
    double = np.sqrt((np.exp(s) ** 2).sum(axis=1))
    for volume, v in (("log", single), ("double-exp", double)):
        mask, stats = large_gaussian_mask(torch.tensor(log_s, dtype=torch.float32), 3.0, volume)
        np.testing.assert_array_equal(mask.numpy(), _culled_by_hand(v, 3.0))
        assert stats["mean"] == pytest.approx(v.mean(), rel=1e-5)
    # C = 7 culls fewer than C = 3 on the same scales.
    mask7, _ = large_gaussian_mask(torch.tensor(log_s, dtype=torch.float32), 7.0, "double-exp")
    assert int(mask7.sum()) <= int(_culled_by_hand(double, 3.0).sum())


# -- cameras ------------------------------------------------------------------------------


def test_legacy_area_uniform_elevation_follows_threestudio_before_its_fix():
    rng = np.random.default_rng(1)
    values = np.array([legacy_area_uniform_elevation(rng, -10.0, 80.0) for _ in range(20_000)])
    low = math.degrees(math.asin(2 * 80 / 180 - 1))  # p0 = (-10 + 90) / 180
    high = math.degrees(math.asin(2 * 170 / 180 - 1))  # p1 = (80 + 90) / 180
    assert values.min() >= low and values.max() <= high
    # sin(elevation) = 2p - 1 is uniform on [2 p0 - 1, 2 p1 - 1].
    sines = np.sin(np.radians(values))
    assert sines.mean() == pytest.approx((2 * 80 / 180 - 1 + 2 * 170 / 180 - 1) / 2, abs=0.01)
    # Area-uniform: fewer samples near the top than uniform-in-degrees would give.
    assert np.mean(values > 50.0) < (high - 50.0) / (high - low)


def test_mixed_elevation_is_seeded_and_uses_both_branches():
    draw = lambda seed: [mixed_elevation(np.random.default_rng(seed), -10, 80) for _ in range(1)]  # noqa: E731
    assert draw(3) == draw(3)
    rng = np.random.default_rng(0)
    draw = legacy_area_uniform_elevation
    values = np.array([mixed_elevation(rng, -10.0, 80.0, draw) for _ in range(4000)])
    assert values.max() > 70.0  # the uniform branch reaches past the legacy area branch's 62.7
    assert values.min() >= -10.0 and values.max() <= 80.0


# -- initialisation, densification ---------------------------------------------------------


def test_rms_initial_scale_by_hand():
    # Point 0 has its 3 nearest neighbours at distances 1, 2 and 2.
    points = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, -2], [30, 0, 0], [0, 30, 0]], dtype=np.float32
    )
    rms = neighbour_spacing(points, 3, "rms")
    mean = neighbour_spacing(points, 3, "mean")
    assert rms[0] == pytest.approx(math.sqrt((1 + 4 + 4) / 3))
    assert mean[0] == pytest.approx(5 / 3)
    assert np.all(rms >= mean - 1e-6)  # RMS >= mean for any distances


def _model(n, seed=0):
    from plantdreamer.pipeline.model.init import init_gaussians

    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3)).astype(np.float32)
    colors = np.full((n, 3), 0.5, dtype=np.float32)
    return GaussianModel(init_gaussians(points, colors, 0.5))


def test_random_prune_at_the_cap_uses_the_seeded_generator():
    mask = random_cap_mask(100, 60, torch.Generator().manual_seed(4))
    assert int(mask.sum()) == 40
    again = random_cap_mask(100, 60, torch.Generator().manual_seed(4))
    other = random_cap_mask(100, 60, torch.Generator().manual_seed(5))
    assert torch.equal(mask, again) and not torch.equal(mask, other)
    assert not random_cap_mask(50, 60, torch.Generator()).any()

    model = _model(40)
    stats = DensifyStats(torch.ones(40, dtype=torch.float64), torch.ones(40, dtype=torch.int64))
    counts = densify_and_prune(
        model, stats, 0.5, 100.0, 0.0, 50, torch.Generator().manual_seed(0), cap_rule="random"
    )
    # Every Gaussian is cloned (80), then a random 30 are pruned to the cap of 50.
    assert counts["cloned"] == 40 and counts["capped"] == 30 and len(model) == 50


def test_split_std_scales_the_split_offsets():
    offsets = {}
    for std in (1.0, 0.5):
        model = _model(10)
        before = model.params["means"].detach().clone()
        stats = DensifyStats(torch.ones(10, dtype=torch.float64), torch.ones(10, dtype=torch.int64))
        densify_and_prune(
            model, stats, 0.5, 0.0, 0.0, 1000, torch.Generator().manual_seed(7), split_std=std
        )
        offsets[std] = model.params["means"].detach() - torch.cat([before, before])
    torch.testing.assert_close(offsets[0.5], 0.5 * offsets[1.0])


def test_released_prep_order_runs_outlier_removal_after_the_voxel_grid():
    from plantdreamer.cloud import PointCloud
    from plantdreamer.prepare import prepare_cloud

    rng = np.random.default_rng(0)
    cloud = PointCloud(positions=rng.normal(size=(6000, 3)).astype(np.float32))
    _, _, ours = prepare_cloud(cloud, target=2000)
    _, _, released = prepare_cloud(cloud, target=2000, sor_after_voxel=True)
    assert [n for n, _ in ours.counts] == ["input", "outliers removed", "downsampled"]
    assert [n for n, _ in released.counts] == ["input", "downsampled", "outliers removed"]


# -- depth --------------------------------------------------------------------------------


def test_released_depth_rule_on_a_hand_made_map():
    accumulated = torch.tensor([[0.0, 0.0, 0.02], [2.0, 3.0, 4.0], [0.0, 3.5, 0.05]])
    out = normalise_depth(
        accumulated, torch.ones(3, 3), DepthCleaning(rule="released", accumulated=True)
    )
    # start = 0.02 (second-smallest value), end = 4.0; n = 1 - (D - 0.02) / 3.98.
    lift = lambda n: min((n + 0.1) * 1.75, 1.0)  # noqa: E731
    expected = [
        [0.0, 0.0, 0.0],  # background, and start itself: n = 1 >= 0.97
        [lift(1 - 1.98 / 3.98), lift(1 - 2.98 / 3.98), 0.0],  # D_max: n = 0 -> 0.175 -> dropped
        [0.0, lift(1 - 3.48 / 3.98), 0.0],  # 0.05: n = 0.9925 >= 0.97 (a faint pixel)
    ]
    torch.testing.assert_close(out, torch.tensor(expected), rtol=0, atol=1e-6)
    assert out[1, 0] == 1.0  # (0.5025 + 0.1) * 1.75 saturates


def test_released_rule_takes_accumulated_depth_from_expected_depth_and_alpha():
    depth = torch.tensor([[4.0, 4.0], [3.0, 0.0]])
    alpha = torch.tensor([[1.0, 0.5], [1.0, 0.0]])
    cfg = DepthCleaning(rule="released")
    acc = DepthCleaning(rule="released", accumulated=True)
    torch.testing.assert_close(
        normalise_depth(depth, alpha, cfg), normalise_depth(depth * alpha, alpha, acc)
    )


def test_stretch_rule_keeps_depth_order_without_saturating():
    depth = torch.linspace(3.0, 5.0, 100).reshape(10, 10)
    alpha = torch.ones(10, 10)
    ours = normalise_depth(depth, alpha, DepthCleaning(far_quantile=1.0))
    old = normalise_depth(depth, alpha, DepthCleaning(far_quantile=1.0, rule="stretch-lift"))
    assert int((ours == 1.0).sum()) == 1  # only the nearest pixel
    assert int((old == 1.0).sum()) > 40  # the earlier rule saturated the near half
    flat = ours.flatten()
    assert torch.all(flat[1:] < flat[:-1])  # strictly brighter when nearer
    assert float(flat.min()) == pytest.approx(0.175)


def test_nearest_resize_keeps_depth_values():
    depth = torch.tensor([[3.0, 4.0], [4.5, 5.0]]).repeat_interleave(8, 0).repeat_interleave(8, 1)
    depth, alpha = depth[None, ..., None], torch.ones(1, 16, 16, 1)
    cfg = dict(far_quantile=1.0, erode=False, dilate=False)
    small = clean_depth(depth, alpha, 4.0, 16, **cfg)
    near = clean_depth(depth, alpha, 4.0, 64, resize="nearest", **cfg)
    assert set(near.unique().tolist()) == set(small.unique().tolist())


# -- guidance: negative prompt, clamp, template ---------------------------------------------


def _guidance(**kwargs):
    from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
    from plantdreamer.guidance.tiny import tiny_models

    return StableDiffusionDepthGuidance(
        components=tiny_models(), resolution=64, device="cpu", **kwargs
    )


def _inputs(low=0.0, high=1.0):
    from plantdreamer.cameras import orbit

    g = torch.Generator().manual_seed(0)
    images = (low + (high - low) * torch.rand(1, 48, 48, 3, generator=g)).requires_grad_(True)
    return images, torch.rand(1, 1, 64, 64, generator=g), [orbit(4.0, 15.0, 0.0, 60.0, 48, 48)]


def test_negative_prompt_reaches_the_unconditional_branch():
    guidance = _guidance()
    seen = {}
    original = guidance.sds_gradient

    def spy(latents, noise, t, text, uncond, control):
        seen["uncond"] = uncond
        return original(latents, noise, t, text, uncond, control)

    guidance.sds_gradient = spy
    guidance(*_inputs(), step=0)
    assert torch.equal(seen["uncond"][0], guidance.text_embedding(RELEASED_NEGATIVE_PROMPT)[0])
    assert not torch.equal(seen["uncond"][0], guidance.text_embedding("")[0])


def test_renders_are_clamped_before_encoding():
    guidance = _guidance()
    seen = {}
    original = guidance.encode

    def spy(rgb):
        seen["rgb"] = rgb.detach().clone()
        return original(rgb)

    guidance.encode = spy
    images, depth, cams = _inputs(-0.5, 1.5)
    out = guidance(images, depth, cams, step=0)
    out.loss.backward()
    assert float(seen["rgb"].min()) >= 0.0 and float(seen["rgb"].max()) <= 1.0
    outside = (images.detach() < 0) | (images.detach() > 1)
    assert outside.any() and torch.all(images.grad[outside] == 0)


def test_prompt_template_and_a_loras_recorded_template(tmp_path):
    from plantdreamer.guidance.lora_weights import recorded_template
    from plantdreamer.pipeline.settings.runtime import resolve_plants

    guidance = _guidance(prompt_template="A photo of {species} plants", species="mint")
    assert guidance.prompts_for(_inputs()[2]) == ["A photo of mint plants, front view"]
    (tmp_path / "lora.json").write_text(
        json.dumps({"config": {"caption_template": "{species} leaves"}})
    )
    assert recorded_template(tmp_path) == "{species} leaves"
    assert recorded_template(tmp_path / "pytorch_lora_weights.safetensors") == "{species} leaves"
    cfg = GenerateConfig.of(species="mint", lora=str(tmp_path))
    resolve_plants([cfg])
    assert cfg.sds.prompt_template == "{species} leaves"
    cfg = GenerateConfig.of(species="mint")
    resolve_plants([cfg])
    assert cfg.sds.prompt_template == "a {species} plant in a pot"
    assert cfg.sds.network_dtype in ("float16", "float32")


# -- end to end ---------------------------------------------------------------------------


def _run_released(tmp_path, *extra):
    out = tmp_path / "o"
    args = [
        "generate", "--preset", "released", "--species", "bean", "--seed", "1",
        "--points", "1500", "--resolution", "48", "--eval-views", "2", "--out", str(out),
        "--quiet", *extra,
    ]  # fmt: skip
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    return json.loads((out / "run.json").read_text())


def test_released_preset_without_guidance_records_every_resolved_value(tmp_path):
    run = _run_released(tmp_path, "--guidance", "none", "--steps", "620", "--cull-threshold", "6")
    config = run["config"]
    assert list(config) == list(GenerateConfig().settings())  # every setting, by name
    cfg = GenerateConfig.from_dict(config)
    assert config["preset"] == "released" and cfg.get("cull-threshold") == 6.0
    assert cfg.get("cull-volume") == "double-exp" and cfg.get("points") == 1500
    assert (cfg.get("densify-split-std"), cfg.get("densify-cap-rule")) == (0.5, "random")
    assert cfg.get("network-dtype") == "float32"  # resolved, never "auto"
    assert cfg.get("prompt-template") == "A photo of {species} plants"
    assert run["source_points"]["outliers removed"] <= 1500
    assert [e["step"] for e in run["events"] if e["event"] == "cull"] == [599]  # theirs


def _depth_sizes_seen(monkeypatch) -> list[tuple[str, int]]:
    """Spies on the conditioners the trainer builds: (depth_size, the depth map's side)."""
    from plantdreamer.guidance import conditioned

    seen: list[tuple[str, int]] = []
    real = conditioned.DepthConditioner

    def spy(render_depth, **kwargs):
        def rendered(camera):
            seen.append((kwargs["depth_size"], camera.width))
            return render_depth(camera)

        return real(rendered, **kwargs)

    monkeypatch.setattr(conditioned, "DepthConditioner", spy)
    return seen


def test_released_preset_with_tiny_sds(tmp_path, monkeypatch):
    from plantdreamer.guidance import save_tiny_models

    base, controlnet = save_tiny_models(tmp_path / "models")
    seen = _depth_sizes_seen(monkeypatch)
    run = _run_released(
        tmp_path,
        "--guidance", "sds", "--base-model", str(base), "--controlnet", str(controlnet),
        "--steps", "3", "--sds-resolution", "64",
    )  # fmt: skip
    # The released code renders its depth maps at the render size (48 here).
    assert seen and set(seen) == {("render", 48)} and run["config"]["depth-size"] == "render"
    seen.clear()
    ours = tmp_path / "ours"
    result = CliRunner().invoke(main, [
        "generate", "--species", "bean", "--seed", "1", "--points", "1500", "--resolution",
        "48", "--eval-views", "1", "--turntable", "none", "--out", str(ours), "--quiet",
        "--guidance", "sds", "--base-model", str(base), "--controlnet", str(controlnet),
        "--steps", "2", "--sds-resolution", "32",
    ])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert seen and set(seen) == {("sds", 32)}  # ours: at the ControlNet's own size
    assert run["config"]["depth-rule"] == "released"
    assert run["config"]["schedule"] == "released"
    assert run["per_step_s"]["guidance.launch"] > 0
