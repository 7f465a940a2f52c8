"""Species LoRA training (``plantdreamer lora train``).

- ``config``: ``LoraTrainConfig``, the settings (and the command's options)
- ``dataset``: the photo folder, captions, conversion, augmentation
- ``train``: ``train_lora``
- ``objective``: the noise-prediction loss and the held-out evaluation
- ``checkpoint``: resumable checkpoints
- ``export``: the diffusers-format weights file and validation samples

Names load on first use, so ``plantdreamer.lora.config`` (read by the CLI at start-up) does
not import torch; diffusers / peft load when training starts.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from plantdreamer.lora.config import LoraTrainConfig
    from plantdreamer.lora.train import LoraTrainResult, train_lora

__all__ = ["LoraTrainConfig", "LoraTrainResult", "train_lora"]

_MODULES = {
    "LoraTrainConfig": "plantdreamer.lora.config",
    "LoraTrainResult": "plantdreamer.lora.train",
    "train_lora": "plantdreamer.lora.train",
}


def __getattr__(name: str) -> Any:
    if name not in _MODULES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_MODULES[name]), name)
