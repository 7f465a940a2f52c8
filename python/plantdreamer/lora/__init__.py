"""Species LoRA training (``plantdreamer lora train``).

- ``dataset``: the photo folder, captions, conversion, augmentation
- ``train``: ``LoraTrainConfig``, ``train_lora``
- ``objective``: the noise-prediction loss and the held-out evaluation
- ``checkpoint``: resumable checkpoints
- ``export``: the diffusers-format weights file and validation samples

Importing this package needs only torch; diffusers / peft load when training starts.
"""

from plantdreamer.lora.train import LoraTrainConfig, LoraTrainResult, train_lora

__all__ = ["LoraTrainConfig", "LoraTrainResult", "train_lora"]
