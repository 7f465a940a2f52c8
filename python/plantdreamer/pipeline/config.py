"""Every setting of a generation run, with the paper's and released code's defaults.

A run's config is written into ``run.json`` and into each checkpoint, so ``--resume``
continues with exactly the settings it started with.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantdreamer.errors import InputError

COLOR_INITS = ("original", "noise", "black", "white")
GUIDANCES = ("sds", "none")


@dataclass
class LearningRates:
    """Adam learning rates of the released code (position and SH as in the paper)."""

    means: float = 5e-5
    sh_dc: float = 0.0125
    sh_rest: float = 0.0125 / 20
    opacity: float = 0.01
    scales: float = 0.005
    quats: float = 0.001
    eps: float = 1e-15


@dataclass
class CameraRanges:
    """Random orbit cameras for training (released code's ranges)."""

    distance: tuple[float, float] = (3.0, 6.0)
    elevation_deg: tuple[float, float] = (-10.0, 80.0)
    azimuth_deg: tuple[float, float] = (-180.0, 180.0)
    fovy_deg: tuple[float, float] = (40.0, 70.0)


@dataclass
class GenerateConfig:
    # Input: a point cloud (PLY), or else the species' L-System. With a point cloud, species
    # only names the plant in the prompts.
    species: str | None = None
    pointcloud: str | None = None
    seed: int = 0
    n_points: int = 100_000
    sor_neighbors: int = 20
    sor_std: float = 3.0
    scene_size: float = 4.0  # longest side of the normalised scene

    # Initialisation.
    sh_degree: int = 0
    color_init: str = "original"
    opacity_init: float | None = None  # None: 0.7 for L-System meshes, 0.1 for point clouds

    # Optimisation.
    steps: int = 3600
    resolution: int | None = None  # None: 512 on CPU, 768 with a CUDA GPU
    background: float = 0.75
    lr: LearningRates = field(default_factory=LearningRates)
    cameras: CameraRanges = field(default_factory=CameraRanges)

    # Densification and pruning (3DGS rules, released code's window).
    densify_from: int = 300
    densify_until: int = 900
    densify_every: int = 100
    densify_grad_threshold: float = 2e-4
    split_scale_threshold: float = 0.04  # 1% of the scene extent
    prune_opacity: float = 0.05
    max_gaussians: int = 500_000

    # Large-Gaussian culling (paper's formula on log-scales).
    cull_threshold: float = 3.0
    cull_every: int = 100
    cull_after: int = 500

    # Guidance.
    guidance: str = "sds"
    base_model: str = "stabilityai/stable-diffusion-2-1-base"
    controlnet: str = "thibaud/controlnet-sd21-depth-diffusers"
    lora: str | None = None
    guidance_scale: float = 100.0
    conditioning_scale: float = 1.0
    schedule: str = "paper"
    sds_resolution: int = 512  # renders are resized to this before VAE encoding

    # Outputs.
    eval_views: int = 120
    eval_distance: float = 4.0
    eval_elevation_deg: float = 15.0
    eval_fovy_deg: float = 70.0
    turntable_frames: int = 40
    sh_degree_export: int | None = None
    checkpoint_every: int = 500

    def validate(self) -> None:
        if self.species is None and self.pointcloud is None:
            raise InputError("give an input: a species (L-System) or a point cloud")
        if self.color_init not in COLOR_INITS:
            raise InputError(f"color init must be one of {', '.join(COLOR_INITS)}")
        if self.guidance not in GUIDANCES:
            raise InputError(f"guidance must be one of {', '.join(GUIDANCES)}")
        if not 0 <= self.sh_degree <= 3:
            raise InputError(f"SH degree must be in 0..3, got {self.sh_degree}")
        if self.sh_degree_export is not None and not 0 <= self.sh_degree_export <= 3:
            raise InputError(f"export SH degree must be in 0..3, got {self.sh_degree_export}")
        if self.steps < 0 or self.n_points <= 0 or self.eval_views < 0:
            raise InputError("steps, points and views must not be negative")
        if self.checkpoint_every <= 0:
            raise InputError("checkpoint interval must be positive")

    def initial_opacity(self) -> float:
        if self.opacity_init is not None:
            return self.opacity_init
        return 0.1 if self.pointcloud is not None else 0.7

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GenerateConfig:
        data = dict(data)
        lr = LearningRates(**data.pop("lr", {}))
        cams = {k: tuple(v) for k, v in data.pop("cameras", {}).items()}
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise InputError(f"unknown config keys: {', '.join(sorted(unknown))}")
        return cls(lr=lr, cameras=CameraRanges(**cams), **data)

    @classmethod
    def from_json(cls, path: str | Path) -> GenerateConfig:
        return cls.from_dict(json.loads(Path(path).read_text()))
