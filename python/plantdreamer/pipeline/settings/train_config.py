"""The training section of a run's settings: steps, render size, learning rates, cameras.

Read by ``trainer.py`` (the loop), ``model.py`` (Adam) and ``sampler.py`` (cameras); kept in
its own torch-free module because the CLI builds its options from it at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from plantdreamer.errors import InputError
from plantdreamer.settings import option_prefix, setting

ELEVATION_SAMPLINGS = ("uniform", "mixed", "mixed-full")
OVERLAP_CHOICES = ("auto", "on", "off")
# A rate of 0 freezes its parameter; beyond 1e6 an Adam step (about the rate) throws
# every Gaussian out of any scene, and beyond float32's 3.4e38 the first step overflows.
LEARNING_RATES = (0.0, 1e6)


@dataclass
class LearningRates:
    """Adam learning rates of the released code (position and SH as in the paper)."""

    means: float = setting(
        5e-5, "Adam learning rate of the Gaussians' positions.", range=LEARNING_RATES
    )
    sh_dc: float = setting(0.0125, "Adam learning rate of the base colour.", range=LEARNING_RATES)
    sh_rest: float = setting(
        0.0125 / 20, "Adam learning rate of the higher SH bands.", range=LEARNING_RATES
    )
    opacity: float = setting(
        0.01, "Adam learning rate of the opacity logits.", range=LEARNING_RATES
    )
    scales: float = setting(0.005, "Adam learning rate of the log-scales.", range=LEARNING_RATES)
    quats: float = setting(0.001, "Adam learning rate of the rotations.", range=LEARNING_RATES)
    eps: float = setting(1e-15, "Adam epsilon.", range=(0.0, 1.0), open=(True, False))


@dataclass
class CameraRanges:
    """Random orbit cameras for training (released code's ranges): (low, high) each."""

    distance: tuple[float, float] = setting((3.0, 6.0), "Training camera distance range.")
    elevation_deg: tuple[float, float] = setting(
        (-10.0, 80.0), "Training camera elevation range (degrees)."
    )
    azimuth_deg: tuple[float, float] = setting(
        (-180.0, 180.0), "Training camera azimuth range (degrees)."
    )
    fovy_deg: tuple[float, float] = setting(
        (40.0, 70.0), "Training camera vertical field of view range (degrees)."
    )

    def validate(self) -> None:
        """Each range is (low, high) with low <= high, and every value in it a camera:
        a positive distance, an elevation within the poles, a field of view in (0, 180)."""
        for name, (low, high) in (
            ("distance", self.distance),
            ("elevation-deg", self.elevation_deg),
            ("azimuth-deg", self.azimuth_deg),
            ("fovy-deg", self.fovy_deg),
        ):
            if low > high:
                raise InputError(
                    f"cameras-{name} is a range LOW HIGH; got {low:g} {high:g} (low > high)"
                )
        if not self.distance[0] > 0:
            raise InputError(f"cameras-distance must be positive, got {self.distance[0]:g}")
        if not -90 <= self.elevation_deg[0] <= self.elevation_deg[1] <= 90:
            raise InputError(
                "cameras-elevation-deg must lie in [-90, 90] degrees, got "
                f"{self.elevation_deg[0]:g} {self.elevation_deg[1]:g}"
            )
        if not 0 < self.fovy_deg[0] <= self.fovy_deg[1] < 180:
            raise InputError(
                "cameras-fovy-deg must lie in (0, 180) degrees, got "
                f"{self.fovy_deg[0]:g} {self.fovy_deg[1]:g}"
            )


# The render size when none is given, by the device the networks run on (render: the CPU).
AUTO_RESOLUTION = {"cpu": 512, "cuda": 768}


@dataclass
class TrainConfig:
    steps: int = setting(3600, "Optimisation steps.")
    resolution: int | None = setting(
        None,
        "Render size of the training and evaluation views.",
        default_text=f"{AUTO_RESOLUTION['cpu']} on CPU, {AUTO_RESOLUTION['cuda']} on GPU",
    )
    background: float = setting(0.75, "Grey level of the background renders are made on.")
    elevation_sampling: str = setting(
        "uniform",
        "Training camera elevation: uniform in degrees, or threestudio's 50/50 mix with "
        "area-uniform: mixed-full (threestudio since 2023-11, released) or mixed (before).",
        choices=ELEVATION_SAMPLINGS,
    )
    checkpoint_every: int = setting(500, "Steps between checkpoints.")
    overlap: str = setting(
        "auto",
        "Plants trained together (--seeds) as two halves in flight: one half renders and "
        "back-propagates on the host while the other's networks run on the GPU. auto: on "
        "for two plants or more with a CUDA guidance, off otherwise (on the CPU nothing "
        "overlaps). The halves draw their SDS noise in turn, so a group's plants differ "
        "with it on and off (docs/scaling.md).",
        choices=OVERLAP_CHOICES,
    )
    torch_threads: int = setting(
        1,
        "torch's CPU threads for the run (the networks on the CPU, the losses): their sums "
        "round by the thread count, so a fixed count gives the same bits on any machine, "
        "whatever its cores (docs/scaling.md). The rasterizer uses every core either way.",
        range=(1, 1024),
    )
    lr: LearningRates = field(default_factory=LearningRates, metadata=option_prefix("lr"))
    cameras: CameraRanges = field(default_factory=CameraRanges, metadata=option_prefix("cameras"))

    @property
    def render_size(self) -> int:
        """``resolution`` once the run decided ``auto`` (``runtime.resolve_runtime``): the
        one place a run reads its render size from."""
        if self.resolution is None:
            raise RuntimeError("the resolution is decided by runtime.resolve_runtime first")
        return self.resolution

    def validate(self) -> None:
        self.cameras.validate()
