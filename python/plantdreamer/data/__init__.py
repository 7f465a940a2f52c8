"""Torch datasets of what plantdreamer writes: ``PlantViews`` reads the labelled views of a
plant or dataset folder in the dtypes torchvision's detection models take."""

from __future__ import annotations

from plantdreamer.data.views import (
    DETECTION_KEYS,
    TARGET_KEYS,
    PlantViews,
    collate,
    object_keys,
)

__all__ = ["DETECTION_KEYS", "TARGET_KEYS", "PlantViews", "collate", "object_keys"]
