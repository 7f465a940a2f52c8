"""The known answer's ground truth: a plant's true-colour Gaussians and views of them.

The plant is what ``generate --guidance none --steps 0`` makes (the same geometry a noise-
coloured run starts from, with the true colours). Cameras come from the pipeline's own
sampler (on seed streams of their own), depth conditioning from its depth cleaning, prompts
from its view-prompt function, so the models learn exactly what SDS will show them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from plantdreamer.cameras import Camera, stack
from plantdreamer.errors import InputError
from plantdreamer.eval.frames import Frame
from plantdreamer.gaussians import Gaussians
from plantdreamer.known_answer.spec import KnownAnswerSpec
from plantdreamer.pipeline.settings.config import GenerateConfig

# Offsets of the camera streams: training views, held-out views (generate uses ``seed``).
TRAIN_STREAM = 1_000_000
HELD_OUT_STREAM = 2_000_000
GATE_STREAM = 3_000_000  # unseen views the CFG-direction gate measures on
HELD_OUT_VIEWS = 16


def generate_config(spec: KnownAnswerSpec, **settings: object) -> GenerateConfig:
    """The ``generate`` config of this plant at this size; ``settings`` (by name) override."""
    values: dict[str, object] = {
        "species": spec.species,
        "seed": spec.seed,
        "points": spec.points,
        "resolution": spec.resolution,
        "sds_resolution": spec.resolution,
        "eval_views": 0,
        "turntable": "none",
        "device": "cpu",
        **settings,
    }
    return GenerateConfig.of(**values)


def true_gaussians(spec: KnownAnswerSpec, work_dir: Path) -> Gaussians:
    """The plant with its true colours, made by ``generate`` without guidance, in the frame
    generate trains in (its scene frame: centred, longest side ``scene_size``), where the
    training cameras see it as SDS will. (Generator versions up to 5 rendered the exported
    plant, in the L-System's own units, 7.7 times smaller for bean seed 0: the models
    learned a plant covering about 1.4% of a view that generate shows at 20-50%.)"""
    from plantdreamer.io import read_splat_ply
    from plantdreamer.pipeline import generate_plants

    cfg = generate_config(spec, guidance="none", steps=0, color_init="original")
    result = generate_plants([cfg], work_dir / "target", overwrite=True, show_progress=False)[0]
    return in_generate_frame(read_splat_ply(result.ply_path), Path(result.ply_path))


def in_generate_frame(gaussians: Gaussians, ply: Path) -> Gaussians:
    """The Gaussians of a ``plant.ply`` written by ``generate`` moved back into the scene
    frame it trained in (``GenerateFrame``: what its ``run.json`` records)."""
    from plantdreamer.pipeline.rerender import GenerateFrame

    frame = GenerateFrame.beside(ply)
    if frame is None:
        raise InputError(f"{ply} has no run.json beside it: not a generate output")
    return frame.to_scene(gaussians)


def sample_cameras(spec: KnownAnswerSpec, n: int, stream: int) -> list[Camera]:
    from plantdreamer.pipeline.model.sampler import CameraSampler
    from plantdreamer.pipeline.settings.train_config import CameraRanges

    sampler = CameraSampler(CameraRanges(), spec.resolution, spec.seed + stream)
    return [sampler.sample() for _ in range(n)]


def render(
    gaussians: Gaussians, cameras: list[Camera], colors: np.ndarray | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """RGB [C, H, W, 3] over the pipeline's grey, expected depth and alpha [C, H, W, 1]."""
    from plantdreamer.rasterizer import rasterization

    def t(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))

    viewmats, ks = stack(cameras)
    sh = gaussians.sh if colors is None else colors[:, None, :]
    grey = GenerateConfig().train.background
    with torch.no_grad():
        out, alpha, _ = rasterization(
            t(gaussians.means),
            t(gaussians.quats),
            t(gaussians.scales()),
            t(gaussians.opacities()),
            t(sh),
            t(viewmats),
            t(ks),
            cameras[0].width,
            cameras[0].height,
            sh_degree=gaussians.sh_degree if colors is None else 0,
            backgrounds=torch.full((len(cameras), 3), float(grey)),
            render_mode="RGB+ED",
        )
    return out[..., :3].clamp(0.0, 1.0), out[..., 3:], alpha


@dataclass
class ViewSet:
    """Training data: true renders, wrong-colour renders, depth conditioning, prompts."""

    images: torch.Tensor  # [N, 3, R, R] in [0, 1]
    recoloured: torch.Tensor  # [M, 3, R, R]
    recoloured_view: torch.Tensor  # [M] index of the view each recoloured image shows
    depth: torch.Tensor  # [N, 1, R, R] cleaned conditioning in [0, 1]
    prompts: list[str]
    alpha: torch.Tensor  # [N, 1, R, R] the plant's coverage of each pixel


def depth_conditioning(
    depth: torch.Tensor, alpha: torch.Tensor, cameras: list[Camera], size: int
) -> torch.Tensor:
    """The pipeline's depth cleaning with generate's default rule and resize."""
    from plantdreamer.guidance.depth import DepthCleaning, camera_distance, clean_depth

    sds = GenerateConfig().sds
    cleaning = DepthCleaning(rule=sds.depth_rule, resize=sds.control_resize)
    distances = [camera_distance(c) for c in cameras]
    return clean_depth(depth, alpha, distances, size, cleaning)


def recolour(gaussians: Gaussians, rng: np.random.Generator) -> np.ndarray:
    """Wrong SH-DC colours: per-Gaussian noise, one flat colour, or the channels permuted."""
    from plantdreamer.gaussians import rgb_to_sh_dc

    true = gaussians.sh[:, 0, :]
    kind = rng.integers(3)
    if kind == 0:
        rgb = rng.random((len(gaussians), 3))
    elif kind == 1:
        rgb = np.broadcast_to(rng.random(3), (len(gaussians), 3))
    else:
        return np.ascontiguousarray(true[:, rng.permutation(3)], dtype=np.float32)
    return np.ascontiguousarray(rgb_to_sh_dc(rgb), dtype=np.float32)


def flat_colours(level: float) -> Callable[[Gaussians, np.random.Generator], np.ndarray]:
    """A ``recolour`` that paints every Gaussian the grey ``level`` (0 black, 1 white)."""
    from plantdreamer.gaussians import rgb_to_sh_dc

    def paint(gaussians: Gaussians, rng: np.random.Generator) -> np.ndarray:
        return rgb_to_sh_dc(np.full((len(gaussians), 3), level, dtype=np.float32))

    return paint


def training_views(
    spec: KnownAnswerSpec,
    gaussians: Gaussians,
    stream: int = TRAIN_STREAM,
    wrong_colours: Callable[[Gaussians, np.random.Generator], np.ndarray] = recolour,
) -> ViewSet:
    """The spec's training views (another ``stream``: as many views no model saw), with
    wrong-colour renders painted by ``wrong_colours``."""
    from plantdreamer.guidance.prompts import camera_prompt

    template = GenerateConfig().sds.prompt_template or _default_template()
    cameras = sample_cameras(spec, spec.train_views, stream)
    images, depths, alphas = [], [], []
    for chunk in range(0, len(cameras), 32):
        part = cameras[chunk : chunk + 32]
        rgb, depth, alpha = render(gaussians, part)
        images.append(rgb.permute(0, 3, 1, 2))
        alphas.append(alpha.permute(0, 3, 1, 2))
        depths.append(depth_conditioning(depth, alpha, part, spec.resolution))
    rng = np.random.default_rng([spec.seed, 0x2EC0])
    which = rng.integers(len(cameras), size=spec.recoloured_views)
    recoloured = [
        render(gaussians, [cameras[i]], wrong_colours(gaussians, rng))[0].permute(0, 3, 1, 2)
        for i in which
    ]
    return ViewSet(
        images=torch.cat(images),
        recoloured=torch.cat(recoloured),
        recoloured_view=torch.from_numpy(which),
        depth=torch.cat(depths),
        prompts=[camera_prompt(spec.species, c, template) for c in cameras],
        alpha=torch.cat(alphas),
    )


def _default_template() -> str:
    from plantdreamer.guidance.config import DEFAULT_PROMPT_TEMPLATE

    return DEFAULT_PROMPT_TEMPLATE


def held_out_frames(spec: KnownAnswerSpec, gaussians: Gaussians) -> list[Frame]:
    """True views from cameras no model trained on, with the plant's mask (alpha > 0.5),
    saved to 8 bits as a photograph would be."""
    cameras = sample_cameras(spec, HELD_OUT_VIEWS, HELD_OUT_STREAM)
    rgb, _, alpha = render(gaussians, cameras)
    frames = []
    for i, camera in enumerate(cameras):
        image = (torch.round(rgb[i] * 255.0) / 255.0).numpy()
        frames.append(Frame(f"held_out_{i:02d}", camera, image, alpha[i, ..., 0].numpy() > 0.5))
    return frames
