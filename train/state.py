"""What a training run changes as it goes, in one `TrainState`: how it is built and how last.pt holds it.

The model side of a run (model -> optimizer -> LR schedule -> AMP scaler -> weight average) and
its progress (epoch, step, best IoU, history, the running loss sums). last.pt stores all of it
(`TrainState.checkpoint_state`) and `resume_state` puts it back, so `--resume` continues a run exactly:
the same weights and the same metrics.csv as a run that was never stopped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch.optim.swa_utils import AveragedModel

from segmin.models import build_model
from segmin.train.checkpoint import read_training_state, rng_state, set_rng_state
from segmin.train.config import TrainConfig
from segmin.train.distributed import DistInfo
from segmin.train.loop import SegLoss, StepContext


@dataclass
class TrainState:
    """Everything that changes while a run trains.

    `model` is the plain network, the one checkpoints hold (the steps may run it wrapped in DDP:
    `StepContext.model`). `epoch` is the epoch in progress, 0-based (`config.epochs` once every
    epoch is done), and `step` how many of its steps are done. `loss_total` is that epoch's
    running [sum of per-sample losses, samples], float64 on the device, updated in place by
    `train_one_epoch`: it goes into last.pt with the rest, so an epoch that is interrupted and
    resumed reports the train_loss of an uninterrupted one.
    """

    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler | None
    scaler: torch.amp.GradScaler | None
    averaged: AveragedModel | None  # the weight average, when swa_start_epoch is set
    loss_total: torch.Tensor
    epoch: int = 0
    step: int = 0
    best_iou: float = -math.inf
    history: list[dict[str, Any]] = field(default_factory=list)

    def last_metrics(self) -> dict[str, float]:
        """The last finished epoch's figures: what a checkpoint written now reports."""
        return {k: v for k, v in (self.history[-1] if self.history else {}).items() if k != "epoch"}

    def checkpoint_state(self) -> dict[str, Any]:
        """last.pt's `training_state`: tensors and plain data only (it loads with weights_only=True)."""
        return {
            "epoch": self.epoch,
            "step": self.step,
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict() if self.scheduler is not None else None,
            "scaler": self.scaler.state_dict() if self.scaler is not None else {},
            "rng": rng_state(),
            "best_iou": self.best_iou,
            "history": self.history,
            # not cpu_state_dict: it unwraps `.module` and would drop n_averaged
            "swa": None
            if self.averaged is None
            else {k: v.detach().cpu().clone() for k, v in self.averaged.state_dict().items()},
            "loss_total": self.loss_total.detach().cpu().clone(),
        }


def build_state(config: TrainConfig, dist: DistInfo) -> tuple[TrainState, StepContext]:
    """A fresh run's state, and the context its steps run in (the model, maybe in DDP, the loss, AMP)."""
    model, net = _build_model(config, dist)
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler = _build_scheduler(config, optimizer)
    amp = dist.device.type == "cuda" and config.amp
    scaler = torch.amp.GradScaler("cuda") if amp else None
    ctx = StepContext(
        net,
        optimizer,
        SegLoss(config.dice_weight),
        dist.device,
        scaler,
        amp=amp,
        channels_last=config.channels_last,
    )
    averaged = AveragedModel(model) if config.swa_start_epoch is not None else None
    loss_total = torch.zeros(2, dtype=torch.float64, device=dist.device)
    return TrainState(model, optimizer, scheduler, scaler, averaged, loss_total), ctx


def _build_model(config: TrainConfig, dist: DistInfo) -> tuple[torch.nn.Module, torch.nn.Module]:
    """The model on its device in its memory layout, and what the steps run: it, or its DDP wrapper."""
    model = build_model(config.backbone_weights, architecture=config.architecture)
    if config.bn_momentum is not None:
        for module in model.modules():
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                module.momentum = config.bn_momentum
    cuda = dist.device.type == "cuda"
    if cuda:
        torch.backends.cudnn.benchmark = True  # fixed input size: let cuDNN pick the fastest kernels
    model.to(dist.device)
    if config.channels_last:  # GPUs and CPUs alike: oneDNN's CPU convolutions gain too (python -m benchmarks train)
        model.to(memory_format=torch.channels_last)
    if not dist.distributed:
        return model, model
    return model, torch.nn.parallel.DistributedDataParallel(model, device_ids=[dist.device.index] if cuda else None)


def _build_scheduler(
    config: TrainConfig, optimizer: torch.optim.Optimizer
) -> torch.optim.lr_scheduler.LRScheduler | None:
    if config.schedule == "cosine":
        return torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=config.epochs)
    if config.schedule == "step":
        return torch.optim.lr_scheduler.StepLR(optimizer, step_size=config.step_size, gamma=config.gamma)
    return None


def resume_state(state: TrainState, last_path: Path, dist: DistInfo, architecture: str) -> None:
    """Put back what `last_path` holds: weights, optimizer, LR schedule, AMP scale, weight average,
    RNG streams, the place in the epoch and the epoch's running loss sums. `architecture` is the
    config's: a last.pt of another architecture is refused in one line (its weights cannot fit).

    Only rank 0 writes last.pt, so the loss sums in it are rank 0's: only rank 0 takes them back.
    With one process the resumed epoch's train_loss is exact; under DDP it leaves out the other
    ranks' share of the steps done before the interrupt. A last.pt from before the sums were
    saved resumes with them at zero (that epoch's train_loss then covers only the resumed steps).
    """
    payload = read_training_state(last_path)
    saved_architecture = payload["model_info"]["architecture"]
    if saved_architecture != architecture:
        raise ValueError(
            f"{last_path}: the run was started with architecture={saved_architecture}, the config says "
            f"{architecture}; resume with architecture={saved_architecture} or start over with --force"
        )
    saved = payload["training_state"]
    state.model.load_state_dict(payload["model"])
    state.optimizer.load_state_dict(saved["optimizer"])
    if state.scheduler is not None and saved.get("scheduler") is not None:
        state.scheduler.load_state_dict(saved["scheduler"])
    if state.scaler is not None and saved.get("scaler"):
        state.scaler.load_state_dict(saved["scaler"])
    set_rng_state(saved["rng"])
    state.epoch, state.step = int(saved["epoch"]), int(saved["step"])
    state.best_iou, state.history = float(saved["best_iou"]), list(saved["history"])
    if state.averaged is not None and saved.get("swa") is not None:
        state.averaged.load_state_dict(saved["swa"])
    if dist.is_main and saved.get("loss_total") is not None:
        state.loss_total.copy_(saved["loss_total"])
