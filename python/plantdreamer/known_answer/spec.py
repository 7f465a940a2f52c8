"""What a known-answer model set is made from: the one place its defaults are written."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from typing import Any

from plantdreamer.errors import InputError

# Bumped whenever the generator's code changes what it makes (it is part of the cache key).
GENERATOR_VERSION = 4


@dataclass(frozen=True)
class KnownAnswerSpec:
    """A plant (species and seed, as ``generate`` makes it) at one render size, and how long
    the tiny VAE and the UNet + depth ControlNet train on its true views."""

    species: str = "bean"
    seed: int = 0
    resolution: int = 64  # training render size and SDS image size (one latent per 8 px)
    points: int = 100_000  # Gaussians the plant starts from (generate's --points)
    train_views: int = 600
    recoloured_views: int = 100  # wrong-colour renders the unconditional branch also sees
    vae_steps: int = 400
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
        if not all(
            0.0 <= p <= 1.0 for p in (self.uncond_prob, self.recoloured_prob, self.corrected_prob)
        ):
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
