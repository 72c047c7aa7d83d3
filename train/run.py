"""Fit a model: data -> sampler -> loader -> model -> optimizer -> resume -> epochs -> evaluate -> save.

Reads top to bottom like torchvision's reference `train.py`: `_fit` is that sequence, one call a
step. The data side is `train.loaders`, the model side and what a run changes as it goes (one
`TrainState`) `train.state`; this module runs the epochs and writes the run folder.
`train_model(config, out_dir)` is the entry point for other stages; `segmin train` and
`torchrun -m segmin.train.cli` call `fit`.

Run folder (written by rank 0 only): `best.pt` (best val IoU), `swa.pt` (the weight average, when
`swa_start_epoch` is set), `last.pt` (end of the last epoch,
the step boundary of a Ctrl-C, or a mid-epoch checkpoint every `checkpoint_every_steps` steps /
`checkpoint_every_minutes` minutes; with the state for `--resume`), `metrics.csv`, `tensorboard/`,
`previews/epoch_NNN.png`, `split.json` (the exact frames of each split), `config.yaml`.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
import random
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from torch.optim.swa_utils import AveragedModel, update_bn
from tqdm import tqdm

from segmin.common.atomic import write_text
from segmin.common.config import to_dict
from segmin.common.outputs import check_output_dir
from segmin.data.agriseg_loader import DatasetError, Frame, save_split
from segmin.data.frame_check import require_sound_frames, worker_error_line
from segmin.models.lraspp import check_backbone_weights
from segmin.train.checkpoint import model_info, write_training_checkpoint
from segmin.train.config import TrainConfig
from segmin.train.distributed import DistInfo, all_reduce_sum, barrier, cleanup, init_distributed
from segmin.train.loaders import Loaders, build_loaders, select_frames
from segmin.train.logs import RunLogger
from segmin.train.loop import StepContext, evaluate, train_one_epoch
from segmin.train.state import TrainState, build_state, resume_state

# Progress lines (resume, epochs, weight average, interruption): the command shows them.
log = logging.getLogger(__name__)


@dataclass
class FitResult:
    best_path: Path
    last_path: Path
    history: list[dict[str, Any]] = field(default_factory=list)
    model: torch.nn.Module | None = None
    interrupted: bool = False
    rank: int = 0
    world_size: int = 1
    swa_path: Path | None = None  # written when weight averaging is on and every epoch is done
    swa_model: torch.nn.Module | None = None  # the averaged weights with their BatchNorm statistics


def train_model(config: TrainConfig, out_dir: str | Path, *, resume: bool = False, force: bool = False) -> Path:
    """Train and return the path of the run's result: swa.pt with weight averaging, else best.pt."""
    result = fit(config, out_dir, resume=resume, force=force)
    if result.interrupted:
        raise KeyboardInterrupt(f"training interrupted; resume with --resume from {result.last_path}")
    return result.swa_path or result.best_path


# What a training run leaves in its folder; a new run must not silently replace them.
RUN_OUTPUTS: tuple[str, ...] = ("best.pt", "last.pt", "metrics.csv", "previews", "tensorboard", "swa.pt")


def claim_run_folder(out_dir: Path, *, resume: bool, force: bool) -> None:
    """Refuse to start a fresh run over an earlier one unless told to continue or to start over.

    Like `segmin export`: overwriting best.pt / last.pt / metrics.csv of a finished run loses
    work, so that needs `--force` (which removes the old outputs first, so a new run that is
    interrupted early cannot leave a stale best.pt behind) or `--resume` (continue it).
    """
    if resume and force:
        raise ValueError("--resume and --force contradict each other: continue the run or start over, not both")
    if resume:
        return
    existing = [name for name in RUN_OUTPUTS[:3] if (out_dir / name).exists()]
    if not existing:
        return
    if not force:
        raise FileExistsError(
            f"{out_dir}: already holds a training run ({', '.join(existing)}); "
            "pass --resume to continue it or --force to start over"
        )
    for name in RUN_OUTPUTS:
        target = out_dir / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()


def fit(config: TrainConfig, out_dir: str | Path, *, resume: bool = False, force: bool = False) -> FitResult:
    """Train per `config` in `out_dir`; `resume` continues last.pt, `force` replaces an earlier run."""
    import cv2

    out_dir = check_output_dir(out_dir, "--out")
    check_backbone_weights(config.backbone_weights)  # before any data is read: names the file to place
    if int(os.environ.get("RANK", "0")) == 0:
        claim_run_folder(out_dir, resume=resume, force=force)
    if config.threads:
        torch.set_num_threads(config.threads)
    cv2.setNumThreads(1)  # in-process loading (num_workers=0) must not start a second thread pool
    dist = init_distributed(config.device)
    try:
        return _fit(config, out_dir, resume, dist)
    finally:
        cleanup()


@dataclass
class CheckpointClock:
    """When a mid-epoch last.pt is due: every `every_steps` steps, and/or `minutes` after the last one."""

    every_steps: int | None
    minutes: float | None
    saved_at: float = field(default_factory=time.monotonic)

    def due(self, step: int) -> bool:
        return (self.every_steps is not None and step % self.every_steps == 0) or (
            self.minutes is not None and time.monotonic() - self.saved_at >= 60.0 * self.minutes
        )

    def restart(self) -> None:
        self.saved_at = time.monotonic()


@dataclass
class Run:
    """What stays fixed while a run trains: its settings, its process, its loaders and step context,
    and what rank 0 writes to (`logger` is None on the other ranks)."""

    config: TrainConfig
    dist: DistInfo
    out_dir: Path
    loaders: Loaders
    ctx: StepContext
    logger: RunLogger | None
    info: dict[str, Any]  # model_info, stored in every checkpoint
    config_dict: dict[str, Any]  # the config, stored in every checkpoint
    clock: CheckpointClock

    @property
    def best_path(self) -> Path:
        return self.out_dir / "best.pt"

    @property
    def last_path(self) -> Path:
        return self.out_dir / "last.pt"

    @property
    def show_progress(self) -> bool:
        return self.config.progress and self.dist.is_main


def _fit(config: TrainConfig, out_dir: Path, resume: bool, dist: DistInfo) -> FitResult:
    """The run: data -> sampler -> loader -> model -> optimizer -> resume -> epochs -> weight average."""
    _seed_everything(config.seed)
    train_frames, val_frames = select_frames(config)
    # Decode every frame once now: a corrupt one must stop the run here, naming the file, not
    # as a worker traceback hours in (or never, when the sampler happens not to pick it).
    require_sound_frames(
        train_frames + val_frames,
        out_dir / "frame_check.json" if dist.is_main else None,
        threads=max(1, config.num_workers),
    )
    loaders = build_loaders(config, dist, train_frames, val_frames)
    state, ctx = build_state(config, dist)
    if resume:
        resume_state(state, out_dir / "last.pt", dist, config.architecture)
        if dist.is_main:
            log.info("resuming %s: epoch %d, step %d", out_dir / "last.pt", state.epoch + 1, state.step)
    logger = _open_run_folder(config, out_dir, train_frames, val_frames) if dist.is_main else None
    run = Run(
        config,
        dist,
        out_dir,
        loaders,
        ctx,
        logger,
        info=checkpoint_model_info(config),
        config_dict=to_dict(config),
        clock=CheckpointClock(config.checkpoint_every_steps, config.checkpoint_every_minutes),
    )
    interrupted, swa_path = False, None
    try:
        while state.epoch < config.epochs:
            train_epoch(run, state)
        if state.averaged is not None and int(state.averaged.n_averaged) > 0:
            swa_path = finish_weight_average(run, state.averaged)
    except DatasetError as exc:  # from a loader worker: its message is the worker's whole traceback
        raise DatasetError(worker_error_line(exc)) from None
    except KeyboardInterrupt:
        interrupted = True
        if dist.is_main:
            _save_interrupted(run, state)
    finally:
        if logger is not None:
            logger.close()
    swa_model = state.averaged.module if swa_path is not None and state.averaged is not None else None
    return FitResult(
        run.best_path,
        run.last_path,
        state.history,
        state.model,
        interrupted,
        dist.rank,
        dist.world_size,
        swa_path,
        swa_model,
    )


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _open_run_folder(
    config: TrainConfig, out_dir: Path, train_frames: list[Frame], val_frames: list[Frame]
) -> RunLogger:
    """Rank 0: the run's logs, its config and its exact split, written before the first epoch."""
    logger = RunLogger(out_dir, config.tensorboard)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_text(out_dir / "config.yaml", yaml.safe_dump(to_dict(config), sort_keys=False))
    save_split(
        out_dir / "split.json",
        {"train": train_frames, "val": val_frames},
        root=str(config.data.root),
        val_root=str(config.data.val_root or config.data.root),
    )
    return logger


# ----------------------------------------------------------------------------- one epoch


def train_epoch(run: Run, state: TrainState) -> None:
    """The epoch `state` is in, from where it stands: train, validate, step the LR schedule, record, save."""
    started = time.perf_counter()
    train_loss = _train_steps(run, state)
    val, samples = _validate(run, run.ctx, "validate", keep=run.config.preview_images if run.dist.is_main else 0)
    lr = state.optimizer.param_groups[0]["lr"]
    if state.scheduler is not None:
        state.scheduler.step()
    row = {
        "epoch": state.epoch + 1,
        "train_loss": train_loss,
        "val_loss": val["loss"],
        "val_iou": val["iou"],
        "val_pixel_acc": val["pixel_acc"],
        "lr": lr,
        "seconds": time.perf_counter() - started,
    }
    improved = _end_epoch(run.config, state, row)
    if run.dist.is_main:
        _save_epoch(run, state, samples, improved)
    barrier()


def _train_steps(run: Run, state: TrainState) -> float:
    """The epoch's steps from `state.step` on; returns the epoch's mean training loss.

    After each step the state counts it, and rank 0 writes a mid-epoch last.pt when one is due
    (no collectives there: the other ranks never wait for it). The epoch's last step is left to
    the epoch end, which saves anyway, with the epoch's metrics.
    """
    skip, steps = state.step, run.loaders.steps_per_epoch
    run.loaders.sampler.set_epoch(state.epoch, skip=skip * run.config.batch_size)

    def after_step(done: int) -> None:
        state.step = skip + done
        if run.dist.is_main and state.step < steps and run.clock.due(state.step):
            save_last(run, state)
            run.clock.restart()

    bar = tqdm(
        total=max(0, steps - skip),
        desc=f"epoch {state.epoch + 1}/{run.config.epochs}",
        disable=not run.show_progress,
        leave=False,
    )
    result = train_one_epoch(
        run.ctx, run.loaders.train, max_steps=steps - skip, on_step=after_step, progress=bar, total=state.loss_total
    )
    bar.close()
    return result["loss"]


def _validate(
    run: Run, ctx: StepContext, desc: str, keep: int = 0
) -> tuple[dict[str, float], list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]]:
    """Metrics of `ctx.model` on the whole validation set (reduced over ranks), and `keep` previews."""
    bar = tqdm(total=len(run.loaders.val), desc=desc, disable=not run.show_progress, leave=False)
    result = evaluate(ctx, run.loaders.val, threshold=run.config.threshold, keep=keep, progress=bar)
    bar.close()
    return result


def _end_epoch(config: TrainConfig, state: TrainState, row: dict[str, Any]) -> bool:
    """Add a finished epoch to the state (history, best IoU, weight average; the next epoch starts
    at step 0 with its loss sums at zero); True when its IoU is the best yet."""
    state.history.append(row)
    improved = row["val_iou"] > state.best_iou
    state.best_iou = max(state.best_iou, row["val_iou"])
    if state.averaged is not None and config.swa_start_epoch is not None and row["epoch"] >= config.swa_start_epoch:
        state.averaged.update_parameters(state.model)
    state.epoch, state.step = state.epoch + 1, 0
    state.loss_total.zero_()
    return improved


def _save_epoch(
    run: Run, state: TrainState, samples: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]], improved: bool
) -> None:
    """Rank 0, after an epoch: best.pt when it improved, last.pt, metrics.csv, TensorBoard, a preview, one line."""
    if improved:
        write_training_checkpoint(
            run.best_path,
            model=state.model,
            info=run.info,
            epoch=state.epoch,
            metrics=state.last_metrics(),
            config=run.config_dict,
        )
    save_last(run, state)
    assert run.logger is not None
    run.logger.epoch(state.history)
    run.logger.preview(state.epoch, samples, run.config.threshold)
    row = state.history[-1]
    log.info(
        f"epoch {state.epoch}/{run.config.epochs}: train loss {row['train_loss']:.4f}  val loss "
        f"{row['val_loss']:.4f}  IoU {row['val_iou']:.4f}  acc {row['val_pixel_acc']:.4f}  "
        f"({row['seconds']:.0f} s){'  *best*' if improved else ''}"
    )


def save_last(run: Run, state: TrainState) -> None:
    """last.pt: the weights, everything `--resume` needs, and the last finished epoch's metrics."""
    write_training_checkpoint(
        run.last_path,
        model=state.model,
        info=run.info,
        epoch=state.epoch,
        metrics=state.last_metrics(),
        config=run.config_dict,
        training_state=state.checkpoint_state(),
    )


def _save_interrupted(run: Run, state: TrainState) -> None:
    """Rank 0, on Ctrl-C (always at a step boundary, see train.interrupt): last.pt, and how to go on."""
    save_last(run, state)
    log.warning(
        "\ninterrupted: saved %s (epoch %d, step %d); continue with --resume",
        run.last_path,
        state.epoch + 1,
        state.step,
    )


# ----------------------------------------------------------------------------- weight average


def finish_weight_average(run: Run, averaged: AveragedModel) -> Path:
    """BatchNorm statistics for the averaged weights, its validation, and swa.pt.

    The running statistics of the last epoch belong to the last weights, not to their average:
    `update_bn` recomputes them with one pass over the training frames (as the SWA paper does),
    an epoch's worth of batches.
    """
    run.loaders.sampler.set_epoch(run.config.epochs)
    _average_batchnorm_statistics(run, averaged)
    val, _ = _validate(run, dataclasses.replace(run.ctx, model=averaged.module), "swa: validate")
    path = run.out_dir / "swa.pt"
    if run.dist.is_main:
        metrics = {
            "val_loss": val["loss"],
            "val_iou": val["iou"],
            "val_pixel_acc": val["pixel_acc"],
            "swa_epochs": float(averaged.n_averaged),
        }
        write_training_checkpoint(
            path, model=averaged.module, info=run.info, epoch=run.config.epochs, metrics=metrics, config=run.config_dict
        )
        log.info(
            f"swa: average of epochs {run.config.swa_start_epoch}-{run.config.epochs} "
            f"({int(averaged.n_averaged)} epochs): val loss {val['loss']:.4f}  IoU {val['iou']:.4f}  "
            f"acc {val['pixel_acc']:.4f}  -> {path}"
        )
    barrier()
    return path


def _average_batchnorm_statistics(run: Run, averaged: AveragedModel) -> None:
    """`update_bn` over an epoch of this rank's batches, then the mean over the ranks.

    Each rank saw its own shard: averaging the statistics makes every rank validate, and rank 0
    save, the same model (update_bn's variance is itself a mean of per-batch variances).
    """
    steps = run.loaders.steps_per_epoch
    batches = itertools.islice(run.loaders.train, steps)
    update_bn(
        tqdm(batches, total=steps, desc="swa: BatchNorm statistics", disable=not run.show_progress, leave=False),
        averaged.module,
        device=run.dist.device,
    )
    for module in averaged.module.modules():
        if isinstance(module, torch.nn.modules.batchnorm._BatchNorm) and module.running_mean is not None:
            for buffer in (module.running_mean, module.running_var):
                all_reduce_sum(buffer).div_(run.dist.world_size)


def checkpoint_model_info(config: TrainConfig) -> dict[str, Any]:
    """What every checkpoint of the run says about its model and the data it learned from."""
    d = config.data
    train_data = f"{d.root} domains={d.domains or 'all'}"
    if d.val_domains:
        train_data += f"; val {d.val_root or d.root} domains={d.val_domains}"
    return model_info(
        backbone_weights=str(config.backbone_weights),
        input_size=(config.image_size, config.image_size),
        family=config.family,
        train_data=train_data,
        threshold=config.threshold,
        architecture=config.architecture,
    )
