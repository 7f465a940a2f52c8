"""A cheap gate on a known-answer model set, before any SDS run: does classifier-free
guidance point from wrong colours towards the true ones?

SDS descends ``w(t) * (eps_hat - eps)`` with ``eps_hat = eps_u + s * (eps_c - eps_u)``, so
the part CFG amplifies moves a latent along ``-(eps_c - eps_u)``. For a wrong-colour render
``z_wrong`` of a view whose true latent is ``z_true``, models that carry the answer give a
CFG direction ``eps_c - eps_u`` with a clearly positive cosine to ``z_wrong - z_true``.
Random models give about zero; models on a VAE that was blind to colour gave 0.01-0.37 and
SDS did not move colours towards the truth; the current recipe gives 0.59-0.89 (bean seed
0, docs/known_answer.md).

SDS does not apply that direction to the latent but to the render, through the encoder's
backward: the pixel step is ``-J^T (eps_c - eps_u)``. ``pixel_cosine`` measures that step
against ``x_true - x_wrong`` on the plant's pixels. It can disagree with the latent cosine:
for a white plant, generator version 5 models (bean seed 0) pointed the latent at the truth
(0.93 at t = 100) and the pixel step away from it (-0.12), and SDS from white stalled;
version 6 models give 0.80 and 0.39 (docs/known_answer.md).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from plantdreamer.known_answer.spec import KnownAnswerSpec
from plantdreamer.known_answer.views import ViewSet

GATE_TIMESTEPS = (100, 300, 600, 900)


@dataclass(frozen=True)
class CfgDirection:
    timestep: int
    cosine: float  # of eps_c - eps_u with z_wrong - z_true, over all samples together
    relative_size: float  # |eps_c - eps_u| / |eps|
    # Of the pixel step -J^T (eps_c - eps_u) with x_true - x_wrong on the plant's pixels
    # (alpha > 0.5), and the share of those pixels' channels it moves the right way.
    pixel_cosine: float
    pixel_agreement: float


def _latents(vae: Any, images: torch.Tensor) -> torch.Tensor:
    return vae.encode(images * 2.0 - 1.0).latent_dist.mean * vae.config.scaling_factor


def _predict(parts: Any, z_t: torch.Tensor, t: torch.Tensor, emb: torch.Tensor, control: Any):  # type: ignore[no-untyped-def]
    down, mid = parts.controlnet(
        z_t, t, encoder_hidden_states=emb, controlnet_cond=control, return_dict=False
    )
    return parts.unet(
        z_t,
        t,
        encoder_hidden_states=emb,
        down_block_additional_residuals=down,
        mid_block_additional_residual=mid,
    ).sample


def cfg_direction(
    parts: Any,
    data: ViewSet,
    negative_prompt: str,
    timesteps: Sequence[int] = GATE_TIMESTEPS,
    seed: int = 0,
) -> list[CfgDirection]:
    """The CFG direction measured on ``data``'s wrong-colour renders (use views the models
    never saw), one entry per timestep, the same noise for both branches; in the latent,
    and as the pixel step SDS makes of it through the encoder (the posterior's mean)."""
    from plantdreamer.guidance.text import PromptEmbeddings

    embed = PromptEmbeddings(parts.tokenizer, parts.text_encoder, "cpu")
    view = data.recoloured_view
    with torch.no_grad():
        text = embed.batch([data.prompts[int(i)] for i in view])
        negative = embed(negative_prompt).expand(len(view), -1, -1)
        z_true = _latents(parts.vae, data.images[view])
    wrong = data.recoloured.clone().requires_grad_(True)
    z_wrong = _latents(parts.vae, wrong)
    control = data.depth[view].repeat(1, 3, 1, 1)
    towards_wrong = (z_wrong.detach() - z_true).flatten()
    plant = (data.alpha[view] > 0.5).expand_as(wrong)
    towards_true = (data.images[view] - data.recoloured)[plant]
    gen = torch.Generator().manual_seed(seed)
    out = []
    for step in timesteps:
        t = torch.full((len(view),), int(step), dtype=torch.long)
        a = parts.scheduler.alphas_cumprod[int(step)]
        eps = torch.randn(z_wrong.shape, generator=gen)
        with torch.no_grad():
            z_t = a.sqrt() * z_wrong + (1.0 - a).sqrt() * eps
            d = _predict(parts, z_t, t, text, control) - _predict(parts, z_t, t, negative, control)
        (pull,) = torch.autograd.grad(z_wrong, wrong, grad_outputs=d, retain_graph=True)
        pixel_step = -pull[plant]
        cosine = torch.nn.functional.cosine_similarity(d.flatten(), towards_wrong, dim=0)
        pixel_cosine = torch.nn.functional.cosine_similarity(pixel_step, towards_true, dim=0)
        moved = towards_true.abs() > 0.02  # channels already right carry no sign
        agree = (torch.sign(pixel_step) == torch.sign(towards_true))[moved].float().mean()
        out.append(
            CfgDirection(
                int(step),
                float(cosine),
                float(d.norm() / eps.norm()),
                float(pixel_cosine),
                float(agree),
            )
        )
    return out


@torch.no_grad()
def colour_gap(vae: Any, data: ViewSet) -> float:
    """|z_wrong - z_true| / |z_true| over ``data``'s wrong-colour renders: how much the
    encoder sees of a plant's colours. A VAE trained on true colours only, with the plant's
    1.4% of the pixels unweighted, gave 0.023 (bean seed 1; SDS could not tell wrong colours
    from the truth); version 5 models gave 0.119 and version 6 models 0.229 (bean seed 0;
    docs/known_answer.md)."""
    z_true = _latents(vae, data.images[data.recoloured_view])
    z_wrong = _latents(vae, data.recoloured)
    return float((z_wrong - z_true).norm() / z_true.norm())


def gate_on_unseen_views(
    models: Path,
    spec: KnownAnswerSpec,
    work_dir: Path,
    views_count: int = 16,
    flat_colour: float | None = None,
) -> tuple[float, list[CfgDirection]]:
    """``colour_gap`` and ``cfg_direction`` of the model folder ``models`` (``base/``,
    ``controlnet/``) on ``views_count`` views of ``spec``'s plant from a camera stream no
    model trained on; wrong colours as the models were trained on, or (``flat_colour``)
    every Gaussian that grey level, as ``--color-init black`` (0) or ``white`` (1) starts."""
    from plantdreamer.guidance.config import SDS_DEFAULTS
    from plantdreamer.guidance.models import load_components
    from plantdreamer.known_answer import views
    from plantdreamer.known_answer.build import model_dirs

    base, control = model_dirs(models)
    parts = load_components(str(base), str(control))
    unseen = dataclasses.replace(spec, train_views=views_count, recoloured_views=views_count)
    truth = views.true_gaussians(spec, work_dir)
    paint = views.recolour if flat_colour is None else views.flat_colours(flat_colour)
    data = views.training_views(unseen, truth, views.GATE_STREAM, paint)
    gap = colour_gap(parts.vae, data)
    return gap, cfg_direction(parts, data, SDS_DEFAULTS.negative_prompt, seed=spec.seed)
