"""How high the validation IoU of an LR-ASPP can go on a set of masks, given its output resolution.

torchvision's LR-ASPP predicts one logit per 8 x 8 input pixels and upsamples the logits
bilinearly to the input size. Holes between leaves, thin branches and ragged canopy edges that
are narrower than that grid cannot be represented, whatever the weights. This module measures
the ceiling this puts on the crop IoU of a dataset (pooled over frames, as train.metrics reports it), with two
predictors that any LR-ASPP could in principle reproduce:

- `area`: the ground truth averaged over each 8 x 8 cell, turned into logits, upsampled and
  thresholded, a simple "perfect at low resolution" predictor;
- `fitted`: logits on the model's output grid optimised directly (Adam on BCE through the same
  bilinear upsampling) to reproduce each mask.

`fitted` estimates the ceiling from below: it is one reachable grid, found with a BCE
objective, not a proven optimum of IoU. On the vineyard test fields it moved by 0.002
with 4x more steps, so it is a close estimate there. A target well above it is not a matter of
training longer; `python -m benchmarks iou-bound` prints both figures for given sizes on any data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segmin.common.seg_metrics import PixelCounts

OUTPUT_STRIDE_CONVS = 3  # stride-2 convolutions before LR-ASPP's low-level features, each ceil-halving the side


def output_grid(size: int) -> int:
    """Side of LR-ASPP's logit grid for an input side `size` (ceil-halved three times)."""
    side = int(size)
    for _ in range(OUTPUT_STRIDE_CONVS):
        side = math.ceil(side / 2)
    return side


@dataclass(frozen=True)
class Bound:
    """IoU ceilings at one input size."""

    size: int
    grid: int
    frames: int
    area_iou: float
    fitted_iou: float


def load_masks(root: str | Path, domains: Sequence[str] | None, limit: int) -> list[np.ndarray]:
    """Up to `limit` binary masks at their stored size, evenly spaced over the sorted frames."""
    from segmin.data.agriseg_loader import find_frames, read_mask

    if limit < 1:
        raise ValueError(f"frames={limit}: need at least one mask")
    frames = find_frames(root, domains)
    if not frames:
        raise ValueError(f"{root}: no frames found for domains {domains}")
    if len(frames) > limit:
        picks = np.linspace(0, len(frames) - 1, limit).round().astype(int)
        frames = [frames[i] for i in picks]
    return [read_mask(frame.mask_path) for frame in frames]


def check_size(size: int) -> None:
    """Refuse an input side the logit grid cannot be computed for (callers check every size before
    printing a table, so an error never follows a header)."""
    if size < 8:
        raise ValueError(f"size={size}: need an input side of at least 8 pixels")


def resize_masks(masks: Sequence[np.ndarray], size: int) -> np.ndarray:
    """N x size x size float masks, resized with nearest neighbour as the training loader does."""
    import cv2

    check_size(size)
    resized = [cv2.resize(m, (size, size), interpolation=cv2.INTER_NEAREST_EXACT) for m in masks]
    return np.stack(resized).astype(np.float32)


def _iou(logits, masks) -> float:
    """Pooled IoU over all frames of the upsampled logits thresholded at 0 (p > 0.5, as training predicts)."""
    import torch.nn.functional as F

    from segmin.train.metrics import count_pixels

    predicted = F.interpolate(logits, size=masks.shape[-2:], mode="bilinear", align_corners=False) > 0
    return PixelCounts.from_values(count_pixels(predicted, masks > 0.5).tolist()).iou


def iou_bound(masks: np.ndarray, steps: int = 150, lr: float = 0.3, seed: int = 0) -> Bound:
    """Both ceilings for masks (N x S x S, 0/1) at input size S."""
    import torch
    import torch.nn.functional as F

    if masks.ndim != 3 or masks.shape[1] != masks.shape[2]:
        raise ValueError(f"masks of shape {masks.shape}: expected N x S x S")
    torch.manual_seed(seed)
    size = int(masks.shape[1])
    grid = output_grid(size)
    target = torch.from_numpy(np.ascontiguousarray(masks, dtype=np.float32))[:, None]
    coverage = F.adaptive_avg_pool2d(target, grid).clamp(1e-3, 1 - 1e-3)
    area_logits = torch.log(coverage / (1 - coverage))
    area_iou = _iou(area_logits, target)
    logits = area_logits.clone().requires_grad_(True)
    optimiser = torch.optim.Adam([logits], lr=lr)
    for _ in range(int(steps)):
        optimiser.zero_grad()
        upsampled = F.interpolate(logits, size=(size, size), mode="bilinear", align_corners=False)
        F.binary_cross_entropy_with_logits(upsampled, target).backward()
        optimiser.step()
    with torch.no_grad():
        fitted_iou = max(_iou(logits, target), area_iou)
    return Bound(size=size, grid=grid, frames=len(masks), area_iou=area_iou, fitted_iou=fitted_iou)
