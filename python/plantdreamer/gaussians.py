"""``Gaussians``: a 3DGS model in its stored (unactivated) parameterisation.

The fields match the INRIA 3DGS PLY layout one to one, so a file round-trips bit-exactly:
log scales, opacity logits, unnormalised (w, x, y, z) quaternions and SH coefficients.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from plantdreamer.errors import InputError
from plantdreamer.integers import as_int

SH_C0 = 0.28209479177387814


def sh_coeff_count(degree: int) -> int:
    """Number of SH basis functions up to ``degree``: (degree + 1)^2."""
    return (degree + 1) ** 2


def rgb_to_sh_dc(rgb: np.ndarray) -> np.ndarray:
    """The degree-0 coefficient whose colour (0.5 + C0 * dc) is ``rgb``."""
    return ((np.asarray(rgb, dtype=np.float32) - 0.5) / SH_C0).astype(np.float32)


def sh_dc_to_rgb(dc: np.ndarray) -> np.ndarray:
    return (0.5 + SH_C0 * np.asarray(dc, dtype=np.float32)).astype(np.float32)


# The activations, the one definition of how stored parameters become what the rasterizer
# reads (training, ground truth and evaluation renders use these). float32 numpy on one
# thread: a torch op on [N] arrays is an OpenMP region, whose wait for its workers cost
# milliseconds per call on a loaded host (BENCHMARKS.md, "The step's phases on the CPU").


def activate_scales(log_scales: np.ndarray) -> np.ndarray:
    """Standard deviations exp(s) (float32, a new array)."""
    return np.exp(np.asarray(log_scales, dtype=np.float32))


def activate_opacities(logits: np.ndarray) -> np.ndarray:
    """Opacities 1 / (1 + exp(-x)) (float32, a new array)."""
    out = np.negative(np.asarray(logits, dtype=np.float32))
    np.exp(out, out=out)
    out += np.float32(1.0)
    return np.reciprocal(out, out=out)


@dataclass
class Gaussians:
    """N Gaussians. Arrays are float32.

    means: [N, 3] world positions.
    quats: [N, 4] rotations as (w, x, y, z), not necessarily normalised.
    log_scales: [N, 3] natural logs of the per-axis standard deviations.
    opacity_logits: [N] logits of the opacities.
    sh: [N, K, 3] SH coefficients, K = (d + 1)^2; ``sh[:, 0]`` is the PLY's f_dc.
    labels: None, or int32 [N, 2]: each Gaussian's class (``label``) and object id
        (``instance``), -1 where none; inherited from the point it was initialised from.
    """

    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    labels: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.validate()

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return math.isqrt(self.sh.shape[1]) - 1

    def validate(self) -> None:
        """Raises InputError naming the first field whose shape is inconsistent."""
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        expected = {
            "means": (n, 3),
            "quats": (n, 4),
            "log_scales": (n, 3),
            "opacity_logits": (n,),
        }
        for name, shape in expected.items():
            value = getattr(self, name)
            if not isinstance(value, np.ndarray) or value.shape != shape or n < 0:
                got = list(value.shape) if isinstance(value, np.ndarray) else type(value).__name__
                raise InputError(f"{name} must have shape {list(shape)}, got {got}")
        k = self.sh.shape[1] if self.sh.ndim == 3 else -1
        if (
            self.sh.ndim != 3
            or self.sh.shape[0] != n
            or self.sh.shape[2] != 3
            or k
            not in (
                1,
                4,
                9,
                16,
            )
        ):
            raise InputError(
                f"sh must have shape [{n}, (d+1)^2, 3] with d in 0..3, got {list(self.sh.shape)}"
            )
        if self.labels is not None and (
            not isinstance(self.labels, np.ndarray)
            or self.labels.shape != (n, 2)
            or self.labels.dtype != np.int32
        ):
            got = getattr(self.labels, "shape", type(self.labels).__name__)
            raise InputError(f"labels must be an int32 [{n}, 2] array (label, instance), got {got}")

    def scales(self) -> np.ndarray:
        return activate_scales(self.log_scales)

    def opacities(self) -> np.ndarray:
        return activate_opacities(self.opacity_logits)

    def base_colors(self) -> np.ndarray:
        """RGB of the degree-0 term (the colour seen from every direction)."""
        return sh_dc_to_rgb(self.sh[:, 0])

    def with_sh_degree(self, degree: int) -> Gaussians:
        """A copy whose SH has exactly ``degree``: pads with zeros or truncates."""
        degree = as_int("SH degree", degree)
        if not 0 <= degree <= 3:
            raise InputError(f"SH degree must be in 0..3, got {degree}")
        k = sh_coeff_count(degree)
        sh = np.zeros((len(self), k, 3), dtype=np.float32)
        keep = min(k, self.sh.shape[1])
        sh[:, :keep] = self.sh[:, :keep]
        return Gaussians(
            self.means.copy(),
            self.quats.copy(),
            self.log_scales.copy(),
            self.opacity_logits.copy(),
            sh,
            None if self.labels is None else self.labels.copy(),
        )

    def moved(self, means: np.ndarray, log_scale_shift: float) -> Gaussians:
        """These Gaussians under a similarity transform without rotation: at ``means`` (its
        image of their means, computed in float64 and cast here once) and every log-scale
        plus ``log_scale_shift`` (log of the transform's scale, added in float32).
        Orientations, opacities, colours and labels are copied."""
        return Gaussians(
            np.asarray(means, dtype=np.float32),
            self.quats.copy(),
            (self.log_scales + np.float32(log_scale_shift)).astype(np.float32),
            self.opacity_logits.copy(),
            self.sh.copy(),
            None if self.labels is None else self.labels.copy(),
        )

    def subset(self, index: np.ndarray) -> Gaussians:
        return Gaussians(
            self.means[index],
            self.quats[index],
            self.log_scales[index],
            self.opacity_logits[index],
            self.sh[index],
            None if self.labels is None else self.labels[index],
        )
