"""One training epoch and one evaluation pass; no I/O besides progress bars."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from segmin.train.distributed import all_reduce_sum
from segmin.train.interrupt import StepGuard
from segmin.train.metrics import SegMetrics


class SegLoss(nn.Module):
    """BCE on logits (the paper), plus `dice_weight` x soft Dice when asked for."""

    def __init__(self, dice_weight: float = 0.0) -> None:
        super().__init__()
        self.dice_weight = dice_weight

    def per_sample(self, logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        logits = logits.float()
        loss = F.binary_cross_entropy_with_logits(logits, target, reduction="none").flatten(1).mean(1)
        if self.dice_weight > 0:
            prob = torch.sigmoid(logits).flatten(1)
            truth = target.flatten(1)
            dice = 1 - (2 * (prob * truth).sum(1) + 1) / (prob.sum(1) + truth.sum(1) + 1)
            loss = loss + self.dice_weight * dice
        return loss

    def forward(self, logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        return self.per_sample(logits, target).mean()


@dataclass
class StepContext:
    """What a training step needs besides the batch."""

    model: nn.Module
    optimizer: torch.optim.Optimizer
    loss_fn: SegLoss
    device: torch.device
    scaler: torch.amp.GradScaler | None = None
    amp: bool = False
    channels_last: bool = False


def _to_device(ctx: StepContext, images: torch.Tensor, masks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    non_blocking = ctx.device.type == "cuda"
    images = images.to(ctx.device, non_blocking=non_blocking)
    masks = masks.to(ctx.device, non_blocking=non_blocking)
    if ctx.channels_last:
        images = images.contiguous(memory_format=torch.channels_last)
    return images, masks


def _autocast(ctx: StepContext):
    if ctx.amp and ctx.device.type == "cuda":
        return torch.autocast(device_type="cuda", dtype=torch.float16)
    return contextlib.nullcontext()


def train_step(ctx: StepContext, images: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
    """One optimizer step; returns the per-sample losses (detached)."""
    images, masks = _to_device(ctx, images, masks)
    ctx.optimizer.zero_grad(set_to_none=True)
    with _autocast(ctx):
        logits = ctx.model(images)
    per_sample = ctx.loss_fn.per_sample(logits, masks)
    loss = per_sample.mean()
    if ctx.scaler is not None:
        ctx.scaler.scale(loss).backward()
        ctx.scaler.step(ctx.optimizer)
        ctx.scaler.update()
    else:
        loss.backward()
        ctx.optimizer.step()
    return per_sample.detach()


def train_one_epoch(
    ctx: StepContext,
    batches: Iterable[tuple[torch.Tensor, torch.Tensor]],
    *,
    max_steps: int | None = None,
    on_step: Callable[[int], None] | None = None,
    progress=None,
    total: torch.Tensor | None = None,
) -> dict[str, float]:
    """Train over `batches`; returns {"loss": mean over samples (reduced over ranks)}.

    `on_step(step)` is called after each step (used to record mid-epoch progress for Ctrl-C and
    for mid-epoch checkpoints). A Ctrl-C during a step is raised once the step and its `on_step`
    are done (see train.interrupt), so the recorded progress always matches the weights.
    `total` ([sum of per-sample losses, samples], float64 on the device) carries the sums of the
    steps an interrupted epoch did before: it is updated in place after each step, so a
    checkpoint written from `on_step` holds the sums up to that step, and summed over the ranks
    at the end.
    """
    ctx.model.train()
    if total is None:
        total = torch.zeros(2, dtype=torch.float64, device=ctx.device)
    with StepGuard() as guard:
        for step, (images, masks) in enumerate(batches):
            if max_steps is not None and step >= max_steps:
                break
            with guard.step():
                per_sample = train_step(ctx, images, masks)
                total += torch.stack(
                    [
                        per_sample.double().sum(),
                        torch.tensor(float(per_sample.numel()), dtype=torch.float64, device=ctx.device),
                    ]
                )
                if on_step is not None:
                    on_step(step + 1)
            if progress is not None:
                progress.update(1)
                progress.set_postfix(loss=f"{per_sample.mean().item():.4f}")
    all_reduce_sum(total)
    return {"loss": (total[0] / total[1]).item() if total[1] > 0 else float("nan")}


@torch.no_grad()
def evaluate(
    ctx: StepContext,
    batches: Iterable[tuple[torch.Tensor, torch.Tensor]],
    *,
    threshold: float = 0.5,
    keep: int = 0,
    progress=None,
) -> tuple[dict[str, float], list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]]:
    """Whole-set metrics (summed, reduced over ranks) and the first `keep` (image, mask, prob)."""
    ctx.model.eval()
    metrics = SegMetrics(threshold, device=ctx.device)
    kept: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
    for images, masks in batches:
        images_d, masks_d = _to_device(ctx, images, masks)
        with _autocast(ctx):
            logits = ctx.model(images_d)
        logits = logits.float()
        metrics.update(logits, masks_d, ctx.loss_fn.per_sample(logits, masks_d).sum())
        if len(kept) < keep:
            probs = torch.sigmoid(logits).cpu()
            for i in range(min(keep - len(kept), images.shape[0])):
                kept.append((images[i], masks[i], probs[i]))
        if progress is not None:
            progress.update(1)
    metrics.all_reduce()
    return metrics.compute(), kept
