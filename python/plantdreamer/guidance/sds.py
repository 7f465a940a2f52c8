"""Score distillation (SDS) with Stable Diffusion 2.1, a depth ControlNet and a species LoRA.

One call, for renders x [B, H, W, 3] in [0, 1] and cleaned depth maps d:

1. clamp x to [0, 1] (as the released code does: a render's additive blending can exceed 1),
   resize it to ``resolution`` (512) and VAE-encode: z = E(2x - 1) * scaling_factor
   (a posterior sample, drawn from the seeded generator);
2. draw t per image from the timestep schedule and noise eps ~ N(0, I); z_t = add_noise(z, eps, t);
3. ControlNet residuals from d (as a 3-channel image) for both classifier-free-guidance
   branches, then the UNet noise prediction for the view prompt and the negative prompt
   (the authors' released negative prompt by default: it is the unconditional branch);
4. CFG: eps_hat = eps_uncond + s (eps_text - eps_uncond), s = ``guidance_scale`` (100);
5. grad = w(t) (eps_hat - eps) with w(t) = 1 - alpha_bar_t; ``nan_to_num``; clamp to [-c, c]
   with c rising linearly 1.5 -> 2.0 over the first 1000 steps;
6. loss = 0.5 ||z - stopgrad(z - grad)||^2 / B, so d loss / d z = grad / B, which flows back
   through the VAE encoder into the renders.

The released code writes CFG as ``eps_text + s (eps_text - eps_uncond)`` (GaussianDreamer's
form), which equals the standard form above with s + 1; use ``guidance_scale=101`` to match it
exactly. A ``v_prediction`` base model (SD 2.1 at 768 px) is converted to epsilon first.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError
from plantdreamer.guidance.base import (
    TIMESTEPS_STAT,
    GuidanceOutput,
    PendingOutput,
    check_images,
)
from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE, RESIZE_MODES, SDS_DEFAULTS
from plantdreamer.guidance.cuda_graph import GraphedAutogradCall, GraphedCall
from plantdreamer.guidance.depth import resize_control
from plantdreamer.guidance.lora_weights import load_lora
from plantdreamer.guidance.models import (
    DEFAULT_VAE_DTYPE,
    DiffusionComponents,
    deterministic_attention,
    load_components,
    make_cuda_deterministic,
    resolve_device,
    resolve_dtype,
)
from plantdreamer.guidance.prompts import camera_prompt, check_template
from plantdreamer.guidance.schedules import REFERENCE_STEPS, TimestepSchedule, make_schedule, ramp
from plantdreamer.guidance.text import PromptEmbeddings
from plantdreamer.guidance.transfer import to_device

# threestudio's grad_clip [start_step, start_value, end_value, end_step] of the released config.
DEFAULT_GRAD_CLIP = (0, 1.5, 2.0, 1000)


class StableDiffusionDepthGuidance:
    """SDS guidance; see the module docstring. Heavy: loads several GB of weights.

    ``components`` injects already-built models (tests use ``tiny_models()``); they are
    moved, frozen and, with ``lora``, modified in place. ``resolution`` is the SDS image size
    (512 for SD 2.1; a multiple of the VAE's downsampling factor). ``grad_clip`` is
    threestudio's ``(start_step, start_value, end_value, end_step)`` ramp, or None for no clamp.
    ``prompt_template`` builds the view prompts; ``control_resize`` ("bilinear" or "nearest")
    resizes the depth map to ``resolution``.
    UNet, ControlNet and text encoder run in ``dtype`` (fp16 on CUDA by default); the VAE in
    ``vae_dtype`` (float32 by default, because its backward pass produces the render
    gradients; None = ``dtype``). On CUDA, ``cuda_graph`` replays ControlNet + UNet and the
    VAE encoder from CUDA graphs captured on the first step (same bits as eager calls).
    """

    needs_depth = True

    def __init__(
        self,
        base_model: str | Path = SDS_DEFAULTS.base_model,
        controlnet: str | Path = SDS_DEFAULTS.controlnet,
        lora: str | Path | None = SDS_DEFAULTS.lora,
        species: str = "bean",
        guidance_scale: float = SDS_DEFAULTS.guidance_scale,
        conditioning_scale: float = SDS_DEFAULTS.conditioning_scale,
        schedule: str
        | TimestepSchedule
        | Sequence[tuple[int | None, float, float]] = SDS_DEFAULTS.schedule,
        total_steps: int = REFERENCE_STEPS,
        negative_prompt: str = SDS_DEFAULTS.negative_prompt,
        prompt_template: str = DEFAULT_PROMPT_TEMPLATE,
        control_resize: str = SDS_DEFAULTS.control_resize,
        device: str | torch.device | None = None,
        dtype: torch.dtype | str | None = None,
        seed: int = 0,
        components: DiffusionComponents | Mapping[str, Any] | None = None,
        resolution: int = SDS_DEFAULTS.resolution,
        grad_clip: tuple[int, float, float, int] | None = DEFAULT_GRAD_CLIP,
        lora_scale: float = 1.0,
        vae_dtype: torch.dtype | str | None = DEFAULT_VAE_DTYPE,
        cuda_graph: bool = True,
    ):
        self.device = resolve_device(device)
        if self.device.type == "cuda":
            make_cuda_deterministic()
        self.dtype = resolve_dtype(dtype, self.device)
        # The VAE encoder is the one network we backpropagate through; in fp16 its backward
        # pass can overflow into the render gradients, where no nan_to_num guards them.
        self.vae_dtype = self.dtype if vae_dtype is None else resolve_dtype(vae_dtype, self.device)
        if components is None:
            parts = load_components(
                str(base_model), str(controlnet), dtype=self.dtype, vae_dtype=self.vae_dtype
            )
        elif isinstance(components, Mapping):
            parts = DiffusionComponents(**components)
        else:
            parts = components
        if lora is not None:
            load_lora(parts.unet, lora, parts.text_encoder, scale=lora_scale)
        self.parts = parts.prepare(self.device, self.dtype, self.vae_dtype)
        # ControlNet + UNet and the VAE encoder (forward and backward) replayed from CUDA
        # graphs: on CUDA their eager calls are bound by kernel launches (cuda_graph.py).
        graphs = cuda_graph and self.device.type == "cuda"
        self._networks = GraphedCall(self._unet_with_control) if graphs else self._unet_with_control
        self._vae_moments = GraphedAutogradCall(self._vae_encoder) if graphs else self._vae_encoder

        vae_factor = 2 ** (len(parts.vae.config.block_out_channels) - 1)
        if resolution <= 0 or resolution % vae_factor:
            raise InputError(
                f"resolution must be a positive multiple of {vae_factor}, got {resolution}"
            )
        self.resolution = resolution
        self.species = species
        self.guidance_scale = float(guidance_scale)
        self.conditioning_scale = float(conditioning_scale)
        self.negative_prompt = negative_prompt
        self.prompt_template = check_template(prompt_template)
        if control_resize not in RESIZE_MODES:
            raise InputError(f"control resize must be bilinear or nearest, got {control_resize!r}")
        self.control_resize = control_resize
        self.grad_clip = grad_clip
        self.schedule = make_schedule(schedule, total_steps)
        scheduler = parts.scheduler
        self.num_train_timesteps = int(scheduler.config.num_train_timesteps)
        self.prediction_type = getattr(scheduler.config, "prediction_type", "epsilon")
        if self.prediction_type not in ("epsilon", "v_prediction"):
            raise InputError(f"unsupported prediction type {self.prediction_type!r}")
        self.alphas_cumprod = scheduler.alphas_cumprod.to(self.device, torch.float32)
        # On the guidance's device: the posterior sample, the timesteps and the SDS noise are
        # drawn where they are used, so no draw waits for the device to copy it over (on
        # CUDA a copy from pageable host memory stalls the host until the GPU catches up).
        self.generator = torch.Generator(self.device).manual_seed(seed)
        self._embeddings = PromptEmbeddings(
            self.parts.tokenizer, self.parts.text_encoder, self.device, self.dtype
        )

    # -- text -------------------------------------------------------------------------------

    def text_embedding(self, prompt: str) -> torch.Tensor:
        """[1, tokens, dim] CLIP hidden states of a prompt, computed once per prompt."""
        return self._embeddings(prompt)

    def prompts_for(self, cameras: Sequence[Camera]) -> list[str]:
        return [camera_prompt(self.species, c, self.prompt_template) for c in cameras]

    # -- latents ----------------------------------------------------------------------------

    def encode(self, rgb: torch.Tensor) -> torch.Tensor:
        """[B, 3, R, R] in [0, 1] -> float32 latents (differentiable)."""
        from diffusers.models.autoencoders.vae import DiagonalGaussianDistribution

        moments = self._vae_moments((rgb * 2.0 - 1.0).to(self.vae_dtype))
        latents = DiagonalGaussianDistribution(moments).sample(generator=self.generator)
        return (latents * self.parts.vae.config.scaling_factor).float()

    def _vae_encoder(self, x: torch.Tensor) -> torch.Tensor:
        """The posterior's parameters (mean and log-variance stacked on channels)."""
        with deterministic_attention(self.device):
            return self.parts.vae.encode(x).latent_dist.parameters

    def control_image(self, depth_cond: torch.Tensor) -> torch.Tensor:
        """[B, 1, h, w] depth in [0, 1] -> [B, 3, R, R] ControlNet input."""
        if depth_cond.dim() != 4 or depth_cond.shape[1] != 1:
            raise InputError(f"depth_cond must be [B, 1, h, w], got {list(depth_cond.shape)}")
        control = to_device(depth_cond.detach().float(), self.device)
        if control.shape[-2:] != (self.resolution, self.resolution):
            control = resize_control(control, self.resolution, self.control_resize)
        return control.clamp(0.0, 1.0).repeat(1, 3, 1, 1).to(self.dtype)

    # -- the SDS gradient -------------------------------------------------------------------

    @torch.no_grad()
    def noise_prediction(
        self,
        latents_noisy: torch.Tensor,
        t: torch.Tensor,
        embeddings: torch.Tensor,
        control: torch.Tensor,
    ) -> torch.Tensor:
        """UNet epsilon prediction with ControlNet residuals (float32, same batch)."""
        out = self._networks(latents_noisy.to(self.dtype), t, embeddings, control).float()
        if self.prediction_type == "v_prediction":
            a = self.alphas_cumprod[t].view(-1, 1, 1, 1)
            out = a.sqrt() * out + (1.0 - a).sqrt() * latents_noisy.float()
        return out

    def _unet_with_control(
        self, x: torch.Tensor, t: torch.Tensor, embeddings: torch.Tensor, control: torch.Tensor
    ) -> torch.Tensor:
        down, mid = self.parts.controlnet(
            x,
            t,
            encoder_hidden_states=embeddings,
            controlnet_cond=control,
            conditioning_scale=self.conditioning_scale,
            return_dict=False,
        )
        return self.parts.unet(
            x,
            t,
            encoder_hidden_states=embeddings,
            down_block_additional_residuals=down,
            mid_block_additional_residual=mid,
        ).sample

    def branch_predictions(
        self,
        latents: torch.Tensor,
        noise: torch.Tensor,
        t: torch.Tensor,
        text_embeddings: torch.Tensor,
        uncond_embeddings: torch.Tensor,
        control: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(z_t, eps_text, eps_uncond): the latents noised at t and both CFG branches' noise
        predictions, float32. The SDS step's one path from latents to predictions; the
        known-answer denoiser check scores it too."""
        latents = latents.detach().float()
        latents_noisy = self.parts.scheduler.add_noise(latents, noise, t)
        eps = self.noise_prediction(
            torch.cat([latents_noisy, latents_noisy]),
            torch.cat([t, t]),
            torch.cat([text_embeddings, uncond_embeddings]),
            torch.cat([control, control]),
        )
        eps_text, eps_uncond = eps.chunk(2)
        return latents_noisy, eps_text, eps_uncond

    def sds_gradient(
        self,
        latents: torch.Tensor,
        noise: torch.Tensor,
        t: torch.Tensor,
        text_embeddings: torch.Tensor,
        uncond_embeddings: torch.Tensor,
        control: torch.Tensor,
    ) -> torch.Tensor:
        """w(t) (eps_hat - eps) before ``nan_to_num`` and clamping (float32)."""
        _, eps_text, eps_uncond = self.branch_predictions(
            latents, noise, t, text_embeddings, uncond_embeddings, control
        )
        eps_hat = eps_uncond + self.guidance_scale * (eps_text - eps_uncond)
        w = (1.0 - self.alphas_cumprod[t]).view(-1, 1, 1, 1)
        return w * (eps_hat - noise)

    def clip_value(self, step: int) -> float | None:
        if self.grad_clip is None:
            return None
        return ramp(step, *self.grad_clip)

    def __call__(
        self,
        images: torch.Tensor,
        depth_cond: torch.Tensor | None,
        cameras: Sequence[Camera],
        step: int,
    ) -> GuidanceOutput:
        return self.launch(images, depth_cond, cameras, step).result()

    def launch(
        self,
        images: torch.Tensor,
        depth_cond: torch.Tensor | None,
        cameras: Sequence[Camera],
        step: int,
    ) -> PendingOutput:
        """The call's work queued on the device, nothing waiting for it: no figure is read
        back here (the draws, the networks and the loss stay on the device)."""
        check_images(images, cameras)
        if depth_cond is None:
            raise InputError("Stable Diffusion depth guidance needs depth conditioning")
        batch = images.shape[0]
        if depth_cond.shape[0] != batch:
            raise InputError(f"got {depth_cond.shape[0]} depth maps for {batch} images")
        control = self.control_image(depth_cond)

        rgb = to_device(images.clamp(0.0, 1.0).permute(0, 3, 1, 2), self.device)
        if rgb.shape[-2:] != (self.resolution, self.resolution):
            rgb = F.interpolate(
                rgb, (self.resolution, self.resolution), mode="bilinear", align_corners=False
            )
        latents = self.encode(rgb)

        t = self.schedule.sample_timestep(step, self.generator, batch, self.num_train_timesteps)
        noise = torch.randn(latents.shape, generator=self.generator, device=self.device)
        text = torch.cat([self.text_embedding(p) for p in self.prompts_for(cameras)])
        uncond = self.text_embedding(self.negative_prompt).expand(batch, -1, -1)
        grad = self.sds_gradient(latents, noise, t, text, uncond, control)

        nonfinite = (~torch.isfinite(grad)).sum()
        grad = torch.nan_to_num(grad)
        clip = self.clip_value(step)
        if clip is not None:
            grad = grad.clamp(-clip, clip)
        # d loss / d latents = (latents - target) / B = grad / B.
        target = (latents - grad).detach()
        loss = 0.5 * F.mse_loss(latents, target, reduction="sum") / batch
        lo, hi = self.schedule.bounds(step, self.num_train_timesteps)
        # Device-side figures stay there: they are read back in one copy, after the device
        # is done (each float() would wait for it on its own). The count is exact in float64.
        stats: dict[str, float | list[float] | torch.Tensor] = {
            "loss": loss.detach(),
            "grad_norm": grad.norm(),
            "timestep": t.float().mean(),
            TIMESTEPS_STAT: t,  # each sample's own: the mean hides a wrong one
            "t_min": float(lo),
            "t_max": float(hi),
            "grad_clip": float("nan") if clip is None else clip,
            "nonfinite_grad": nonfinite,
        }
        return PendingOutput(loss=loss, stats=stats)
