"""Depth conditioning for the ControlNet: clean the depth of the fixed initial Gaussians.

The paper renders a depth map of the *initial* Gaussians from each training camera (so the
geometry the diffusion model sees never drifts), then cleans it with "mask thresholding,
erosion, and dilation". ``clean_depth`` does, per image, with ``rule="stretch"`` (ours):

1. background removal: keep pixels whose accumulated opacity is above ``alpha_threshold``
   (a render's alpha, not a depth value, says what is background);
2. far-tail removal: drop kept pixels farther than the ``far_quantile`` of the kept depths
   (stray Gaussians behind the plant);
3. normalisation, near = bright: ``n = (far - d) / (far - near)`` in [0, 1], mapped linearly
   onto [f, 1] with the released code's floor ``f = min_intensity * intensity_scale`` (0.175),
   so the farthest plant pixel stays visibly brighter than the black background and no two
   depths share a value;
4. grey erosion then dilation (a morphological opening) with a square kernel chosen from
   the camera distance, which removes the thin halo of half-transparent edge Gaussians;
5. resize to the ControlNet resolution (``out_size`` square, like the RGB render), where
   the map was not made at it: ``DepthConditioner`` renders it at that size by default
   (``depth_size="sds"``), or at the training render's (``"render"``, the released code).

``rule="released"`` is the authors' released processing instead (``released_normalise``):
accumulated depth D (sum of T alpha z) rounded to 2 decimals; ``start`` = the second-smallest
value (the smallest is the background's 0; the next comes from faint edge pixels, so
``start`` is nearly 0); ``n = 1 - max(D - start, 0) / (D_max - start)``, which is close to
``1 - D / D_max``; pixels with ``n >= 0.97`` are dropped (the background, and faint pixels:
D is alpha times depth, so with depths near 4 this drops alpha below about 4%); then
``min((n + 0.1) * 1.75, 1)``, dropping values <= 0.175 (the farthest pixel); erosion only.
A plant spans a small part of D_max, so its values fill a narrow band, and the lift still
saturates part of it. ``rule="stretch-lift"`` is this project's earlier rule: step 3
as ``min((n + 0.1) * 1.75, 1)`` on the stretched n, which sets the nearest ~half of the depth
range to 1.0 (docs/fidelity.md measures all three).

Other differences from the released code, on purpose: the kernel is chosen from the real
camera distance by default (the released code takes the norm of the 4x4 camera-to-world
matrix, which is sqrt(4 + r^2), not r; ``distance="c2w-norm"`` does the same); the background is found from alpha, not from depth values; and
every threshold is a field of ``DepthCleaning``. Kernel sizes are specified in pixels of a
``kernel_reference_size`` render (768, the released resolution) and scaled to the actual
render size. ``resize="nearest"`` resizes as the released code's control-image preparation
does (bilinear with antialiasing otherwise).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from plantdreamer.atomic import write_image
from plantdreamer.cameras import Camera
from plantdreamer.errors import InputError
from plantdreamer.guidance.config import (
    DEPTH_RULES,
    DEPTH_SIZES,
    EROSION_DISTANCES,
    RESIZE_MODES,
    SDS_DEFAULTS,
)


@dataclass(frozen=True)
class DepthCleaning:
    """Parameters of ``clean_depth``; defaults follow the released code where it is sound."""

    alpha_threshold: float = 0.5
    far_quantile: float = 0.99
    min_intensity: float = 0.1
    intensity_scale: float = 1.75
    # (max camera distance, kernel px) pairs, tried in order; beyond all of them: far_kernel.
    kernel_by_distance: tuple[tuple[float, int], ...] = ((2.0, 3), (5.0, 5))
    far_kernel: int = 7
    # "camera": the thresholds above apply to the camera distance r; "c2w-norm": to the
    # Frobenius norm of the 4x4 camera-to-world matrix, sqrt(r^2 + 4), as the released code
    # does (its radius argument, geometry/depth_utils.py:17-22): 5 px below r = sqrt(21).
    distance: str = "camera"
    kernel_reference_size: int = 768
    erode: bool = True
    dilate: bool = True
    # True if ``depth`` is accumulated depth (sum of T alpha z) rather than expected depth.
    accumulated: bool = False
    rule: str = "stretch"  # "stretch", "released" or "stretch-lift" (module docstring)
    background_cutoff: float = 0.97  # released rule: drop n >= this
    round_decimals: int = 2  # released rule: depth rounding before finding ``start``
    resize: str = "bilinear"  # or "nearest"

    def __post_init__(self) -> None:
        if self.rule not in DEPTH_RULES:
            raise InputError(f"depth rule must be one of {', '.join(DEPTH_RULES)}")
        if self.distance not in EROSION_DISTANCES:
            raise InputError(f"erosion distance must be camera or c2w-norm, got {self.distance!r}")
        if self.resize not in RESIZE_MODES:
            raise InputError(f"depth resize must be bilinear or nearest, got {self.resize!r}")
        if not 0.0 <= self.alpha_threshold < 1.0:
            raise InputError(f"alpha_threshold must be in [0, 1), got {self.alpha_threshold}")
        if not 0.0 < self.far_quantile <= 1.0:
            raise InputError(f"far_quantile must be in (0, 1], got {self.far_quantile}")
        if self.intensity_scale <= 0.0 or self.min_intensity < 0.0:
            raise InputError("intensity_scale must be > 0 and min_intensity >= 0")
        if self.kernel_reference_size <= 0:
            raise InputError("kernel_reference_size must be positive")
        sizes = [k for _, k in self.kernel_by_distance] + [self.far_kernel]
        if any(k < 1 for k in sizes):
            raise InputError(f"kernel sizes must be >= 1 px, got {sizes}")


def kernel_size(camera_distance: float, image_size: int, config: DepthCleaning) -> int:
    """Odd square kernel (pixels of an ``image_size`` render) for a camera at this distance."""
    if not np.isfinite(camera_distance) or camera_distance <= 0.0:
        raise InputError(f"camera distance must be positive and finite, got {camera_distance}")
    if config.distance == "c2w-norm":  # ||[R t; 0 1]||_F with orthonormal R
        camera_distance = math.sqrt(camera_distance**2 + 4.0)
    k_ref = config.far_kernel
    for max_distance, size in config.kernel_by_distance:
        if camera_distance < max_distance:
            k_ref = size
            break
    scaled = k_ref * image_size / config.kernel_reference_size
    return max(1, 2 * round((scaled - 1) / 2) + 1)


def erode(image: torch.Tensor, k: int) -> torch.Tensor:
    """Grey erosion (min filter) of [B, 1, H, W]; the image border is not treated as dark."""
    if k <= 1:
        return image
    return window_extreme(image, k, torch.minimum, float("inf"))


def dilate(image: torch.Tensor, k: int) -> torch.Tensor:
    """Grey dilation (max filter) of [B, 1, H, W]."""
    if k <= 1:
        return image
    return max_filter(image, k)


def max_filter(image: torch.Tensor, k: int) -> torch.Tensor:
    """k x k maximum of [B, C, H, W] centred on each pixel (odd k; outside the image does not
    count): ``F.max_pool2d(image, k, stride=1, padding=k // 2)``, the same values, computed
    as a row pass and a column pass of elementwise maxima. On a 768^2 single-channel map
    with k = 5 that pooling took 31 ms on one core (it is parallel over B x C only) and these
    passes 2 ms, side by side (tests/test_guidance_depth.py compares them)."""
    return window_extreme(image, k, torch.maximum, float("-inf"))


def window_extreme(
    image: torch.Tensor, k: int, pick: Callable[..., torch.Tensor], outside: float
) -> torch.Tensor:
    """The k x k window's ``pick`` (``torch.maximum`` or ``torch.minimum``) of [B, C, H, W],
    ``outside`` beyond the image: a row pass and a column pass, each folding k shifted views
    into one buffer in place (no image allocated per shift). Erosion as a minimum gives the
    bits of the negated maximum of the negated map on the maps ``clean_depth`` makes (finite,
    +0 or positive), without its two negations (tests/test_guidance_depth.py)."""
    r = k // 2
    height, width = image.shape[-2:]
    rows = F.pad(image, (r, r, 0, 0), value=outside)
    out = rows[..., :, 0:width].clone(memory_format=torch.contiguous_format)
    for i in range(1, k):
        pick(out, rows[..., :, i : i + width], out=out)
    cols = F.pad(out, (0, 0, r, r), value=outside)
    out = cols[..., 0:height, :].clone(memory_format=torch.contiguous_format)
    for i in range(1, k):
        pick(out, cols[..., i : i + height, :], out=out)
    return out


def quantile(values: torch.Tensor, q: float) -> torch.Tensor:
    """``torch.quantile(values, q)`` (linear interpolation) of a 1-D float64 tensor without
    NaN, the same bits, from the two order statistics around the rank (a selection, O(n))
    rather than a full sort: on a 768^2 depth map torch's sort made it the costliest call of
    the depth worker, which shares the cores and the GIL with the training step."""
    n = values.numel()
    rank = q * (n - 1)  # torch: a float64 tensor q times the last index, rounded the same
    below = int(rank)
    above = min(below + 1, n - 1) if rank > below else below
    picked = np.partition(values.detach().cpu().numpy(), [below, above])
    lo, hi, weight = (
        torch.tensor(v, dtype=torch.float64, device=values.device)
        for v in (picked[below], picked[above], rank - below)
    )
    return torch.lerp(lo, hi, weight)


def normalise_depth(
    depth: torch.Tensor, alpha: torch.Tensor, config: DepthCleaning
) -> torch.Tensor:
    """Steps 1-3 for one [H, W] map: near = bright in (0, 1], removed pixels 0."""
    if config.rule == "released":
        accumulated = depth if config.accumulated else depth * alpha
        return released_normalise(accumulated, config)
    if config.accumulated:
        depth = depth / alpha.clamp_min(1e-6)
    # Computed in numpy on the plant's pixels alone (a fraction of the image; the rest is
    # 0), gathered once by one boolean mask: the plain whole-map formulation's operations
    # on those pixels (float64, rounded to the map's dtype at the same place, scalars in
    # it), so the same bits (tests/test_guidance_depth.py) in a few passes over the image.
    # d > 0 and d < inf is isfinite(d) & (d > 0) (NaN fails both) in two comparisons.
    d = depth.detach().cpu().numpy()
    a = alpha.detach().cpu().numpy()
    inside = np.flatnonzero((a > config.alpha_threshold) & (d > 0) & (d < np.inf))
    out = np.zeros(d.shape, dtype=d.dtype)  # C order: its flat view is written below
    like = d.dtype.type  # the map's float type: float32 from clean_depth
    if inside.size == 0:
        return torch.from_numpy(out).to(depth.device)
    gathered = d.reshape(-1)[inside]
    values = gathered.astype(np.float64)
    near = values.min()
    if config.far_quantile < 1.0:
        far = float(quantile(torch.from_numpy(values), config.far_quantile))
    else:
        far = float(values.max())
    keep = gathered <= like(far)
    span = far - near
    if span <= 1e-12:  # flat plant, e.g. a single Gaussian: all nearest
        n = np.ones(int(keep.sum()), dtype=d.dtype)
    else:
        n = np.clip((far - values[keep]) / span, 0.0, 1.0).astype(d.dtype)
    if config.rule == "stretch-lift":
        mapped = np.minimum((n + like(config.min_intensity)) * like(config.intensity_scale), 1)
    else:
        floor = config.min_intensity * config.intensity_scale
        mapped = like(1.0 - floor) * n + like(floor)
    out.reshape(-1)[inside[keep]] = mapped
    return torch.from_numpy(out).to(depth.device)


def released_normalise(accumulated: torch.Tensor, config: DepthCleaning) -> torch.Tensor:
    """The authors' released normalisation of one [H, W] accumulated-depth map (module
    docstring); 0 where dropped. Computed in float64 like their numpy code."""
    d = accumulated.double()
    d = torch.where(torch.isfinite(d), d, torch.zeros_like(d))
    d = torch.round(d, decimals=config.round_decimals)
    unique = torch.unique(d)
    if unique.numel() < 2:  # nothing but background
        return torch.zeros_like(accumulated)
    start, end = unique[1], unique[-1]
    span = end - start
    if float(span) <= 0.0:  # one depth value besides the background
        n = torch.where(d >= start, torch.zeros_like(d), torch.ones_like(d))
    else:
        n = 1.0 - (d - start).clamp_min(0.0) / span
    n = torch.where(n < config.background_cutoff, n, torch.zeros_like(n))
    lifted = ((n + config.min_intensity) * config.intensity_scale).clamp(max=1.0)
    floor = config.min_intensity * config.intensity_scale
    out = torch.where(lifted > floor, lifted, torch.zeros_like(lifted))
    return out.to(accumulated.dtype)


def _distances(camera_distance: float | torch.Tensor | Sequence[float], batch: int) -> list[float]:
    """One distance per depth map: a single number (a float or a 0-dim tensor) is every
    map's; a sequence (or a 1-dim tensor) gives each map its own."""
    if isinstance(camera_distance, (int, float)):
        return [float(camera_distance)] * batch
    if isinstance(camera_distance, torch.Tensor) and camera_distance.dim() == 0:
        return [float(camera_distance)] * batch
    if isinstance(camera_distance, torch.Tensor):
        values = camera_distance.detach().reshape(-1).tolist()
    else:
        values = [float(v) for v in camera_distance]
    if len(values) != batch:
        raise InputError(f"got {len(values)} camera distances for {batch} depth maps")
    return values


def clean_depth(
    depth: torch.Tensor,
    alpha: torch.Tensor,
    camera_distance: float | torch.Tensor | Sequence[float],
    out_size: int = 512,
    config: DepthCleaning | None = None,
    **overrides: object,
) -> torch.Tensor:
    """ControlNet conditioning [B, 1, out_size, out_size] in [0, 1] from rendered depth.

    ``depth`` and ``alpha`` are [B, H, W, 1] (or [H, W, 1]); ``camera_distance`` is one value or
    one per image. Keyword ``overrides`` replace fields of ``config`` (see ``DepthCleaning``).
    A view where nothing is opaque gives an all-zero map.
    """
    cfg = replace(config or DepthCleaning(), **overrides)  # type: ignore[arg-type]
    if depth.dim() == 3:
        depth, alpha = depth[None], alpha[None]
    if depth.dim() != 4 or depth.shape[-1] != 1 or alpha.shape != depth.shape:
        raise InputError(
            f"depth and alpha must both be [B, H, W, 1], got {list(depth.shape)} and {list(alpha.shape)}"
        )
    if out_size <= 0:
        raise InputError(f"out_size must be positive, got {out_size}")
    batch, height, width = depth.shape[:3]
    distances = _distances(camera_distance, batch)
    with torch.no_grad():
        depth = depth.detach().float()
        alpha = alpha.detach().float()
        maps = []
        for b in range(batch):
            image = normalise_depth(depth[b, ..., 0], alpha[b, ..., 0], cfg)[None, None]
            k = kernel_size(distances[b], min(height, width), cfg)
            if cfg.erode:
                image = erode(image, k)
            if cfg.dilate and cfg.rule != "released":  # the released code only erodes
                image = dilate(image, k)
            maps.append(image)
        out = torch.cat(maps)
        if (height, width) != (out_size, out_size):
            out = resize_control(out, out_size, cfg.resize)
        return out.clamp(0.0, 1.0)


def resize_control(image: torch.Tensor, size: int, mode: str = "bilinear") -> torch.Tensor:
    """[B, C, h, w] -> [B, C, size, size]: bilinear (antialiased when shrinking) or nearest."""
    if mode == "nearest":
        return F.interpolate(image, (size, size), mode="nearest")
    antialias = image.shape[-2] > size or image.shape[-1] > size
    return F.interpolate(
        image, (size, size), mode="bilinear", align_corners=False, antialias=antialias
    )


def camera_distance(camera: Camera) -> float:
    """The orbit distance if known, else the distance of the camera centre from the origin."""
    if camera.distance is not None:
        return float(camera.distance)
    return float(np.linalg.norm(camera.position))


class DepthConditioner:
    """Cleaned depth conditioning per camera, rendered once per pose.

    ``render_depth(camera) -> (depth, alpha)`` renders the fixed initial Gaussians
    ([H, W, 1] or [1, H, W, 1] each) from the camera it is given: with ``depth_size="sds"``
    the training camera resized to ``out_size`` (the map is rendered and cleaned at the size
    the ControlNet reads), with ``"render"`` the training camera itself (then resized to
    ``out_size``). Results are kept in an LRU cache keyed by the training camera's matrices
    and size, so evaluation orbits and repeated poses are not re-rendered.
    """

    def __init__(
        self,
        render_depth: Callable[[Camera], tuple[torch.Tensor, torch.Tensor]],
        cache_size: int = 256,
        out_size: int = 512,
        config: DepthCleaning | None = None,
        depth_size: str = SDS_DEFAULTS.depth_size,
        **overrides: object,
    ):
        if cache_size < 0:
            raise InputError(f"cache_size must be >= 0, got {cache_size}")
        if depth_size not in DEPTH_SIZES:
            raise InputError(f"depth size must be one of {DEPTH_SIZES}, got {depth_size!r}")
        self.depth_size = depth_size
        self.render_depth = render_depth
        self.cache_size = cache_size
        self.out_size = out_size
        self.config = replace(config or DepthCleaning(), **overrides)  # type: ignore[arg-type]
        self._cache: OrderedDict[tuple[bytes, bytes, int, int], torch.Tensor] = OrderedDict()
        self.hits = 0
        self.misses = 0

    @staticmethod
    def key(camera: Camera) -> tuple[bytes, bytes, int, int]:
        return (
            np.ascontiguousarray(camera.viewmat, dtype=np.float64).tobytes(),
            np.ascontiguousarray(camera.K, dtype=np.float64).tobytes(),
            camera.width,
            camera.height,
        )

    def condition(self, camera: Camera) -> torch.Tensor:
        """[1, 1, out_size, out_size] conditioning for one camera."""
        key = self.key(camera)
        cached = self._cache.get(key)
        if cached is not None:
            self.hits += 1
            self._cache.move_to_end(key)
            return cached
        self.misses += 1
        seen_by = camera
        if self.depth_size == "sds":
            seen_by = camera.resized(self.out_size, self.out_size)
        with torch.no_grad():
            depth, alpha = self.render_depth(seen_by)
        cond = clean_depth(depth, alpha, camera_distance(camera), self.out_size, self.config)
        if self.cache_size > 0:
            self._cache[key] = cond
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
        return cond

    def __call__(self, cameras: Sequence[Camera]) -> torch.Tensor:
        """[B, 1, out_size, out_size] conditioning for a batch of cameras."""
        if not cameras:
            raise InputError("no cameras given")
        return torch.cat([self.condition(c) for c in cameras])

    def clear(self) -> None:
        self._cache.clear()


def save_depth_png(cond: torch.Tensor, path: str | Path) -> Path:
    """Write a [1, h, w] or [1, 1, h, w] conditioning map as an 8-bit greyscale PNG."""
    from PIL import Image

    image = cond.detach().float().reshape(cond.shape[-2], cond.shape[-1]).clamp(0, 1)
    array = (image.cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, Image.fromarray(array))
    return path
