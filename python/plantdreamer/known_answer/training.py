"""Training the tiny models on a plant's true views: the VAE as an autoencoder, then the
UNet and depth ControlNet as a conditional noise predictor with classifier-free guidance.

The shipped tiny VAE is random: its latents are mostly posterior noise, so SDS through it
cannot see colour. Trained here as an autoencoder (its posterior's variance penalised, so
it stays narrow; the plant's pixels weighted up; half of each batch wrong-colour renders, so
the encoder must carry colour), its ``scaling_factor`` is then set to 1 / std of the true
views' latents, as Stable Diffusion's 0.18215 was chosen. The UNet and ControlNet learn epsilon on those latents;
with probability ``uncond_prob`` a sample gets the pipeline's negative prompt, and half of
those show wrong colours, so that conditional minus unconditional points at the truth.

Everything runs on the CPU on a pinned number of threads (one unless asked) from seeded
generators: same spec, thread count and library versions, same bits.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from plantdreamer.known_answer.spec import KnownAnswerSpec
from plantdreamer.known_answer.views import ViewSet

# Weight of the posterior's variance in the VAE loss: it keeps the posterior narrow, so an
# encoding carries the image rather than sampling noise. (A KL term to N(0, I) lets the
# channels the decoder ignores fall back to unit noise: posterior std 0.85 of the latents'
# spread, and SDS through it barely moved a plant's colours.)
VARIANCE_WEIGHT = 1.0
VAE_LEARNING_RATE = 2e-3
LEARNING_RATE = 1e-3


def _schedule(optimizer: torch.optim.Optimizer, steps: int) -> Any:
    return torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda i: 0.5 * (1.0 + math.cos(math.pi * i / steps))
    )


def train_vae(vae: Any, data: ViewSet, spec: KnownAnswerSpec) -> dict[str, float]:
    """Autoencoder training of ``vae`` in place on ``data``'s true and wrong-colour views."""
    from diffusers.models.autoencoders.vae import DiagonalGaussianDistribution

    gen = torch.Generator().manual_seed(spec.seed * 7919 + 1)
    vae.train().requires_grad_(True)
    optimizer = torch.optim.Adam(vae.parameters(), lr=VAE_LEARNING_RATE)
    schedule = _schedule(optimizer, max(spec.vae_steps, 1))
    true_x, wrong_x = data.images * 2.0 - 1.0, data.recoloured * 2.0 - 1.0
    true_w = 1.0 + spec.vae_mask_weight * data.alpha
    wrong_w = true_w[data.recoloured_view]
    n_wrong = round(spec.batch * spec.vae_recoloured_share)
    recon = float("nan")
    for _ in range(spec.vae_steps):
        i = torch.randint(len(true_x), (spec.batch - n_wrong,), generator=gen)
        j = torch.randint(len(wrong_x), (n_wrong,), generator=gen)
        x, w = torch.cat([true_x[i], wrong_x[j]]), torch.cat([true_w[i], wrong_w[j]])
        posterior = DiagonalGaussianDistribution(vae.encode(x).latent_dist.parameters)
        z = posterior.sample(generator=gen)
        loss_recon = (w * (vae.decode(z).sample - x) ** 2).mean() / w.mean()
        loss = loss_recon + VARIANCE_WEIGHT * posterior.var.mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        schedule.step()
        recon = float(loss_recon.detach())
    vae.eval().requires_grad_(False)
    with torch.no_grad():
        dist = vae.encode(true_x).latent_dist
        scale = 1.0 / float(dist.mean.std())
    vae.register_to_config(scaling_factor=scale)
    return {
        "vae_recon_mse": recon,
        "vae_scaling_factor": scale,
        "vae_posterior_std": float(dist.std.mean()) * scale,
    }


def denoiser(width: int, seed: int) -> tuple[Any, Any]:
    """A UNet and depth ControlNet of the shipped tiny structure at ``width`` channels (then
    2 * width), cross-attending to the tiny text encoder; the ControlNet's output
    convolutions start at zero, as ControlNet training starts."""
    from diffusers import ControlNetModel, UNet2DConditionModel

    from plantdreamer.guidance.tiny import TINY_TEXT_DIM

    torch.manual_seed(seed)
    unet = UNet2DConditionModel(
        sample_size=8,
        in_channels=4,
        out_channels=4,
        layers_per_block=1,
        block_out_channels=(width, 2 * width),
        down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
        up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
        cross_attention_dim=TINY_TEXT_DIM,
        attention_head_dim=(max(2, width // 16), max(4, width // 8)),
        norm_num_groups=8,
        use_linear_projection=True,
    )
    controlnet = ControlNetModel.from_unet(unet, conditioning_embedding_out_channels=(8, 8, 16, 16))
    return unet, controlnet


def _latent_moments(vae: Any, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    with torch.no_grad():
        dist = vae.encode(images * 2.0 - 1.0).latent_dist
    scale = vae.config.scaling_factor
    return dist.mean * scale, dist.std * scale


def train_denoiser(
    parts: Any, views: ViewSet, spec: KnownAnswerSpec, negative_prompt: str
) -> dict[str, float]:
    """Epsilon training of ``parts.unet`` and ``parts.controlnet`` in place."""
    from plantdreamer.guidance.text import PromptEmbeddings

    gen = torch.Generator().manual_seed(spec.seed * 7919 + 2)
    embed = PromptEmbeddings(parts.tokenizer, parts.text_encoder, "cpu")
    text = embed.batch(views.prompts)
    negative = embed(negative_prompt)
    mean, std = _latent_moments(parts.vae, views.images)
    wrong_mean, wrong_std = _latent_moments(parts.vae, views.recoloured)
    control = views.depth.repeat(1, 3, 1, 1)
    alphas = parts.scheduler.alphas_cumprod
    steps = int(parts.scheduler.config.num_train_timesteps)
    params = [*parts.unet.parameters(), *parts.controlnet.parameters()]
    for model in (parts.unet, parts.controlnet):
        model.train().requires_grad_(True)
    optimizer = torch.optim.Adam(params, lr=LEARNING_RATE)
    schedule = _schedule(optimizer, max(spec.denoiser_steps, 1))
    loss_value = float("nan")
    b = spec.batch
    for _ in range(spec.denoiser_steps):
        idx = torch.randint(len(mean), (b,), generator=gen)
        z = mean[idx] + std[idx] * torch.randn(mean[idx].shape, generator=gen)
        emb = text[idx].clone()
        uncond = torch.rand(b, generator=gen) < spec.uncond_prob
        wrong = uncond & (torch.rand(b, generator=gen) < spec.recoloured_prob)
        emb[uncond] = negative[0]
        if wrong.any():
            pick = torch.randint(len(wrong_mean), (int(wrong.sum()),), generator=gen)
            noise_z = torch.randn(wrong_mean[pick].shape, generator=gen)
            z[wrong] = wrong_mean[pick] + wrong_std[pick] * noise_z
            idx[wrong] = views.recoloured_view[pick]  # the depth of the view it shows
        shift = torch.zeros_like(z)  # z - z_true of the samples shown with a corrected target
        if spec.corrected_prob > 0.0:
            fix = ~uncond & (torch.rand(b, generator=gen) < spec.corrected_prob)
            if fix.any():
                pick = torch.randint(len(wrong_mean), (int(fix.sum()),), generator=gen)
                view = views.recoloured_view[pick]
                noise_z = torch.randn(wrong_mean[pick].shape, generator=gen)
                z[fix] = wrong_mean[pick] + wrong_std[pick] * noise_z
                shift[fix] = z[fix] - mean[view]
                emb[fix] = text[view]
                idx[fix] = view
        t = torch.randint(steps, (b,), generator=gen)
        eps = torch.randn(z.shape, generator=gen)
        a = alphas[t].view(-1, 1, 1, 1)
        z_t = a.sqrt() * z + (1.0 - a).sqrt() * eps
        # The noise that would make z_t from the *true* latent: the conditional branch then
        # learns to point a wrong-colour latent at the truth (weight 1 - a keeps it bounded).
        target = eps + (a / (1.0 - a)).sqrt() * shift
        weight = torch.where(shift.flatten(1).any(1).view(-1, 1, 1, 1), 1.0 - a, 1.0)
        down, mid = parts.controlnet(
            z_t, t, encoder_hidden_states=emb, controlnet_cond=control[idx], return_dict=False
        )
        pred = parts.unet(
            z_t,
            t,
            encoder_hidden_states=emb,
            down_block_additional_residuals=down,
            mid_block_additional_residual=mid,
        ).sample
        loss = (weight * (pred - target) ** 2).mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        schedule.step()
        loss_value = float(loss.detach())
    for model in (parts.unet, parts.controlnet):
        model.eval().requires_grad_(False)
    return {"denoiser_loss": loss_value}
