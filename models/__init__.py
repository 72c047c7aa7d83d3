"""Models: build the LR-ASPP MobileNetV3 segmentation network, nothing else.

The torch-backed names load on first use, so `segmin.models.architectures` (the table a training
config validates against) imports without torch.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

__all__ = ["SegmentationNet", "WeightsUnavailableError", "build_model"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(import_module("segmin.models.lraspp"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
