"""``rasterization``: gsplat-compatible, differentiable 3DGS rendering on the CPU.

The function mirrors ``gsplat.rasterization`` (v1.5, "classic" semantics; see
docs/rasterizer.md) so code can move between them. The work runs in the Rust core
(``plantdreamer._core.rasterize_forward_many`` / ``rasterize_backward_many``); this module
validates inputs and wraps the native pair in one ``torch.autograd.Function``: one scene
(``rasterization``) is the many-scene call of one. A background behind 1 or
3 colour channels is blended by the core (torch's float32 operations in its order, the
same bits as ``color + bg * (1 - alpha)`` through autograd); other backgrounds and the
expected depth are plain torch ops (so their gradients come from autograd).
``rasterization_many`` renders several scenes (a group's plants) in one native call each
way, with the bits of separate calls. Neither schedules anything: ``RasterBatch`` is the
same call in its stages (each scene's argument checks, the native call, each scene's
outputs), so that a caller with a thread pool (the training step) runs the scenes'
Python work on it.

Conventions and choices (documented behaviour):

* Inputs must be float32. CUDA (or other device) tensors are copied to the CPU and the
  outputs are moved back to the device of ``means``; gradients flow back through the copy.
  ``meta["means2d"]`` (the gradient carrier) always lives on the CPU.
* Contiguous float32 CPU inputs reach the core without a copy, and the outputs are the
  core's arrays wrapped without one (docs/rasterizer.md, "The Python call"). Non-contiguous
  inputs are made contiguous (a copy).
* A Gaussian with NaN/Inf in any parameter (colours included), a quaternion of norm
  < 1e-12, opacity < 1/255, centre outside [near_plane, far_plane] or footprint entirely
  off-screen is culled: radii 0, no contribution, zero gradient.
* ``N == 0`` renders the background only; ``C == 0`` returns empty [0, H, W, ch] tensors.
* Gradients are zero where undefined: culled Gaussians, colour channels clamped at 0
  (SH), and opacity/geometry where alpha was clamped at 0.99. ``viewmats``, ``Ks`` are not
  differentiated (their gradients are None).
"""

from __future__ import annotations

import operator
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from plantdreamer import _core
from plantdreamer.errors import InputError, PlantDreamerError

# The core's `RasterOptions::default()`, the one place the rasterizer's defaults are written.
RASTER_DEFAULTS: dict[str, Any] = _core.raster_defaults()
RENDER_MODES = ("RGB", "D", "ED", "RGB+D", "RGB+ED")
RASTERIZE_MODES = ("classic", "antialiased")
GRAD_NAMES = ("means", "quats", "scales", "opacities", "colors", "means2d")


def _numpy(t: torch.Tensor) -> np.ndarray:
    """The tensor's memory as a numpy array: no copy when it is already contiguous."""
    t = t.detach()
    return (t if t.is_contiguous() else t.contiguous()).numpy()


def _upstream(
    v_render: torch.Tensor | None, v_alpha: torch.Tensor | None, render_shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray | None]:
    """The native backward's dL/d(render) (zeros when the render got no gradient) and
    dL/d(alpha) [C, H, W] (None when the alpha got none: the core then adds nothing, or a
    blended background's own gradient, unchanged, as autograd would have passed it)."""
    vr = np.zeros(render_shape, np.float32) if v_render is None else _array(v_render)
    va = None if v_alpha is None else _array(v_alpha.squeeze(-1))
    return vr, va


class _RasterizeManyFunction(torch.autograd.Function):
    """Autograd node of one ``rasterize_forward_many`` call (``rasterization_many``): the
    inputs of scene j are ``inputs[6 j : 6 j + 6]`` (means, quats, scales, opacities,
    colors, means2d), its outputs render and alpha ``2 j`` and ``2 j + 1``. The backward is
    one ``rasterize_backward_many`` call for every scene."""

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any, natives: list[dict[str, Any]], threads: int | None, *inputs: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        ctx.states = [n["state"] for n in natives]
        ctx.threads = threads
        # An output that gets no gradient stays None (``_upstream``).
        ctx.set_materialize_grads(False)
        out: list[torch.Tensor] = []
        for n in natives:
            out += [torch.from_numpy(n["render"]), torch.from_numpy(n["alpha"]).unsqueeze(-1)]
        ctx.shapes = [tuple(t.shape) for t in out]
        return tuple(out)

    @staticmethod
    def backward(ctx: Any, *grads: torch.Tensor | None) -> tuple[Any, ...]:
        need = ctx.needs_input_grad[2:]
        b = len(ctx.states)
        # The groups any scene needs; a scene's unneeded ones are dropped below.
        wanted = [any(need[6 * j + i] for j in range(b)) for i in range(5)]
        upstream = [_upstream(grads[2 * j], grads[2 * j + 1], ctx.shapes[2 * j]) for j in range(b)]
        results = _core.rasterize_backward_many(
            ctx.states,
            [vr for vr, _ in upstream],
            [va for _, va in upstream],
            means=wanted[0],
            quats=wanted[1],
            scales=wanted[2],
            opacities=wanted[3],
            colors=wanted[4],
            threads=ctx.threads,
        )
        out: list[Any] = [None, None]
        for j, g in enumerate(results):
            if isinstance(g, BaseException):
                raise type(g)(f"scene {j}: {g}") from None
            for i, name in enumerate(GRAD_NAMES):
                wants = need[6 * j + i] and g[name] is not None
                out.append(torch.from_numpy(g[name]) if wants else None)
        return tuple(out)


def _array(t: torch.Tensor) -> np.ndarray:
    """A gradient as a contiguous float32 numpy array (no copy when it is one already)."""
    return _numpy(t.to(torch.float32))


def _tensor(name: str, value: Any) -> torch.Tensor:
    if isinstance(value, np.ndarray):
        value = torch.from_numpy(value)
    if not isinstance(value, torch.Tensor):
        raise InputError(f"{name} must be a torch tensor, got {type(value).__name__}")
    if value.dtype != torch.float32:
        raise InputError(f"{name} must be float32, got {value.dtype}")
    return value


def _check_shape(name: str, t: torch.Tensor, shape: tuple[int | None, ...]) -> None:
    ok = t.dim() == len(shape) and all(
        w is None or s == w for s, w in zip(t.shape, shape, strict=False)
    )
    if not ok:
        want = ", ".join("*" if w is None else str(w) for w in shape)
        raise InputError(f"{name} must have shape [{want}], got {list(t.shape)}")


def _integer(name: str, value: Any) -> int:
    """An integer argument as an int; a float (3.7) is an InputError, never truncated.
    Ranges are checked by the native binding (also an InputError)."""
    try:
        return operator.index(value)
    except TypeError:
        raise InputError(f"{name} must be an integer, got {value!r}") from None


def rasterization(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    near_plane: float = RASTER_DEFAULTS["near_plane"],
    far_plane: float = RASTER_DEFAULTS["far_plane"],
    eps2d: float = RASTER_DEFAULTS["eps2d"],
    sh_degree: int | None = None,
    backgrounds: torch.Tensor | None = None,
    render_mode: str = "RGB",
    rasterize_mode: str = "antialiased" if RASTER_DEFAULTS["antialiased"] else "classic",
    tile_size: int = RASTER_DEFAULTS["tile_size"],
    *,
    threads: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor, dict[str, Any]]:
    """Renders N Gaussians into C cameras (gsplat 1.5 ``rasterization``, CPU).

    Args:
        means: [N, 3] centres (world).
        quats: [N, 4] (w, x, y, z), any norm.
        scales: [N, 3] standard deviations (activated).
        opacities: [N] in [0, 1].
        colors: [N, D] colours, or [N, K, 3] SH coefficients when ``sh_degree`` is given
            (0..3, K >= (sh_degree + 1)^2; colour = max(SH(dir) + 0.5, 0)).
        viewmats: [C, 4, 4] world-to-camera (OpenCV axes).
        Ks: [C, 3, 3] intrinsics.
        width: image width in pixels.
        height: image height in pixels.
        sh_degree: the SH degree of ``colors`` (None: plain colours).
        backgrounds: [C, D] colour behind the Gaussians (colour channels only).
        render_mode: "RGB", "D" (sum of T alpha z), "ED" (D / alpha), "RGB+D", "RGB+ED";
            the depth channel comes last.
        rasterize_mode: "classic", or "antialiased" (opacity times the 2D-blur
            compensation sqrt(det Sigma / det(Sigma + eps2d I))).
        tile_size: tile edge in pixels (2..64).
        threads: worker threads for this call (None: the global pool). Not in gsplat.

    Returns:
        render_colors [C, H, W, ch] float32, render_alphas [C, H, W, 1], and ``meta``:
        "radii" [C, N, 2] int32 (footprint half-sizes in pixels, x and y, as gsplat 1.5;
        0 = culled), "means2d" [C, N, 2] projected centres in pixels (a leaf that requires
        grad when any input does: after ``backward`` its ``.grad`` is dL/d(means2d)),
        "depths" [C, N] camera-space z, "n_visible" [C] int64 (Gaussians kept after
        culling), "n_intersections" [C] int64 (tile-Gaussian pairs), "width", "height",
        "tile_size", "n_cameras", "render_mode", "profile" (native seconds per stage),
        "state" (the native pass, opaque: ``_core.group_coverage`` reuses its projection).
    """
    kwargs = dict(
        means=means, quats=quats, scales=scales, opacities=opacities, colors=colors,
        viewmats=viewmats, Ks=Ks, width=width, height=height, near_plane=near_plane,
        far_plane=far_plane, eps2d=eps2d, sh_degree=sh_degree, backgrounds=backgrounds,
        render_mode=render_mode, rasterize_mode=rasterize_mode, tile_size=tile_size,
    )  # fmt: skip
    batch = RasterBatch([kwargs], threads=threads)
    batch.run()
    (result,) = batch.outcomes
    if isinstance(result, Exception):
        raise result
    return result


def rasterization_many(
    calls: Sequence[Mapping[str, Any]], *, threads: int | None = None
) -> list[tuple[torch.Tensor, torch.Tensor, dict[str, Any]] | PlantDreamerError]:
    """``rasterization`` of every call in ``calls`` (each a dict of its keyword arguments;
    the settings, as ``render_mode``, the same in all), as ONE native forward call whose
    scenes run side by side, and later one native backward call for all of them: the
    renders of B plants with one call's overhead.

    Each result has exactly the bits of its own ``rasterization`` call (also its gradients)
    and comes back in its place in the list; a call with bad input comes back as its
    error (not raised), naming it (``scene K: ...``), and the others are rendered. The
    gradients of all the renders must be computed in one ``torch.autograd.backward`` (one
    autograd node holds them all). The scenes' Python work runs one after another on the
    calling thread; ``RasterBatch`` runs the same stages for a caller that spreads it.
    """
    batch = RasterBatch(calls, threads=threads)
    batch.run()
    return batch.results()


class RasterBatch:
    """``rasterization_many`` in its stages, for a caller that schedules the scenes' Python
    work itself: ``prepare(k)`` checks scene k's arguments, ``render()`` makes the one
    native forward call of every scene prepared without error (one autograd node), and
    ``finish(k)`` wraps scene k's outputs; ``results()`` then returns what
    ``rasterization_many`` does, with the same bits.

    ``render`` runs once, on the calling thread, after every scene's ``prepare`` and before
    any ``finish``. ``prepare`` and ``finish`` of different scenes may run on any threads,
    in any order (numpy and torch release the GIL), each in the caller's autograd mode: a
    thread pool's threads do not inherit ``torch.no_grad``.
    """

    def __init__(self, calls: Sequence[Mapping[str, Any]], *, threads: int | None = None):
        self.calls = list(calls)
        self.threads = threads
        # Per scene: its result, or its error as raised (``results`` names the scene).
        self.outcomes: list[Any] = [None] * len(self.calls)
        self._prepared: list[_Call | None] = [None] * len(self.calls)
        # The rendered scenes' places in the node's outputs, natives and means2d.
        self._rendered: dict[int, tuple[int, dict[str, Any], torch.Tensor]] = {}
        self._outputs: tuple[torch.Tensor, ...] | None = None

    def __len__(self) -> int:
        return len(self.calls)

    def prepare(self, k: int) -> None:
        """Checks scene k's arguments and makes its native call's arrays."""
        try:
            self._prepared[k] = _prepare(**self.calls[k])
        except (InputError, TypeError) as exc:
            self.outcomes[k] = exc

    def render(self) -> None:
        """The native forward call of every scene prepared without error, and the one
        autograd node of their renders."""
        pairs = zip(self._prepared, self.outcomes, strict=True)
        if any(p is None and o is None for p, o in pairs):
            raise RuntimeError("RasterBatch.render: every scene must be prepared first")
        prepared = {k: p for k, p in enumerate(self._prepared) if p is not None}
        ok = list(prepared)
        if not ok:
            return
        settings = prepared[ok[0]].settings
        for k in ok[1:]:
            if prepared[k].settings != settings:
                self.outcomes[k] = InputError(
                    f"its settings differ from scene {ok[0]}'s: "
                    f"{prepared[k].settings} against {settings}"
                )
        ok = [k for k in ok if self.outcomes[k] is None]
        if not ok:
            return
        natives = _core.rasterize_forward_many(
            [prepared[k].scene for k in ok], **settings, threads=self.threads
        )
        inputs: list[torch.Tensor] = []
        rendered: list[dict[str, Any]] = []
        for k, native in zip(ok, natives, strict=True):
            if isinstance(native, BaseException):
                # MemoryError stays one (a buffer the data sized could not be allocated).
                kept = isinstance(native, (PlantDreamerError, MemoryError))
                error = native if kept else InputError(str(native))
                self.outcomes[k] = error
                continue
            means2d = prepared[k].means2d(native)
            self._rendered[k] = (len(rendered), native, means2d)
            rendered.append(native)
            inputs += [*prepared[k].params, prepared[k].color_in, means2d]
        if rendered:
            self._outputs = _RasterizeManyFunction.apply(rendered, self.threads, *inputs)

    def finish(self, k: int) -> None:
        """Scene k's render, alpha and ``meta`` (nothing to do for a scene that failed)."""
        if k not in self._rendered:
            return
        assert self._outputs is not None
        j, native, means2d = self._rendered[k]
        call = self._prepared[k]
        assert call is not None
        self.outcomes[k] = call.finish(
            self._outputs[2 * j], self._outputs[2 * j + 1], means2d, native
        )

    def run(self) -> None:
        """Every stage, one scene after another on the calling thread."""
        for k in range(len(self)):
            self.prepare(k)
        self.render()
        for k in range(len(self)):
            self.finish(k)

    def results(
        self,
    ) -> list[tuple[torch.Tensor, torch.Tensor, dict[str, Any]] | PlantDreamerError]:
        """Each scene's (render, alpha, meta), or its error naming it (``scene K: ...``; one
        that ran out of memory as an InputError saying so: a plant of a group fails alone)."""
        named: list[Any] = []
        for k, result in enumerate(self.outcomes):
            if result is None:
                raise RuntimeError(f"RasterBatch.results: scene {k} was not finished")
            if isinstance(result, Exception):
                kind = type(result) if isinstance(result, PlantDreamerError) else InputError
                result = kind(f"scene {k}: {result}")
            named.append(result)
        return named


@dataclass
class _Call:
    """One validated ``rasterization`` call: the native call's arrays (``scene``) and
    settings, the differentiable inputs, and what ``finish`` needs."""

    tensors: dict[str, torch.Tensor]
    device: torch.device
    render_color: bool
    render_depth: bool
    render_mode: str
    bg: torch.Tensor | None
    n_color: int
    n_cameras: int
    width: int
    height: int
    sh_degree: int | None
    settings: dict[str, Any]
    params: list[torch.Tensor] = field(init=False)
    color_in: torch.Tensor = field(init=False)
    scene: dict[str, Any] = field(init=False)

    def __post_init__(self) -> None:
        t = self.tensors
        self.params = [t[k].to("cpu") for k in ("means", "quats", "scales", "opacities")]
        color_in = t["colors"].to("cpu")
        if not self.render_color:
            color_in = color_in.detach()  # colours do not affect depth renders
        self.color_in = color_in
        means_a, quats_a, scales_a, opacities_a = (_numpy(x) for x in self.params)
        self.scene = {
            "means": means_a,
            "quats": quats_a,
            "scales": scales_a,
            "opacities": opacities_a,
            # Not read for depth renders.
            "colors": _numpy(color_in) if self.render_color else None,
            "viewmats": _numpy(t["viewmats"].cpu()),
            "Ks": _numpy(t["Ks"].cpu()),
            "width": self.width,
            "height": self.height,
            "sh_degree": self.sh_degree,
            # Blended by the core when it can give autograd's bits (``plain_background``).
            "background": self.plain_background(),
        }

    def means2d(self, native: dict[str, Any]) -> torch.Tensor:
        """The native array itself (no copy); a leaf, so its .grad is dL/d(means2d)."""
        inputs = [*self.params, self.color_in]
        wants_grad = torch.is_grad_enabled() and any(p.requires_grad for p in inputs)
        return torch.from_numpy(native["means2d"]).requires_grad_(wants_grad)

    def plain_background(self) -> np.ndarray | None:
        """The background as a [C, ch] array where the core blends it (the bits of the torch
        expression): 1 or 3 colour channels, no depth channel, no gradient wanted for it;
        else None (``finish`` blends it with torch ops, or there is none)."""
        bg = self.bg
        if bg is None or self.render_depth or bg.requires_grad or self.n_color not in (1, 3):
            return None
        return bg.contiguous().numpy()

    def finish(
        self, render: torch.Tensor, alpha: torch.Tensor, means2d: torch.Tensor, native: dict
    ) -> tuple[torch.Tensor, torch.Tensor, dict[str, Any]]:
        """The background the core did not blend, expected depth and ``meta`` on the native
        call's render and alpha."""
        bg, n_color = self.bg, self.n_color
        if bg is not None and self.scene["background"] is None:
            # Whole-tensor ops where possible: slicing costs a zero-filled copy in backward.
            color = render[..., :n_color] if self.render_depth else render
            color = color + bg[:, None, None, :] * (1.0 - alpha)
            render = (
                torch.cat([color, render[..., n_color:]], dim=-1) if self.render_depth else color
            )
        if self.render_mode.endswith("ED"):
            depth = render[..., -1:] / alpha.clamp_min(1e-10)
            render = torch.cat([render[..., :-1], depth], dim=-1) if render.shape[-1] > 1 else depth
        device = self.device
        meta: dict[str, Any] = {
            "radii": torch.from_numpy(native["radii"]).to(device),
            "means2d": means2d,
            "depths": torch.from_numpy(native["depths"]).to(device),
            "n_visible": torch.from_numpy(native["n_visible"].astype(np.int64)).to(device),
            "n_intersections": torch.from_numpy(native["n_intersections"].astype(np.int64)).to(
                device
            ),
            "width": self.width,
            "height": self.height,
            "tile_size": self.settings["tile_size"],
            "n_cameras": self.n_cameras,
            "render_mode": self.render_mode,
            "profile": dict(native["profile"]),
            # The native pass itself (its projection and depth order, which a view's leaf
            # occlusion reuses: ``_core.group_coverage``); kept alive by whoever holds it.
            "state": native["state"],
        }
        return render.to(device), alpha.to(device), meta


def _prepare(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    near_plane: float = RASTER_DEFAULTS["near_plane"],
    far_plane: float = RASTER_DEFAULTS["far_plane"],
    eps2d: float = RASTER_DEFAULTS["eps2d"],
    sh_degree: int | None = None,
    backgrounds: torch.Tensor | None = None,
    render_mode: str = "RGB",
    rasterize_mode: str = "antialiased" if RASTER_DEFAULTS["antialiased"] else "classic",
    tile_size: int = RASTER_DEFAULTS["tile_size"],
) -> _Call:
    """The checks of ``rasterization``'s arguments (shapes, dtypes, modes)."""
    if render_mode not in RENDER_MODES:
        raise InputError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
    if rasterize_mode not in RASTERIZE_MODES:
        raise InputError(f"rasterize_mode must be one of {RASTERIZE_MODES}, got {rasterize_mode!r}")
    width, height = _integer("width", width), _integer("height", height)
    tile_size = _integer("tile_size", tile_size)
    if sh_degree is not None:
        sh_degree = _integer("sh_degree", sh_degree)
    if width <= 0 or height <= 0:
        raise InputError(f"image size must be positive, got {width}x{height}")
    tensors = {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": opacities,
        "colors": colors,
        "viewmats": viewmats,
        "Ks": Ks,
    }
    t = {k: _tensor(k, v) for k, v in tensors.items()}
    device = t["means"].device
    n = t["means"].shape[0] if t["means"].dim() == 2 else -1
    _check_shape("means", t["means"], (None, 3))
    _check_shape("quats", t["quats"], (n, 4))
    _check_shape("scales", t["scales"], (n, 3))
    _check_shape("opacities", t["opacities"], (n,))
    if sh_degree is None:
        _check_shape("colors", t["colors"], (n, None))
        n_color = t["colors"].shape[1]
    else:
        if not 0 <= sh_degree <= 3:
            raise InputError(f"sh_degree must be 0..3, got {sh_degree}")
        _check_shape("colors (SH coefficients)", t["colors"], (n, None, 3))
        if t["colors"].shape[1] < (sh_degree + 1) ** 2:
            raise InputError(
                f"sh_degree {sh_degree} needs {(sh_degree + 1) ** 2} coefficients per "
                f"Gaussian, colors has {t['colors'].shape[1]}"
            )
        n_color = 3
    c = t["viewmats"].shape[0] if t["viewmats"].dim() == 3 else -1
    _check_shape("viewmats", t["viewmats"], (None, 4, 4))
    _check_shape("Ks", t["Ks"], (c, 3, 3))
    # Finiteness of viewmats and Ks is checked by the core, which reads them anyway.
    render_color = render_mode in ("RGB", "RGB+D", "RGB+ED")
    render_depth = render_mode != "RGB"
    bg = None
    if backgrounds is not None and render_color:
        bg = _tensor("backgrounds", backgrounds).to("cpu")
        _check_shape("backgrounds", bg, (c, n_color))

    return _Call(
        t,
        device=device,
        render_color=render_color,
        render_depth=render_depth,
        render_mode=render_mode,
        bg=bg,
        n_color=n_color,
        n_cameras=c,
        width=width,
        height=height,
        sh_degree=sh_degree,
        settings={
            "near_plane": float(near_plane),
            "far_plane": float(far_plane),
            "eps2d": float(eps2d),
            "antialiased": rasterize_mode == "antialiased",
            "render_color": render_color,
            "render_depth": render_depth,
            "tile_size": tile_size,
        },
    )
