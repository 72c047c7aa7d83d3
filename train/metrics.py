"""Validation metrics summed over the whole set, then divided once.

The crop IoU is (sum of intersections) / (sum of unions) over every validation pixel, not a mean
of per-batch IoUs: batch means weigh a batch of two frames like one of sixty-four and change
with the batch size. Sums also reduce exactly across DDP ranks. Pixels are counted on the
training device with torch; the figures come from `segmin.common.seg_metrics`, the one place
that defines them for training, export verification, the IoU bound and eval-seg.
"""

from __future__ import annotations

import torch

from segmin.common.seg_metrics import PixelCounts
from segmin.train.distributed import all_reduce_sum

_COUNTS = 4  # tp, fp, fn, tn: the order of PixelCounts.from_values
_FIELDS = ("loss_sum", "samples")  # after the counts


def count_pixels(prediction: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """(tp, fp, fn, tn) of two same-shape boolean tensors, int64 on their device (no sync with the host).

    One bincount over the codes 2 * prediction + truth, as torchvision's reference ConfusionMatrix
    counts; uint8 codes keep the temporary at one byte per pixel.
    """
    codes = prediction.reshape(-1).to(torch.uint8) * 2 + truth.reshape(-1).to(torch.uint8)
    tn, fn, fp, tp = torch.bincount(codes, minlength=4)
    return torch.stack([tp, fp, fn, tn])


class SegMetrics:
    """Accumulates crop-class pixel counts and the loss (float64 sums) for IoU, pixel accuracy and mean loss."""

    def __init__(self, threshold: float = 0.5, device: torch.device | str = "cpu") -> None:
        self.threshold = threshold
        self.sums = torch.zeros(_COUNTS + len(_FIELDS), dtype=torch.float64, device=device)

    @torch.no_grad()
    def update(self, logits: torch.Tensor, target: torch.Tensor, loss_sum: torch.Tensor | float = 0.0) -> None:
        """Add a batch: `logits` and `target` N x 1 x H x W; `loss_sum` = loss summed over samples."""
        pred = torch.sigmoid(logits.float()) > self.threshold
        batch = torch.cat(
            [
                count_pixels(pred, target > 0.5).double(),
                torch.as_tensor(loss_sum, dtype=torch.float64, device=pred.device).detach().reshape(1),
                torch.tensor([float(logits.shape[0])], dtype=torch.float64, device=pred.device),
            ]
        )
        self.sums += batch.to(self.sums.device)

    def all_reduce(self) -> None:
        """Sum the accumulators over DDP ranks (no-op without a process group)."""
        all_reduce_sum(self.sums)

    def compute(self) -> dict[str, float]:
        sums = self.sums.tolist()
        counts = PixelCounts.from_values(sums[:_COUNTS])
        loss_sum, samples = sums[_COUNTS:]
        return {
            "iou": counts.iou,
            "pixel_acc": counts.pixel_accuracy,
            "loss": loss_sum / samples if samples > 0 else float("nan"),
        }
