"""Every setting of a generation run, with the paper's and released code's defaults.

These dataclasses are the one place a default is written: ``plantdreamer generate`` builds
one option per field made with ``setting(...)`` (default, choices and help read from here),
``run.json`` and each checkpoint store ``to_dict()``, and ``--resume`` rebuilds the config
with ``from_dict`` so it continues with exactly the settings it started with.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from typing import Any

from plantdreamer.errors import InputError
from plantdreamer.guidance.config import (
    DEPTH_RULES,
    EROSION_DISTANCES,
    RESIZE_MODES,
    SCHEDULES,
    SDS_DEFAULTS,
    VAE_DTYPES,
)
from plantdreamer.settings import check_choices, check_types, option_prefix, setting
from plantdreamer.turntable import TURNTABLE_FORMATS, TURNTABLE_FRAMES

COLOR_INITS = ("original", "noise", "black", "white")
INIT_SHAPES = ("surface", "sphere")
MAX_RESOLUTION = 8192  # largest training / evaluation render side
GUIDANCES = ("sds", "none")
# Where ours, the paper and the authors' released code differ (docs/fidelity.md);
# pipeline/presets.py holds each preset's values.
PRESET_NAMES = ("plantdreamer", "released", "paper")
STRUCTURES = ("plantdreamer", "released")  # species grammars: ours or the authors'
ELEVATION_SAMPLINGS = ("uniform", "mixed", "mixed-full")


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
class DensifyConfig:
    """3DGS adaptive density control in the released code's window: every ``every`` steps
    strictly between ``start`` and ``until``, clone or split Gaussians whose mean 2D-mean
    gradient (NDC units) is at least ``grad_threshold``, then prune transparent ones."""

    start: int = 300
    until: int = 900
    every: int = 100
    grad_threshold: float = 2e-4
    split_scale: float = 0.04  # larger Gaussians are split, smaller cloned (1% of the scene)
    prune_opacity: float = 0.05
    max_gaussians: int = 500_000
    cap_rule: str = setting(
        "strongest",
        "At the cap: densify the strongest gradients, or all then prune at random (released).",
        choices=("strongest", "random"),
    )
    split_std: float = setting(1.0, "Split samples' std as a fraction of the scale.")
    prune_screen_px: float | None = setting(
        None,
        "Also prune Gaussians whose screen radius exceeded this many pixels since the last "
        "round, before densifying (released: 1000).",
    )

    def due(self, step: int) -> bool:
        return self.start < step < self.until and step % self.every == 0


@dataclass
class CullConfig:
    """Large-Gaussian culling (paper Sec. 3.3, on log-scales): every ``every`` steps after
    ``after``, remove Gaussians with V = ||exp(s)|| > mean + ``threshold`` std."""

    threshold: float = setting(3.0, "C in V > mean + C std.")
    every: int = 100
    after: int = 500
    volume: str = setting(
        "log",
        "V on log-scales (paper), or double-exp: exp of activated scales (released).",
        choices=("log", "double-exp"),
    )
    offset: int = setting(
        0, "Cull when step + offset is a multiple of every (released: 1, steps 599 ... 3599)."
    )

    def due(self, step: int) -> bool:
        return step > self.after and (step + self.offset) % self.every == 0


@dataclass
class GenerateConfig:
    preset: str = setting(
        "plantdreamer",
        "Base settings: ours, the authors' released code or the paper's stated values "
        "(docs/fidelity.md); options given override them.",
        choices=PRESET_NAMES,
    )

    # Input: a point cloud (PLY), or else the species' L-System. With a point cloud, species
    # only names the plant in the prompts.
    species: str | None = setting(
        None,
        "L-System species to generate (see `plantdreamer lsystem --list`); with "
        "--pointcloud, the plant named in the prompts.",
    )
    structures: str = setting(
        "plantdreamer",
        "Which grammar a species name grows: ours, or the authors' released structure "
        "(bean -> bean-released).",
        choices=STRUCTURES,
    )
    pointcloud: str | None = setting(None, "A real plant point cloud (PLY).")
    seed: int = setting(0, "Seed of the plant, cameras and noise.")
    n_points: int = setting(100_000, "Points to start from.", option="--points")
    sor_neighbors: int = 20
    sor_std: float = 3.0
    scene_size: float = 4.0  # longest side of the normalised scene
    sor_after_voxel: bool = setting(False, "Capture prep: outlier removal after the voxel grid.")
    downsample_tolerance: float = setting(
        0.05,
        "Capture prep: voxel downsampling aims at --points +- this fraction; clouds below "
        "(1 + this) x --points are kept whole (released: 0.25).",
    )
    mesh_sor: bool = setting(False, "Outlier removal on L-System mesh samples too.")
    label_field: str | None = setting(
        None,
        "Point-cloud property with class ids.",
        default_text="label, class, scalar_Classification, semantic, ... if present",
    )
    instance_field: str | None = setting(
        None,
        "Point-cloud property with instance ids.",
        default_text="instance, instance_id, leaf_id, ... if present",
    )

    # Initialisation.
    sh_degree: int = setting(0, "SH degree optimised.", range=(0, 3))
    color_init: str = setting("original", "Colours of the initial Gaussians.", choices=COLOR_INITS)
    opacity_init: float | None = None  # None: 0.7 for L-System meshes, 0.1 for point clouds
    init_scale: str = setting(
        "mean", "Initial scale from the 3 nearest neighbours' distances.", choices=("mean", "rms")
    )
    init_shape: str = setting(
        "surface",
        "Initial Gaussians on an L-System mesh: flat discs in the surface, or spheres "
        "(released); point clouds always get spheres.",
        choices=INIT_SHAPES,
    )

    # Optimisation.
    steps: int = setting(3600, "Optimisation steps.")
    resolution: int | None = setting(
        None, "Training render size.", default_text="512 on CPU, 768 on GPU"
    )
    background: float = setting(0.75, "Grey level of the background renders are made on.")
    lr: LearningRates = field(default_factory=LearningRates)
    cameras: CameraRanges = field(default_factory=CameraRanges)
    elevation_sampling: str = setting(
        "uniform",
        "Training camera elevation: uniform in degrees, or threestudio's 50/50 mix with "
        "area-uniform: mixed-full (threestudio since 2023-11, released) or mixed (before).",
        choices=ELEVATION_SAMPLINGS,
    )
    densify: DensifyConfig = field(default_factory=DensifyConfig, metadata=option_prefix("densify"))
    cull: CullConfig = field(default_factory=CullConfig, metadata=option_prefix("cull"))

    # Guidance (SDS defaults: guidance/config.py).
    guidance: str = setting("sds", "Guidance: SDS, or none (no optimisation).", choices=GUIDANCES)
    base_model: str = setting(SDS_DEFAULTS.base_model, "Base model: a hub id or a local folder.")
    controlnet: str = setting(
        SDS_DEFAULTS.controlnet, "Depth ControlNet: a hub id or a local folder."
    )
    lora: str | None = setting(
        SDS_DEFAULTS.lora, "Species LoRA: a folder or .safetensors file (diffusers format)."
    )
    guidance_scale: float = setting(SDS_DEFAULTS.guidance_scale, "Classifier-free guidance scale.")
    conditioning_scale: float = SDS_DEFAULTS.conditioning_scale
    schedule: str = setting(
        SDS_DEFAULTS.schedule,
        f"Timestep schedule: {' or '.join(SCHEDULES)}, or a table like '0.2-0.98@600,0.075-0.15'.",
    )
    sds_resolution: int = setting(SDS_DEFAULTS.resolution, "Image size given to the VAE.")
    prompt_template: str | None = setting(
        None,
        "Prompt with a {species} field.",
        default_text=f"the LoRA's lora.json, else '{SDS_DEFAULTS.prompt_template}'",
    )
    negative_prompt: str = setting(
        SDS_DEFAULTS.negative_prompt,
        "The unconditional CFG prompt.",
        default_text="the authors'",
    )
    depth_rule: str = setting("stretch", "Depth-map normalisation.", choices=DEPTH_RULES)
    erosion_distance: str = setting(
        "camera",
        "Depth erosion kernel chosen from the camera distance r, or from the camera-to-world "
        "matrix's norm sqrt(r^2 + 4) (released: 5 px below r = 4.58, never 3 px).",
        choices=EROSION_DISTANCES,
    )
    control_resize: str = setting(
        SDS_DEFAULTS.control_resize, "Resizing of the depth control image.", choices=RESIZE_MODES
    )
    network_dtype: str = setting(
        "auto",
        "UNet and ControlNet precision (auto: float16 on CUDA).",
        choices=("auto", "float32", "float16"),
    )
    vae_dtype: str = setting(
        SDS_DEFAULTS.vae_dtype,
        "VAE precision (its backward pass makes the render gradients).",
        choices=VAE_DTYPES,
    )
    device: str | None = setting(
        None, "Where the networks run: cpu, cuda or cuda:N (default: CUDA when usable, else CPU)."
    )

    # Outputs.
    eval_views: int = setting(120, "Renders on the evaluation orbit.")
    eval_distance: float = 4.0
    eval_elevation_deg: float = 15.0
    eval_fovy_deg: float = 70.0
    turntable_frames: int = TURNTABLE_FRAMES
    turntable: str = setting(
        "gif",
        "Turntable of the evaluation orbit: turntable.gif, turntable.mp4, both or none.",
        choices=TURNTABLE_FORMATS,
    )
    sh_degree_export: int | None = setting(
        3,
        "SH degree of plant.ply, zero-padded or cut (3: what INRIA's loader and strict "
        "viewers accept).",
        range=(0, 3),
    )
    labels: bool = setting(
        True, "Write label/instance into plant.ply and the class and instance masks."
    )
    checkpoint_every: int = setting(500, "Steps between checkpoints.")

    def validate(self) -> None:
        try:
            check_types(self)  # a spec or --set can give any TOML value
            check_choices(self)
        except ValueError as exc:
            raise InputError(str(exc)) from None
        self._check_numbers()
        if self.species is None and self.pointcloud is None:
            raise InputError("give an input: a species (L-System) or a point cloud")
        if not 0 <= self.sh_degree <= 3:
            raise InputError(f"SH degree must be in 0..3, got {self.sh_degree}")
        if self.sh_degree_export is not None and not 0 <= self.sh_degree_export <= 3:
            raise InputError(f"export SH degree must be in 0..3, got {self.sh_degree_export}")
        if self.steps < 0 or self.n_points <= 0 or self.eval_views < 0:
            raise InputError("steps, points and views must not be negative")
        if self.checkpoint_every <= 0 or self.densify.every <= 0 or self.cull.every <= 0:
            raise InputError("checkpoint, densify and cull intervals must be positive")
        if not 0.0 < self.downsample_tolerance < 1.0:
            raise InputError(
                f"downsample tolerance must be in (0, 1), got {self.downsample_tolerance}"
            )
        screen = self.densify.prune_screen_px
        if screen is not None and not (math.isfinite(screen) and screen > 0):
            raise InputError(f"screen-size prune must be a positive pixel count, got {screen}")
        if not 0.0 < self.densify.split_std <= 4.0:
            raise InputError(f"split std must be in (0, 4], got {self.densify.split_std}")
        if self.prompt_template is not None:
            from plantdreamer.guidance.prompts import check_template

            check_template(self.prompt_template)

    def _check_numbers(self) -> None:
        """Integers are integers (3.7 points is an error, not 3), numbers are finite and
        in range, counts fit in memory: no run starts on values it would silently garble."""
        from plantdreamer.cloud import check_point_count

        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.type in ("int", "int | None") and value is not None:
                if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                    raise InputError(f"{f.name} must be an integer, got {value!r}")
            if f.type in ("float", "float | None") and value is not None:
                if isinstance(value, bool) or not isinstance(value, numbers.Real):
                    raise InputError(f"{f.name} must be a number, got {value!r}")
                if not math.isfinite(value):
                    raise InputError(f"{f.name} must be finite, got {value}")
        if not 0 <= self.seed < 2**32:
            raise InputError(f"seed must be in 0..{2**32 - 1}, got {self.seed}")
        check_point_count(self.n_points, "points")
        if self.guidance_scale < 0:
            raise InputError(f"guidance scale must be >= 0, got {self.guidance_scale}")
        if not 0.0 <= self.background <= 1.0:
            raise InputError(f"background must be a grey level in [0, 1], got {self.background}")
        for name in ("resolution", "sds_resolution"):
            size = getattr(self, name)
            if size is not None and not 8 <= size <= MAX_RESOLUTION:
                raise InputError(f"{name} must be in 8..{MAX_RESOLUTION}, got {size}")

    def structure(self) -> str | None:
        """The registered species the L-System input grows (``structures`` applied)."""
        from plantdreamer.lsystem.species import structure_for

        return None if self.species is None else structure_for(self.species, self.structures)

    def plant_name(self) -> str:
        """The plant's name in the prompts (``bean`` for ``bean-released``)."""
        from plantdreamer.lsystem.species import plant_name

        return "plant" if self.species is None else plant_name(self.species)

    def initial_opacity(self) -> float:
        if self.opacity_init is not None:
            return self.opacity_init
        return 0.1 if self.pointcloud is not None else 0.7

    def to_dict(self) -> dict[str, Any]:
        """Plain values only (dicts, lists, numbers, strings, None): JSON and checkpoints."""
        return _plain(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GenerateConfig:
        return _build(cls, data)


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _build(cls: Any, data: dict[str, Any]) -> Any:
    """``cls`` from ``to_dict`` output; nested configs recursively, lists back to tuples."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(data) - set(fields)
    if unknown:
        raise InputError(f"unknown config keys: {', '.join(sorted(unknown))}")
    values = {}
    for name, value in data.items():
        default = _default(fields[name])
        if dataclasses.is_dataclass(default) and isinstance(value, dict):
            value = _build(type(default), value)
        elif isinstance(default, tuple) and isinstance(value, list):
            value = tuple(value)
        values[name] = value
    return cls(**values)


def _default(f: dataclasses.Field) -> Any:
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return f.default
