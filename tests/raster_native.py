"""One scene through the native rasterizer pair, without the torch wrapper (tests and
benches): ``_core.rasterize_forward_many`` / ``rasterize_backward_many`` with a list of
one, the scene's error raised."""

from __future__ import annotations

from typing import Any

import numpy as np

from plantdreamer import _core


def forward(
    means: np.ndarray,
    quats: np.ndarray,
    scales: np.ndarray,
    opacities: np.ndarray,
    colors: np.ndarray | None,
    viewmats: np.ndarray,
    Ks: np.ndarray,
    width: Any,
    height: Any,
    *,
    sh_degree: Any = None,
    background: np.ndarray | None = None,
    **settings: Any,
) -> dict[str, Any]:
    """The scene's forward dict (render, alpha, ..., state); ``settings`` are the call's
    keywords (tile_size, threads, ...)."""
    scene = {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": opacities,
        "colors": colors,
        "viewmats": viewmats,
        "Ks": Ks,
        "width": width,
        "height": height,
        "sh_degree": sh_degree,
        "background": background,
    }
    (out,) = _core.rasterize_forward_many([scene], **settings)
    if isinstance(out, BaseException):
        raise out
    return out


def backward(
    state: _core.RasterState,
    v_render: np.ndarray,
    v_alpha: np.ndarray | None = None,
    **settings: Any,
) -> dict[str, Any]:
    """The gradients of a ``forward``'s inputs (gradient groups and threads as keywords)."""
    (grads,) = _core.rasterize_backward_many([state], [v_render], [v_alpha], **settings)
    if isinstance(grads, BaseException):
        raise grads
    return grads
