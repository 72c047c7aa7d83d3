"""Models: build the LR-ASPP MobileNetV3 segmentation network, nothing else."""

from segmin.models.lraspp import SegmentationNet, WeightsUnavailableError, build_model

__all__ = ["SegmentationNet", "WeightsUnavailableError", "build_model"]
