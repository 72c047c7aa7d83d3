"""Validation metrics summed over the whole set, then divided once.

The crop IoU is (sum of intersections) / (sum of unions) over every validation pixel, not a mean
of per-batch IoUs: batch means weigh a batch of two frames like one of sixty-four and change
with the batch size. Sums also reduce exactly across DDP ranks.
"""

from __future__ import annotations

import torch

from segmin.train.distributed import all_reduce_sum

_FIELDS = ("intersection", "union", "correct", "pixels", "loss_sum", "samples")


class SegMetrics:
    """Accumulates crop-class IoU, pixel accuracy and mean loss (float64 sums)."""

    def __init__(self, threshold: float = 0.5, device: torch.device | str = "cpu") -> None:
        self.threshold = threshold
        self.sums = torch.zeros(len(_FIELDS), dtype=torch.float64, device=device)

    @torch.no_grad()
    def update(self, logits: torch.Tensor, target: torch.Tensor, loss_sum: torch.Tensor | float = 0.0) -> None:
        """Add a batch: `logits` and `target` N x 1 x H x W; `loss_sum` = loss summed over samples."""
        pred = torch.sigmoid(logits.float()) > self.threshold
        truth = target > 0.5
        inter = (pred & truth).sum()
        union = (pred | truth).sum()
        correct = (pred == truth).sum()
        batch = torch.stack(
            [
                inter.double(),
                union.double(),
                correct.double(),
                torch.tensor(float(truth.numel()), dtype=torch.float64, device=inter.device),
                torch.as_tensor(loss_sum, dtype=torch.float64, device=inter.device).detach(),
                torch.tensor(float(logits.shape[0]), dtype=torch.float64, device=inter.device),
            ]
        )
        self.sums += batch.to(self.sums.device)

    def all_reduce(self) -> None:
        """Sum the accumulators over DDP ranks (no-op without a process group)."""
        all_reduce_sum(self.sums)

    def compute(self) -> dict[str, float]:
        s = dict(zip(_FIELDS, self.sums.tolist()))
        return {
            # no crop anywhere, none predicted: a perfect answer
            "iou": s["intersection"] / s["union"] if s["union"] > 0 else 1.0,
            "pixel_acc": s["correct"] / s["pixels"] if s["pixels"] > 0 else float("nan"),
            "loss": s["loss_sum"] / s["samples"] if s["samples"] > 0 else float("nan"),
        }
