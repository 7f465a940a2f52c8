"""``PixelMap``: a per-pixel target ([H, W]: a class map, an ignore map) that torchvision's
v2 transforms move as they move a ``Mask`` but never filter per object.

A ``Mask`` does not do: ``SanitizeBoundingBoxes`` indexes every ``Mask``'s first dimension
with the boxes it keeps, so an [H, W] map lost rows whenever a view had H objects. The
class is registered for the geometric functionals with the mask kernels (the public
``register_kernel``); other transforms pass it through, as they pass a mask. It lives at
module level so that a DataLoader's workers can pickle it. Imports torchvision.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torchvision import tv_tensors
from torchvision.transforms.v2 import functional as F

# The geometric functionals that move a mask.
GEOMETRY = (
    "horizontal_flip",
    "vertical_flip",
    "resize",
    "affine",
    "rotate",
    "pad",
    "crop",
    "perspective",
    "elastic",
    "center_crop",
    "resized_crop",
)


class PixelMap(tv_tensors.TVTensor):
    """A per-pixel target, moved like a mask, left whole by per-object filtering."""

    def __new__(cls, data: Any) -> PixelMap:
        return torch.as_tensor(data).as_subclass(cls)


def _as_mask_kernel(functional: Callable[..., Any]) -> Callable[..., Any]:
    def kernel(inpt: torch.Tensor, *args: Any, **kwargs: Any) -> torch.Tensor:
        moved = functional(tv_tensors.Mask(inpt.as_subclass(torch.Tensor)), *args, **kwargs)
        return tv_tensors.wrap(moved, like=inpt)

    return kernel


for _name in GEOMETRY:
    F.register_kernel(getattr(F, _name), PixelMap)(_as_mask_kernel(getattr(F, _name)))
