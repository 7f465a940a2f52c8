"""What a known-answer model set is made from: the one place its defaults are written."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from typing import Any

from plantdreamer.errors import InputError

# Bumped whenever the generator's code changes what it makes (it is part of the cache key).
GENERATOR_VERSION = 6

# Steps of the scored runs: the 100. With the views in generate's scene frame
# (generator version 6) and the VAE trained 1600 steps, bean seeds 0 / 1 / 2 gain 4.2 / 5.4
# / 5.4 dB in 100 steps (docs/known_answer.md).
CHECK_STEPS = 100


@dataclass(frozen=True)
class KnownAnswerSpec:
    """A plant (species and seed, as ``generate`` makes it) at one render size, and how long
    the tiny VAE and the UNet + depth ControlNet train on its true views."""

    species: str = "bean"
    seed: int = 0
    resolution: int = 64  # training render size and SDS image size (one latent per 8 px)
    points: int = 100_000  # Gaussians the plant starts from (generate's --points)
    train_views: int = 600
    recoloured_views: int = 300  # wrong-colour renders (the VAE and the unconditional branch)
    # 800 steps gave bean seed 0 +2.74 dB in 100 steps, 1600 steps +4.21: the longer-trained
    # encoder tells colours apart better (docs/known_answer.md, "What limits the gain").
    vae_steps: int = 1600
    # The plant's pixels weigh 1 + vae_mask_weight in the VAE's loss. Found when the views
    # showed the plant 7.7 times too small (about 1.4% of a view; up to generator version 5):
    # unweighted, the VAE learned the grey background and blurred the plant away.
    vae_mask_weight: float = 20.0
    # Of each VAE batch, wrong-colour renders: trained on true colours only, the encoder
    # needs no colour to encode a view and maps wrong colours near the true latent.
    vae_recoloured_share: float = 0.5
    denoiser_steps: int = 1800
    # UNet channels (ControlNet alike): 48 gives 2.7M parameters together; the shipped
    # tiny width (16, 318k) barely told the view prompt from the negative prompt.
    denoiser_width: int = 48
    batch: int = 16
    uncond_prob: float = 0.2  # the negative prompt, as classifier-free guidance is trained
    recoloured_prob: float = 0.5  # of the unconditional samples
    # Of the conditional samples: a wrong-colour render with the true latent's noise as the
    # target (0 = plain epsilon training).
    corrected_prob: float = 0.0

    def __post_init__(self) -> None:
        if self.resolution <= 0 or self.resolution % 8:
            raise InputError(f"resolution must be a positive multiple of 8, got {self.resolution}")
        counts = (self.points, self.train_views, self.recoloured_views, self.batch)
        if self.denoiser_width <= 0 or self.denoiser_width % 8:
            raise InputError(
                f"denoiser_width must be a positive multiple of 8, got {self.denoiser_width}"
            )
        if min(counts) <= 0 or min(self.vae_steps, self.denoiser_steps) < 0:
            raise InputError("points, views, batch must be positive and steps not negative")
        shares = (self.uncond_prob, self.recoloured_prob, self.corrected_prob,
                  self.vae_recoloured_share)  # fmt: skip
        if self.vae_mask_weight < 0.0:
            raise InputError(f"vae_mask_weight must not be negative, got {self.vae_mask_weight}")
        if not all(0.0 <= p <= 1.0 for p in shares):
            raise InputError("probabilities must be in [0, 1]")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def key(self) -> str:
        """A name for the cache: the spec, the generator version and the library versions
        (a different torch may round differently, so it makes different models)."""
        blob = json.dumps(
            {"spec": self.to_dict(), "generator": GENERATOR_VERSION, **library_versions()},
            sort_keys=True,
        )
        digest = hashlib.sha256(blob.encode()).hexdigest()[:16]
        return f"{self.species}-s{self.seed}-r{self.resolution}-{digest}"


def library_versions() -> dict[str, str | None]:
    from plantdreamer.versions import package_versions

    return package_versions(("torch", "diffusers", "transformers"))
