"""SDS guidance with tiny random-weight models on the CPU: gradients, the hand-computed step,
determinism, clamping, caching, and the simple guidances."""

import math

import pytest
import torch

from plantdreamer.cameras import orbit
from plantdreamer.errors import InputError
from plantdreamer.guidance.base import Guidance, NoGuidance, PhotometricGuidance
from plantdreamer.guidance.config import RELEASED_NEGATIVE_PROMPT
from plantdreamer.guidance.schedules import TimestepSchedule
from plantdreamer.guidance.sds import StableDiffusionDepthGuidance
from plantdreamer.guidance.tiny import tiny_models

RES = 64  # SDS resolution for the tiny models (latents 8 x 8)


def make_guidance(**kwargs):
    kwargs.setdefault("components", tiny_models())
    kwargs.setdefault("resolution", RES)
    kwargs.setdefault("device", "cpu")
    return StableDiffusionDepthGuidance(**kwargs)


def cameras(n=2, size=48):
    return [orbit(4.0, 15.0 + 30.0 * i, 100.0 * i, 60.0, size, size) for i in range(n)]


def inputs(batch=2, size=48, seed=0):
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(batch, size, size, 3, generator=g).requires_grad_(True)
    depth = torch.rand(batch, 1, RES, RES, generator=g)
    return images, depth


def test_implementations_satisfy_the_protocol():
    assert isinstance(make_guidance(), Guidance)
    assert isinstance(NoGuidance(), Guidance)
    assert isinstance(PhotometricGuidance(torch.zeros(1, 4, 4, 3)), Guidance)


def test_one_step_gives_a_finite_nonzero_gradient_on_the_render():
    guidance = make_guidance()
    images, depth = inputs()
    out = guidance(images, depth, cameras(), step=0)
    assert out.loss.dim() == 0 and torch.isfinite(out.loss)
    out.loss.backward()
    assert images.grad is not None
    assert torch.isfinite(images.grad).all()
    assert images.grad.abs().sum() > 0
    assert set(out.stats) >= {"loss", "grad_norm", "timestep", "grad_clip"}
    assert 200 <= out.stats["timestep"] <= 980  # paper stage 1
    assert out.stats["grad_clip"] == 1.5


def reference_alphas_cumprod():
    """SD 2.1's training noise schedule, written out: scaled-linear betas."""
    betas = torch.linspace(0.00085**0.5, 0.012**0.5, 1000, dtype=torch.float64) ** 2
    return torch.cumprod(1.0 - betas, dim=0)


def test_sds_gradient_matches_a_hand_computed_step():
    parts = tiny_models(seed=1)
    guidance = make_guidance(components=parts, guidance_scale=7.5)
    g = torch.Generator().manual_seed(5)
    latents = torch.randn(2, 4, 8, 8, generator=g)
    noise = torch.randn(2, 4, 8, 8, generator=g)
    t = torch.tensor([37, 801])
    control = torch.rand(2, 3, RES, RES, generator=g)
    text = torch.randn(2, 77, 32, generator=g)
    uncond = torch.randn(1, 77, 32, generator=g).expand(2, -1, -1)

    grad = guidance.sds_gradient(latents, noise, t, text, uncond, control)

    ab = reference_alphas_cumprod()
    expected = []
    with torch.no_grad():
        for i in range(2):
            a = ab[t[i]].item()
            noisy = math.sqrt(a) * latents[i : i + 1] + math.sqrt(1 - a) * noise[i : i + 1]

            def eps(emb, i=i, noisy=noisy):
                down, mid = parts.controlnet(
                    noisy, t[i : i + 1], emb, control[i : i + 1], return_dict=False
                )
                return parts.unet(
                    noisy,
                    t[i : i + 1],
                    emb,
                    down_block_additional_residuals=down,
                    mid_block_additional_residual=mid,
                ).sample

            e_text, e_uncond = eps(text[i : i + 1]), eps(uncond[i : i + 1])
            e_hat = e_uncond + 7.5 * (e_text - e_uncond)
            expected.append((1 - a) * (e_hat - noise[i : i + 1]))
    torch.testing.assert_close(grad, torch.cat(expected), rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(guidance.alphas_cumprod.double(), ab, rtol=1e-6, atol=1e-7)


class FixedLatents(StableDiffusionDepthGuidance):
    """Replaces the VAE encoder by a leaf tensor so d loss / d latents can be read."""

    def __init__(self, latents, **kwargs):
        self.fixed = latents
        super().__init__(**kwargs)

    def encode(self, rgb):
        return self.fixed


def test_loss_gradient_is_the_clamped_sds_gradient_over_batch():
    schedule = TimestepSchedule([(None, 0.3, 0.6)])
    latents = torch.randn(2, 4, 8, 8, generator=torch.Generator().manual_seed(2))
    latents.requires_grad_(True)
    guidance = FixedLatents(
        latents, components=tiny_models(), resolution=RES, device="cpu", seed=11, schedule=schedule
    )
    images, depth = inputs()
    cams = cameras()
    step = 400
    out = guidance(images, depth, cams, step)
    out.loss.backward()

    # Replay the generator: the timesteps, then the noise (encode drew nothing here).
    replay = torch.Generator().manual_seed(11)
    t = schedule.sample_timestep(step, replay, 2)
    noise = torch.randn(latents.shape, generator=replay)
    text = torch.cat([guidance.text_embedding(p) for p in guidance.prompts_for(cams)])
    uncond = guidance.text_embedding(guidance.negative_prompt).expand(2, -1, -1)
    control = guidance.control_image(depth)
    grad = guidance.sds_gradient(latents, noise, t, text, uncond, control)
    clip = 1.5 + 0.5 * step / 1000
    assert out.stats["grad_clip"] == pytest.approx(clip)
    # Every sample's own draw is logged, not only their mean (the known-answer check reads them).
    assert out.stats["timesteps"] == [float(v) for v in t.tolist()]
    assert out.stats["timestep"] == pytest.approx(float(t.double().mean()))
    expected = torch.nan_to_num(grad).clamp(-clip, clip) / 2
    torch.testing.assert_close(latents.grad, expected)
    assert (grad.abs() > clip).any(), "CFG 100 should make the clamp active"
    torch.testing.assert_close(
        out.loss, 0.5 * (torch.nan_to_num(grad).clamp(-clip, clip) ** 2).sum() / 2
    )


def test_nan_predictions_become_zero_gradient():
    guidance = make_guidance()
    guidance.noise_prediction = lambda x, t, e, c: torch.full_like(x, float("nan"))
    images, depth = inputs()
    out = guidance(images, depth, cameras(), step=0)
    out.loss.backward()
    assert out.stats["nonfinite_grad"] > 0
    assert torch.isfinite(out.loss) and torch.isfinite(images.grad).all()


def test_a_run_is_reproducible_from_its_seed():
    def run(seed):
        guidance = make_guidance(seed=seed)
        images, depth = inputs()
        losses = []
        for step in range(2):
            out = guidance(images, depth, cameras(), step)
            out.loss.backward()
            losses.append(out.loss.item())
        return losses, images.grad.clone()

    (la, ga), (lb, gb), (lc, _) = run(0), run(0), run(1)
    assert la == lb
    assert torch.equal(ga, gb)
    assert la != lc


def test_depth_conditioning_changes_the_gradient():
    images, depth = inputs()
    a = make_guidance()(images, depth, cameras(), 0).loss
    b = make_guidance()(images, torch.zeros_like(depth), cameras(), 0).loss
    c = make_guidance(conditioning_scale=0.0)(images, depth, cameras(), 0).loss
    d = make_guidance(conditioning_scale=0.0)(images, torch.zeros_like(depth), cameras(), 0).loss
    assert a.item() != b.item()
    assert c.item() == d.item()  # scale 0 switches the ControlNet off


def test_text_embeddings_are_computed_once_per_prompt():
    guidance = make_guidance()
    calls = []
    encoder = guidance.parts.text_encoder
    original = encoder.forward

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    encoder.forward = counting
    images, depth = inputs()
    for step in range(3):
        guidance(images, depth, cameras(), step)
    # Two view prompts (front, side) and the negative prompt (the authors' by default).
    assert len(calls) == 3
    assert set(guidance._embeddings) == {
        "a bean plant in a pot, front view",
        "a bean plant in a pot, side view",
        RELEASED_NEGATIVE_PROMPT,
    }


def test_renders_of_any_size_are_resized():
    guidance = make_guidance()
    images = torch.rand(1, 30, 40, 3, requires_grad=True)
    out = guidance(images, torch.rand(1, 1, 17, 17), cameras(1, 30), 0)
    out.loss.backward()
    assert images.grad.shape == images.shape and images.grad.abs().sum() > 0


def test_bad_inputs_are_input_errors():
    guidance = make_guidance()
    images, depth = inputs()
    with pytest.raises(InputError, match="depth"):
        guidance(images, None, cameras(), 0)
    with pytest.raises(InputError):
        guidance(images, depth[:1], cameras(), 0)
    with pytest.raises(InputError):
        guidance(images, depth, cameras(1), 0)
    with pytest.raises(InputError):
        guidance(images[..., :2], depth, cameras(), 0)
    with pytest.raises(InputError):
        make_guidance(resolution=60)


def test_v_prediction_models_are_converted_to_epsilon():
    parts = tiny_models()
    parts.scheduler.register_to_config(prediction_type="v_prediction")
    guidance = make_guidance(components=parts)
    x = torch.randn(1, 4, 8, 8)
    t = torch.tensor([500])
    emb = guidance.text_embedding("x")
    control = torch.rand(1, 3, RES, RES)
    guidance.prediction_type = "epsilon"
    raw = guidance.noise_prediction(x, t, emb, control)
    guidance.prediction_type = "v_prediction"
    eps = guidance.noise_prediction(x, t, emb, control)
    a = guidance.alphas_cumprod[500]
    torch.testing.assert_close(eps, a.sqrt() * raw + (1 - a).sqrt() * x)


def test_no_guidance_and_photometric_guidance():
    images = torch.rand(2, 4, 4, 3, requires_grad=True)
    out = NoGuidance()(images, None, cameras(), 0)
    out.loss.backward()
    assert out.loss.item() == 0.0 and torch.equal(images.grad, torch.zeros_like(images))

    target = torch.rand(4, 4, 3)
    images.grad = None
    out = PhotometricGuidance(target)(images, None, cameras(), 0)
    out.loss.backward()
    torch.testing.assert_close(out.loss, ((images - target) ** 2).mean())
    torch.testing.assert_close(images.grad, 2 * (images - target).detach() / images.numel())
    with pytest.raises(InputError):
        PhotometricGuidance(torch.rand(3, 5, 5, 3))(images, None, cameras(), 0)


def test_half_precision_networks_keep_a_float32_vae():
    # bfloat16 on the CPU stands in for CUDA's fp16 path (no GPU in CI).
    guidance = make_guidance(dtype=torch.bfloat16)
    assert guidance.parts.unet.dtype == torch.bfloat16
    assert guidance.parts.controlnet.dtype == torch.bfloat16
    assert guidance.parts.vae.dtype == torch.float32
    images, depth = inputs()
    out = guidance(images, depth, cameras(), 0)
    out.loss.backward()
    assert out.loss.dtype == torch.float32
    assert torch.isfinite(images.grad).all() and images.grad.abs().sum() > 0
