"""What the CUDA path relies on, checked on the CPU: full-size model configs, depth ahead,
device selection, pinned copies, the non-finite gradient check and the GPU bench's loop."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner

from plantdreamer.cli import main
from plantdreamer.errors import InputError, PlantDreamerError
from plantdreamer.pipeline import GenerateConfig, StepOptions, generate_plants

ROOT = Path(__file__).resolve().parents[1]


def small_sds(**kw):
    base = dict(
        species="mint", seed=3, points=1500, resolution=48, eval_views=2,
        turntable_frames=2, steps=6, guidance="sds",
    )  # fmt: skip
    base.update(kw)
    return GenerateConfig.of(**base)


def tiny_sds(**kw):
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    return StableDiffusionDepthGuidance(
        species="mint", components=tiny_models(), resolution=64, seed=3, **kw
    )


# -- full-size models ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "count"),
    # The published sizes of SD 2.1-base's networks (docs/full_size_models.md).
    [("vae", 83_653_863), ("text_encoder", 340_387_840)],
)
def test_full_size_configs_give_the_published_parameter_counts(name, count):
    from plantdreamer.guidance.full_size import parameter_count

    assert parameter_count(name) == count


def test_full_size_controlnet_is_the_unets_encoder():
    # The ControlNet config must agree with the UNet's: diffusers' from_unet copies it.
    from diffusers import ControlNetModel

    from plantdreamer.guidance import full_size

    with torch.device("meta"):
        unet = full_size.build_unet()
        derived = ControlNetModel.from_unet(
            unet, conditioning_embedding_out_channels=(16, 32, 96, 256)
        )
    assert sum(p.numel() for p in unet.parameters()) == 865_910_724
    assert sum(p.numel() for p in derived.parameters()) == full_size.parameter_count("controlnet")


# -- depth ahead -----------------------------------------------------------------------------


def test_depth_ahead_gives_the_same_plant_as_depth_in_line(tmp_path):
    ahead = generate_plants(
        [small_sds()], tmp_path / "ahead", guidance=tiny_sds(), show_progress=False
    )[0]
    inline = generate_plants(
        [small_sds()], tmp_path / "inline", guidance=tiny_sds(), show_progress=False,
        options=StepOptions(depth_ahead=False),
    )[0]  # fmt: skip
    assert ahead.ply_path.read_bytes() == inline.ply_path.read_bytes()
    # The run trained (the loss log has every step) and the depth phase was timed.
    run = json.loads((tmp_path / "ahead" / "run.json").read_text())
    assert "depth" in run["per_step_s"] and run["raster_threads"] >= 1
    assert len((tmp_path / "ahead" / "log.csv").read_text().splitlines()) == 7


def test_sampler_peek_does_not_draw():
    from plantdreamer.pipeline.model.sampler import CameraSampler
    from plantdreamer.pipeline.settings.train_config import CameraRanges

    a, b = CameraSampler(CameraRanges(), 32, 5), CameraSampler(CameraRanges(), 32, 5)
    peeked = a.peek()
    assert a.peek().viewmat.tobytes() == peeked.viewmat.tobytes()
    assert a.sample().viewmat.tobytes() == peeked.viewmat.tobytes() == b.sample().viewmat.tobytes()
    assert a.peek().viewmat.tobytes() != peeked.viewmat.tobytes()


# -- devices -------------------------------------------------------------------------------


@pytest.mark.parametrize("device", ["banana", "cuda:x", "meta"])
def test_bad_device_is_a_clear_input_error(device):
    from plantdreamer.guidance.models import resolve_device

    with pytest.raises(InputError, match="device"):
        resolve_device(device)


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_cuda_without_a_gpu_is_one_error_line(tmp_path):
    for device in ("cuda", "cuda:1", "banana"):
        result = CliRunner().invoke(
            main,
            ["generate", "--species", "bean", "--device", device, "--out", str(tmp_path / "o")],
        )
        assert result.exit_code == 1, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error:") and device in lines[0]
        assert not (tmp_path / "o").exists()


def test_info_lists_devices_and_network_dtypes():
    result = CliRunner().invoke(main, ["info"])
    assert result.exit_code == 0, result.output
    for name in ("unet", "controlnet", "text_encoder", "vae"):
        assert f"{name} dtype" in result.output
    if not torch.cuda.is_available():
        assert "cuda" in result.output and "not available" in result.output
        assert re.search(r"^unet dtype \(cpu\) +float32$", result.output, re.MULTILINE)


def test_to_device_is_a_plain_copy_off_cuda():
    from plantdreamer.guidance.transfer import to_device

    x = torch.rand(2, 3, requires_grad=True)
    y = to_device(x, torch.device("cpu"))
    y.sum().backward()
    assert torch.equal(x.grad, torch.ones(2, 3))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_pinned_copy_round_trips_values_and_gradients():  # pragma: no cover - no GPU on CI
    from plantdreamer.guidance.transfer import to_device

    x = torch.rand(4, 5, requires_grad=True)
    y = to_device(x, torch.device("cuda"))
    assert y.device.type == "cuda" and torch.equal(y.cpu(), x.detach())
    (2 * y).sum().backward()
    assert x.grad is not None and torch.equal(x.grad, torch.full((4, 5), 2.0))


# -- numerics --------------------------------------------------------------------------------


class _NaNGradient(torch.autograd.Function):
    """The identity whose backward returns NaN: a finite loss with poisoned gradients."""

    @staticmethod
    def forward(ctx, x):
        return x.clone()

    @staticmethod
    def backward(ctx, grad):
        return grad * float("nan")


class _PoisonedGuidance:
    needs_depth = False
    resolution = None
    generator = None

    def __call__(self, images, depth, cameras, step):
        from plantdreamer.guidance.base import GuidanceOutput

        return GuidanceOutput(loss=_NaNGradient.apply(images).mean(), stats={})


def test_non_finite_gradients_on_the_gaussians_stop_the_run(tmp_path):
    cfg = small_sds(guidance="none", steps=3)
    with pytest.raises(PlantDreamerError, match="non-finite gradient on the Gaussians"):
        generate_plants([cfg], tmp_path / "o", guidance=_PoisonedGuidance(), show_progress=False)
    assert not (tmp_path / "o" / "plant.ply").exists()


def test_the_finite_gradient_check_is_exact_when_a_finite_sum_overflows():
    from types import SimpleNamespace

    from plantdreamer.pipeline.step.update import (
        check_finite_gradients as _check_finite_gradients,
    )

    def model(grad):
        p = torch.nn.Parameter(torch.zeros_like(grad))
        p.grad = grad
        return SimpleNamespace(params={"means": p, "quats": torch.nn.Parameter(torch.zeros(1))})

    big = torch.full((4, 3), 3e38)
    assert not torch.isfinite(big.sum())  # the fast path cannot decide: the exact test runs
    _check_finite_gradients(model(big), 0)
    for bad in (float("inf"), float("-inf"), float("nan")):
        g = torch.ones(4, 3)
        g[2, 1] = bad
        with pytest.raises(PlantDreamerError, match=r"means \(1 values\) at step 5"):
            _check_finite_gradients(model(g), 5)


# -- the GPU bench's loop --------------------------------------------------------------------


@pytest.mark.slow
def test_gpu_bench_runs_its_loop_at_tiny_size_on_the_cpu(tmp_path):
    out = tmp_path / "bench.json"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benches" / "bench_gpu.py"), "--steps", "3",
         "--tiny", "--points", "1500", "--render", "128", "--sds", "128", "--compare-depth", "0",
         "--profile", "5", "--json", str(out), "--md", str(tmp_path / "gpu.md")],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    report = json.loads(out.read_text())
    assert report["steps"] == 3 and report["models"] == "tiny"
    for phase in (
        "raster.forward",
        "depth",
        "transfer",
        "text",
        "unet+controlnet",
        "vae encode",
        "raster backward",
        "vae backward",
        "optimizer",
        "guidance other",
        "rest (in no phase)",
    ):
        assert phase in report["per_step_ms"], phase
    # Every millisecond of the mean step is in one row (the rest by construction).
    total = sum(report["per_step_ms"].values())
    assert total == pytest.approx(report["step_ms_mean"], rel=1e-9)
    assert "usable cores" in report["host"] and report["torch"] == torch.__version__
    assert report["profile"].count("\n| `") == 5
    assert report["projected_3600_steps_s"] > 0
    md = (tmp_path / "gpu.md").read_text()
    assert md.startswith("## SDS loop per phase") and "usable cores" in md


def _large_posterior_guidance(dtype, vae_dtype):
    """Tiny models whose VAE posterior has a large log-variance (14, and 30x its spread):
    the latent sample's derivative is 0.5 std eps with std ~ 1e3, so the render gradients
    exceed float16's range (65504)."""
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    parts = tiny_models()
    with torch.no_grad():
        parts.vae.quant_conv.weight[4:].mul_(30.0)
        parts.vae.quant_conv.bias[4:] = 14.0
    return StableDiffusionDepthGuidance(
        species="bean", components=parts, resolution=64, seed=0, dtype=dtype, vae_dtype=vae_dtype
    )


def _sds_render_gradient(guidance):
    from plantdreamer.cameras import orbit

    images = torch.full((1, 64, 64, 3), 0.75, requires_grad=True)
    depth = torch.rand(1, 1, 64, 64, generator=torch.Generator().manual_seed(0))
    out = guidance(images, depth, [orbit(4.0, 15.0, 0.0, 50.0, 64, 64)], 0)
    out.loss.backward()
    return out.loss.detach(), images.grad


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
def test_half_precision_networks_give_finite_render_gradients(dtype):
    # Networks in half precision, the VAE in float32 (the default): finite, and larger than
    # float16 can hold, so a float16 VAE backward could not have carried them.
    loss, grad = _sds_render_gradient(_large_posterior_guidance(dtype, torch.float32))
    assert torch.isfinite(loss) and bool(torch.isfinite(grad).all())
    assert grad.abs().max() > 65504
    # The naive all-float16 path overflows on the same scene.
    loss16, grad16 = _sds_render_gradient(_large_posterior_guidance(torch.float16, torch.float16))
    assert not (torch.isfinite(loss16) and bool(torch.isfinite(grad16).all()))


@pytest.mark.parametrize("name", ["float32", "bfloat16", "float16"])
def test_vae_dtype_setting_reaches_the_guidance(monkeypatch, name):
    from plantdreamer.guidance import sds
    from plantdreamer.pipeline import GenerateConfig
    from plantdreamer.pipeline.settings.group_settings import GroupSettings
    from plantdreamer.pipeline.settings.runtime import build_guidance, resolve_plants

    # The guidance resolves the name to that dtype, and the VAE runs in it.
    guidance = _large_posterior_guidance(torch.float32, name)
    assert guidance.vae_dtype == getattr(torch, name)
    assert next(guidance.parts.vae.parameters()).dtype == getattr(torch, name)
    # The config's setting is what generate builds its guidance with.
    seen = {}
    monkeypatch.setattr(sds, "StableDiffusionDepthGuidance", lambda **kw: seen.update(kw))
    cfg = GenerateConfig.of(guidance="sds", vae_dtype=name)
    resolve_plants([cfg])
    build_guidance(GroupSettings.of([cfg]))
    assert seen["vae_dtype"] == name


def test_sds_random_draws_come_from_a_generator_on_the_guidance_device():
    guidance = _large_posterior_guidance(torch.float32, torch.float32)
    assert guidance.generator.device == guidance.device
    # The timesteps come out where the networks run (no copy before the noise is added).
    t = guidance.schedule.sample_timestep(0, guidance.generator, 2)
    assert t.device == guidance.device and t.dtype == torch.long


def test_graphed_call_runs_eagerly_off_cuda():
    from plantdreamer.guidance.cuda_graph import GraphedCall

    calls = []
    graphed = GraphedCall(lambda a, b: calls.append(1) or a * b)
    x = torch.arange(4.0)
    assert torch.equal(graphed(x, x), x * x) and torch.equal(graphed(x, 2 * x), 2 * x * x)
    assert len(calls) == 2 and not graphed.graphs


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_graph_replay_equals_the_eager_networks():  # pragma: no cover - no GPU on CI
    """ControlNet + UNet from the CUDA graph give the eager call's bits, for fresh inputs
    each call (the inputs are copied into the graph's buffers, not captured once)."""
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    def guidance(graph: bool) -> StableDiffusionDepthGuidance:
        return StableDiffusionDepthGuidance(
            components=tiny_models(), resolution=64, device="cuda", seed=0, cuda_graph=graph
        )

    graphed, eager = guidance(True), guidance(False)
    g = torch.Generator("cuda").manual_seed(0)
    outputs = []
    for t in (900, 100, 500):
        x = torch.randn(2, 4, 8, 8, device="cuda", generator=g)
        emb = torch.randn(2, 77, 32, device="cuda", generator=g).half()
        control = torch.rand(2, 3, 64, 64, device="cuda", generator=g).half()
        ts = torch.tensor([t, t], device="cuda")
        out = graphed.noise_prediction(x, ts, emb, control)
        assert torch.equal(out, eager.noise_prediction(x, ts, emb, control))
        outputs.append(out)
    assert len(graphed._networks.graphs) == 1
    assert not torch.equal(outputs[0], outputs[1])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_graphed_vae_gives_the_eager_latents_and_gradients():  # pragma: no cover - no GPU on CI
    from plantdreamer.guidance import StableDiffusionDepthGuidance, tiny_models

    def guidance(graph: bool) -> StableDiffusionDepthGuidance:
        return StableDiffusionDepthGuidance(
            components=tiny_models(), resolution=64, device="cuda", seed=0, cuda_graph=graph
        )

    graphed, eager = guidance(True), guidance(False)
    g = torch.Generator("cuda").manual_seed(1)
    for _ in range(3):
        rgb = torch.rand(1, 3, 64, 64, device="cuda", generator=g)
        grads = []
        for guide in (graphed, eager):
            image = rgb.clone().requires_grad_(True)
            latents = guide.encode(image)
            (latents * latents).sum().backward()
            grads.append((latents.detach(), image.grad))
        assert torch.equal(grads[0][0], grads[1][0]) and torch.equal(grads[0][1], grads[1][1])
    assert len(graphed._vae_moments.graphs) == 1


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_graphs_of_two_half_sizes_are_each_captured_once():  # pragma: no cover - no GPU on CI
    """An odd group in two halves alternates two batch sizes: one graph each, kept."""
    from plantdreamer.guidance.cuda_graph import GraphedCall

    calls = []
    graphed = GraphedCall(lambda a: calls.append(1) or a * 2 + 1, warmup=1)
    sizes = (3, 2, 3, 2, 3)
    for i, n in enumerate(sizes):
        x = torch.full((n, 4), float(i), device="cuda")
        assert torch.equal(graphed(x), x * 2 + 1)
    assert len(graphed.graphs) == 2 and len(calls) == 2 * 2  # warm-up + capture per size


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_an_overlapped_launch_never_waits_for_the_device(tmp_path, monkeypatch):  # pragma: no cover
    """Each half's launch (copies, networks, backward, copies back) queues its work and
    returns: under CUDA's sync debug mode "error" any host sync in it raises. The first
    launches capture the graphs and the view prompts are encoded beforehand (one-off syncs)."""
    from plant_runs import failed, group
    from plantdreamer.guidance.prompts import VIEWS, base_prompt
    from plantdreamer.pipeline.step import schedule

    guidance = tiny_sds(device="cuda")
    for view in VIEWS:
        guidance.text_embedding(f"{base_prompt(guidance.species, guidance.prompt_template)}, "
                                f"{view} view")  # fmt: skip
    guidance.text_embedding(guidance.negative_prompt)
    launch, launches = schedule.launch_guidance, []

    def strict_launch(*args, **kwargs):
        launches.append(1)
        if len(launches) <= 2:
            return launch(*args, **kwargs)
        torch.cuda.set_sync_debug_mode("error")
        try:
            return launch(*args, **kwargs)
        finally:
            torch.cuda.set_sync_debug_mode("default")

    monkeypatch.setattr(schedule, "launch_guidance", strict_launch)
    cfgs = [small_sds(seed=s, steps=4, overlap="on", device="cuda") for s in range(4)]
    result = group(cfgs, tmp_path / "g", guidance=guidance, show_progress=False)
    assert not failed(result) and len(launches) == 8


@pytest.mark.slow
def test_gpu_checks_script_resume_dry_run_on_the_cpu(tmp_path):
    """scripts/gpu_checks.py's Ctrl-C + --resume check, run with tiny models on the CPU: the
    same script a CUDA machine runs at full size."""
    out = tmp_path / "out"
    cmd = [
        sys.executable, "scripts/gpu_checks.py", "resume", str(out), "--tiny", "--device", "cpu",
        "--steps", "40", "--checkpoint-every", "5", "--cut-after", "0", "--eval-views", "2",
        "--points", "1500", "--resolution", "48", "--sds-resolution", "64",
        "--models", str(tmp_path / "models"), "--work", str(tmp_path / "work"),
    ]  # fmt: skip
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    report = json.loads((out / "resume.json").read_text())
    assert report["identical"] and report["cut_rc"] == 130 and 5 <= report["cut_at_step"] < 40
    assert report["compared_files"] > 2 and not report["different"]
