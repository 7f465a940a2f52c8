"""The LoRA training objective: noise (or velocity) prediction on VAE latents.

``NoiseLoss.random_step`` draws a training batch (images, crops, flips, VAE posterior
samples, noise, timesteps) from one seeded generator; ``NoiseLoss.evaluate`` measures the loss
on a fixed held-out set (centre crops, posterior means, fixed noise and timesteps), so runs
can be compared and a test can tell that training lowered the loss.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from plantdreamer.guidance.models import DiffusionComponents
from plantdreamer.guidance.text import PromptEmbeddings
from plantdreamer.lora.dataset import Example, augment

EVAL_IMAGES = 8
EVAL_TIMESTEPS = (100, 300, 500, 700, 900)  # per 1000 training timesteps


class NoiseLoss:
    """The denoising objective on VAE latents of a batch of [B, 3, R, R] images."""

    def __init__(self, parts: DiffusionComponents, device: torch.device, weight_dtype: torch.dtype):
        self.parts = parts
        self.device = device
        self.weight_dtype = weight_dtype
        self.num_timesteps = int(parts.scheduler.config.num_train_timesteps)
        self.v_prediction = parts.scheduler.config.prediction_type == "v_prediction"
        self._embeddings = PromptEmbeddings(parts.tokenizer, parts.text_encoder, device)

    def embed(self, captions: list[str]) -> torch.Tensor:
        return self._embeddings.batch(captions)

    @torch.no_grad()
    def latents(self, pixels: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        vae = self.parts.vae
        x = (pixels * 2.0 - 1.0).to(self.device, self.weight_dtype)
        dist = vae.encode(x).latent_dist
        z = dist.sample(generator=generator) if generator is not None else dist.mean
        return (z * vae.config.scaling_factor).float()

    def __call__(
        self,
        latents: torch.Tensor,
        captions: list[str],
        noise: torch.Tensor,
        timesteps: torch.Tensor,
    ) -> torch.Tensor:
        scheduler = self.parts.scheduler
        noise = noise.to(self.device)
        timesteps = timesteps.to(self.device)
        noisy = scheduler.add_noise(latents, noise, timesteps)
        target = scheduler.get_velocity(latents, noise, timesteps) if self.v_prediction else noise
        with torch.autocast(
            self.device.type, dtype=torch.float16, enabled=self.weight_dtype == torch.float16
        ):
            pred = self.parts.unet(
                noisy.to(self.weight_dtype), timesteps, self.embed(captions)
            ).sample
        return F.mse_loss(pred.float(), target.float())

    def random_step(
        self, examples: list[Example], batch_size: int, resolution: int, generator: torch.Generator
    ) -> torch.Tensor:
        """Loss of one random batch: images, crops, flips, VAE sample, noise, timesteps."""
        idx = torch.randint(0, len(examples), (batch_size,), generator=generator).tolist()
        pixels = torch.stack([augment(examples[i].image, resolution, generator) for i in idx])
        latents = self.latents(pixels, generator)
        noise = torch.randn(latents.shape, generator=generator)
        t = torch.randint(0, self.num_timesteps, (batch_size,), generator=generator)
        return self(latents, [examples[i].caption for i in idx], noise, t)

    @torch.no_grad()
    def evaluate(self, examples: list[Example], resolution: int, seed: int) -> float:
        """Loss on a fixed set (centre crops, posterior means, fixed noise and timesteps)."""
        generator = torch.Generator().manual_seed(seed + 7919)
        total, count = 0.0, 0
        for example in examples[:EVAL_IMAGES]:
            _, h, w = example.image.shape
            top, left = (h - resolution) // 2, (w - resolution) // 2
            pixels = example.image[None, :, top : top + resolution, left : left + resolution]
            latents = self.latents(pixels, None).expand(len(EVAL_TIMESTEPS), -1, -1, -1)
            noise = torch.randn(latents.shape, generator=generator)
            t = torch.tensor(EVAL_TIMESTEPS)
            t = (t * self.num_timesteps) // 1000
            total += float(self(latents, [example.caption] * len(t), noise, t))
            count += 1
        return total / count
