"""Renders of the model: many plants' scenes as one native call each way, with each plant's
inputs cut from its parameters' graph (``render_many``, ``RenderInputs``), and scenes that
never change rendered from their inputs made once (``FrozenScene``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch

from plantdreamer.cameras import Camera
from plantdreamer.errors import PlantDreamerError
from plantdreamer.pipeline.model.gaussian_model import GaussianModel, camera_args


class FrozenScene:
    """Gaussians that never change, rendered from many cameras: their render inputs
    (activations, colours) are made once, not per render (the depth maps' initial
    Gaussians: the same values, so the same bits as ``GaussianModel.render``)."""

    def __init__(self, model: GaussianModel, render_mode: str = "RGB") -> None:
        with torch.no_grad():
            self.scene = model.scene_args(render_mode)
        self.render_mode = render_mode

    def render(
        self, cameras: Sequence[Camera], background: float
    ) -> tuple[torch.Tensor, torch.Tensor, dict]:
        from plantdreamer.rasterizer import rasterization

        with torch.no_grad():
            return rasterization(**self.scene, **camera_args(cameras, background, self.render_mode))


class RenderInputs:
    """A render's inputs cut from the graph of the model's parameters: the render sees
    detached leaves (``leaves``) in place of the activated scales, opacities and the
    concatenated SH coefficients, and ``backward`` later carries the leaves' gradients
    through those operations to the parameters. A group's first backward then stops at
    the leaves, and each plant's ``backward`` (its share of the autograd graph) runs as
    its own task: the same operations on the same values, so the same bits."""

    CUT = ("scales", "opacities", "colors")

    def __init__(self, call: dict[str, Any]) -> None:
        self.inputs: list[torch.Tensor] = []
        self.leaves: list[torch.Tensor] = []
        for name in self.CUT:
            t = call[name]
            if t.grad_fn is not None:
                leaf = t.detach().requires_grad_(True)
                self.inputs.append(t)
                self.leaves.append(leaf)
                call[name] = leaf
        self.call = call

    def backward(self) -> None:
        pairs = [(t, leaf.grad) for t, leaf in zip(self.inputs, self.leaves, strict=True)]
        pairs = [(t, g) for t, g in pairs if g is not None]
        if pairs:
            torch.autograd.backward([t for t, _ in pairs], [g for _, g in pairs])


# ``host_map(fn, indices)``: ``[fn(k) for k in indices]``, on any threads, in order (the
# step's host pool).
HostMap = Callable[[Callable[[int], Any], Sequence[int]], list[Any]]


def render_many(
    models: Sequence[GaussianModel],
    cameras: Sequence[Camera],
    background: float,
    host_map: HostMap | None = None,
) -> tuple[
    list[tuple[torch.Tensor, torch.Tensor, dict[str, Any]] | PlantDreamerError],
    list[RenderInputs],
]:
    """``models[k].render([cameras[k]], background)`` for every k, as one native call each
    way (``rasterization_many``'s stages, ``RasterBatch``: the same bits); a model whose
    render fails gets its error in its place. The renders' gradients must come from one
    ``torch.autograd.backward`` over all of them, which reaches the parameters' gradients
    once every model's ``RenderInputs.backward`` ran (the second list). ``host_map`` runs
    each plant's Python work (render arguments, the rasterizer's per-scene stages; a thread
    pool's ``map``), each task in the caller's autograd mode; by default one plant after
    another."""
    from plantdreamer.rasterizer import RasterBatch

    each_plant = _in_callers_grad_mode(host_map)
    plants = range(len(models))

    def cut(k: int) -> RenderInputs:
        return RenderInputs(models[k].render_call([cameras[k]], background))

    inputs = each_plant(cut, plants)
    batch = RasterBatch([i.call for i in inputs])
    each_plant(batch.prepare, plants)
    batch.render()
    each_plant(batch.finish, plants)
    return batch.results(), inputs


def _in_callers_grad_mode(host_map: HostMap | None) -> HostMap:
    """``host_map`` with each task in the calling thread's autograd mode (a thread pool's
    threads do not inherit ``torch.no_grad``), or, for None, one task after another on the
    calling thread."""
    if host_map is None:
        return lambda fn, indices: [fn(k) for k in indices]
    enabled = torch.is_grad_enabled()

    def run(fn: Callable[[int], Any], indices: Sequence[int]) -> list[Any]:
        def task(k: int) -> Any:
            with torch.set_grad_enabled(enabled):
                return fn(k)

        return host_map(task, indices)

    return run
