"""Fit a model: data -> sampler -> loader -> model -> optimizer -> resume -> epochs -> checkpoints.

Reads top to bottom like torchvision's reference `train.py`. `train_model(config, out_dir)` is
the entry point for other stages; `segmin train` and `torchrun -m segmin.train.cli` call `fit`.

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
import math
import os
import random
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from torch.optim.swa_utils import AveragedModel, update_bn
from torch.utils.data import DataLoader, DistributedSampler

from segmin.common.atomic import write_text
from segmin.common.config import to_dict
from segmin.common.outputs import check_output_dir
from segmin.data.agriseg_loader import (
    AgriSegDataset,
    DatasetError,
    Frame,
    find_frames,
    load_split,
    make_splits,
    save_split,
)
from segmin.data.augment import eval_transform, train_transform
from segmin.data.frame_check import require_sound_frames, worker_error_line
from segmin.data.real_sets import check_frames_not_real
from segmin.models import build_model
from segmin.models.lraspp import check_backbone_weights
from segmin.train.checkpoint import model_info, read_training_state, rng_state, set_rng_state, write_training_checkpoint
from segmin.train.config import TrainConfig
from segmin.train.distributed import (
    DistInfo,
    EpochSampler,
    ShardSampler,
    all_reduce_sum,
    barrier,
    cleanup,
    init_distributed,
)
from segmin.train.logs import RunLogger
from segmin.train.loop import SegLoss, StepContext, evaluate, train_one_epoch

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


# ----------------------------------------------------------------------------- data


def select_frames(config: TrainConfig) -> tuple[list[Frame], list[Frame]]:
    """(train frames, val frames) as the config says: held-out domains, split file or seeded split."""
    d = config.data
    if d.val_domains:
        train = find_frames(d.root, d.domains, skip_unpaired=d.skip_unpaired)
        val = find_frames(d.val_root or d.root, d.val_domains, skip_unpaired=d.skip_unpaired)
        overlap = {f.image_path for f in train} & {f.image_path for f in val}
        if overlap:
            raise DatasetError(f"{sorted(overlap)[0]}: frame is in both training and validation domains")
    else:
        frames = find_frames(d.root, d.domains, skip_unpaired=d.skip_unpaired)
        splits = load_split(d.split_file, frames) if d.split_file else make_splits(frames, d.val_fraction, d.split_seed)
        train, val = splits["train"], splits["val"]
    check_frames_not_real({"training": train, "validation": val})  # whatever the config says now
    train = _subsample(train, d.max_train_frames, d.split_seed)
    val = _subsample(val, d.max_val_frames, d.split_seed + 1)
    if not train:
        raise DatasetError(f"{d.root}: no training frames for domains {d.domains}")
    if not val:
        raise DatasetError(
            f"{d.val_root or d.root}: no validation frames (set data.val_fraction > 0 or data.val_domains)"
        )
    return train, val


def _subsample(frames: list[Frame], limit: int | None, seed: int) -> list[Frame]:
    if limit is None or len(frames) <= limit:
        return frames
    keep = np.random.default_rng(seed).choice(len(frames), size=limit, replace=False)
    return [frames[i] for i in sorted(keep.tolist())]


def _worker_init(_: int) -> None:
    import signal

    import cv2

    cv2.setNumThreads(1)  # loader workers must not fight the training threads for the cores
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to handle (it saves)


def build_loaders(config: TrainConfig, dist: DistInfo, train_frames: list[Frame], val_frames: list[Frame]):
    size = config.image_size
    closing = config.data.label_closing
    train_ds = AgriSegDataset(
        config.data.root,
        split="all",
        seed=config.seed,
        frames=train_frames,
        transform=train_transform(size, config.augment),
        image_size=size,
        label_closing=closing,
    )
    val_ds = AgriSegDataset(
        config.data.root,
        split="all",
        seed=config.seed,
        frames=val_frames,
        transform=eval_transform(size),
        image_size=size,
        label_closing=closing,
    )
    base = DistributedSampler(
        train_ds, num_replicas=dist.world_size, rank=dist.rank, shuffle=True, seed=config.seed, drop_last=False
    )
    sampler = EpochSampler(base)
    common: dict[str, Any] = {"num_workers": config.num_workers, "pin_memory": dist.device.type == "cuda"}
    if config.num_workers > 0:
        common.update(prefetch_factor=config.prefetch_factor, persistent_workers=True, worker_init_fn=_worker_init)
    per_rank = len(base)
    train_loader = DataLoader(
        train_ds, batch_size=config.batch_size, sampler=sampler, drop_last=per_rank > config.batch_size, **common
    )
    val_loader = DataLoader(
        val_ds,
        batch_size=config.eval_batch_size or config.batch_size,
        sampler=ShardSampler(len(val_ds), dist.rank, dist.world_size),
        **common,
    )
    return train_loader, sampler, val_loader


# ----------------------------------------------------------------------------- fit


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
    import shutil

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


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _fit(config: TrainConfig, out_dir: Path, resume: bool, dist: DistInfo) -> FitResult:
    from tqdm import tqdm

    _seed_everything(config.seed)
    train_frames, val_frames = select_frames(config)
    # Decode every frame once now: a corrupt one must stop the run here, naming the file, not
    # as a worker traceback hours in (or never, when the sampler happens not to pick it).
    require_sound_frames(
        train_frames + val_frames,
        out_dir / "frame_check.json" if dist.is_main else None,
        threads=max(1, config.num_workers),
    )
    train_loader, sampler, val_loader = build_loaders(config, dist, train_frames, val_frames)

    model = build_model(config.backbone_weights)
    if config.bn_momentum is not None:
        for module in model.modules():
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                module.momentum = config.bn_momentum
    cuda = dist.device.type == "cuda"
    if cuda:
        torch.backends.cudnn.benchmark = True  # fixed input size: let cuDNN pick the fastest kernels
    model.to(dist.device)
    if config.channels_last:  # GPUs and CPUs alike: oneDNN's CPU convolutions gain too (segmin bench train)
        model.to(memory_format=torch.channels_last)
    net: torch.nn.Module = model
    if dist.distributed:
        net = torch.nn.parallel.DistributedDataParallel(model, device_ids=[dist.device.index] if cuda else None)
    optimizer = torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler: torch.optim.lr_scheduler.LRScheduler | None = None
    if config.schedule == "cosine":
        scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=config.epochs)
    elif config.schedule == "step":
        scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=config.step_size, gamma=config.gamma)
    scaler = torch.amp.GradScaler("cuda") if cuda and config.amp else None
    ctx = StepContext(
        net,
        optimizer,
        SegLoss(config.dice_weight),
        dist.device,
        scaler,
        amp=cuda and config.amp,
        channels_last=config.channels_last,
    )

    averaged = AveragedModel(model) if config.swa_start_epoch is not None else None
    info = model_info(
        backbone_weights=str(config.backbone_weights),
        input_size=(config.image_size, config.image_size),
        family=config.family,
        train_data=_describe_data(config),
        threshold=config.threshold,
    )
    config_dict = to_dict(config)
    best_path, last_path = out_dir / "best.pt", out_dir / "last.pt"
    start_epoch, skip_steps, best_iou, history = 0, 0, -math.inf, []
    if resume:
        payload = read_training_state(last_path)
        state = payload["training_state"]
        model.load_state_dict(payload["model"])
        optimizer.load_state_dict(state["optimizer"])
        if scheduler is not None and state.get("scheduler") is not None:
            scheduler.load_state_dict(state["scheduler"])
        if scaler is not None and state.get("scaler"):
            scaler.load_state_dict(state["scaler"])
        set_rng_state(state["rng"])
        start_epoch, skip_steps = int(state["epoch"]), int(state["step"])
        best_iou, history = float(state["best_iou"]), list(state["history"])
        if averaged is not None and state.get("swa") is not None:
            averaged.load_state_dict(state["swa"])
        if dist.is_main:
            print(f"resuming {last_path}: epoch {start_epoch + 1}, step {skip_steps}")

    logger = RunLogger(out_dir, config.tensorboard) if dist.is_main else None
    if dist.is_main:
        out_dir.mkdir(parents=True, exist_ok=True)
        write_text(out_dir / "config.yaml", yaml.safe_dump(config_dict, sort_keys=False))
        save_split(
            out_dir / "split.json",
            {"train": train_frames, "val": val_frames},
            root=str(config.data.root),
            val_root=str(config.data.val_root or config.data.root),
        )

    progress = {"epoch": start_epoch, "step": skip_steps}

    def save_last(metrics: dict[str, float]) -> None:
        write_training_checkpoint(
            last_path,
            model=model,
            info=info,
            epoch=progress["epoch"],
            metrics=metrics,
            config=config_dict,
            training_state={
                "epoch": progress["epoch"],
                "step": progress["step"],
                "optimizer": optimizer.state_dict(),
                "scheduler": scheduler.state_dict() if scheduler is not None else None,
                "scaler": scaler.state_dict() if scaler is not None else {},
                "rng": rng_state(),
                "best_iou": best_iou,
                "history": history,
                # not cpu_state_dict: it unwraps `.module` and would drop n_averaged
                "swa": None
                if averaged is None
                else {k: v.detach().cpu().clone() for k, v in averaged.state_dict().items()},
            },
        )

    interrupted = False
    swa_path: Path | None = None
    last_metrics: dict[str, float] = history[-1] if history else {}
    saved_at = time.monotonic()

    def after_step(step: int) -> None:
        """Record progress; write a mid-epoch last.pt when one is due (rank 0; no collectives)."""
        nonlocal saved_at
        progress.update(step=step)
        if not dist.is_main:
            return
        every, minutes = config.checkpoint_every_steps, config.checkpoint_every_minutes
        due = (every is not None and step % every == 0) or (
            minutes is not None and time.monotonic() - saved_at >= 60.0 * minutes
        )
        if due and step < steps_per_epoch:  # the epoch end saves anyway, with its metrics
            save_last({k: v for k, v in last_metrics.items() if k != "epoch"})
            saved_at = time.monotonic()

    steps_per_epoch = len(train_loader)
    if config.max_steps_per_epoch is not None:
        steps_per_epoch = min(steps_per_epoch, config.max_steps_per_epoch)
    try:
        for epoch in range(start_epoch, config.epochs):
            started = time.perf_counter()
            skip = skip_steps if epoch == start_epoch else 0
            progress.update(epoch=epoch, step=skip)
            sampler.set_epoch(epoch, skip=skip * config.batch_size)
            bar = tqdm(
                total=max(0, steps_per_epoch - skip),
                desc=f"epoch {epoch + 1}/{config.epochs}",
                disable=not (config.progress and dist.is_main),
                leave=False,
            )
            train = train_one_epoch(
                ctx,
                train_loader,
                max_steps=steps_per_epoch - skip,
                on_step=lambda s, skip=skip: after_step(skip + s),
                progress=bar,
            )
            bar.close()
            keep = config.preview_images if dist.is_main else 0
            bar = tqdm(
                total=len(val_loader), desc="validate", disable=not (config.progress and dist.is_main), leave=False
            )
            val, samples = evaluate(ctx, val_loader, threshold=config.threshold, keep=keep, progress=bar)
            bar.close()
            lr = optimizer.param_groups[0]["lr"]
            if scheduler is not None:
                scheduler.step()
            row = {
                "epoch": epoch + 1,
                "train_loss": train["loss"],
                "val_loss": val["loss"],
                "val_iou": val["iou"],
                "val_pixel_acc": val["pixel_acc"],
                "lr": lr,
                "seconds": time.perf_counter() - started,
            }
            history.append(row)
            last_metrics = row
            improved = val["iou"] > best_iou
            best_iou = max(best_iou, val["iou"])
            if averaged is not None and epoch + 1 >= config.swa_start_epoch:
                averaged.update_parameters(model)
            progress.update(epoch=epoch + 1, step=0)
            if dist.is_main:
                metrics = {k: v for k, v in row.items() if k != "epoch"}
                if improved:
                    write_training_checkpoint(
                        best_path, model=model, info=info, epoch=epoch + 1, metrics=metrics, config=config_dict
                    )
                save_last(metrics)
                assert logger is not None
                logger.epoch(history)
                logger.preview(epoch + 1, samples, config.threshold)
                print(
                    f"epoch {epoch + 1}/{config.epochs}: train loss {train['loss']:.4f}  val loss "
                    f"{val['loss']:.4f}  IoU {val['iou']:.4f}  acc {val['pixel_acc']:.4f}  "
                    f"({row['seconds']:.0f} s){'  *best*' if improved else ''}",
                    flush=True,
                )
            barrier()
        if averaged is not None and int(averaged.n_averaged) > 0:
            sampler.set_epoch(config.epochs)
            swa_path = _finish_weight_average(
                config, ctx, averaged, train_loader, steps_per_epoch, val_loader, out_dir, dist, info, config_dict
            )
    except DatasetError as exc:  # from a loader worker: its message is the worker's whole traceback
        raise DatasetError(worker_error_line(exc)) from None
    except KeyboardInterrupt:
        interrupted = True
        if dist.is_main:
            save_last({k: v for k, v in last_metrics.items() if k != "epoch"})
            print(
                f"\ninterrupted: saved {last_path} (epoch {progress['epoch'] + 1}, step {progress['step']}); "
                "continue with --resume",
                flush=True,
            )
    finally:
        if logger is not None:
            logger.close()
    return FitResult(
        best_path,
        last_path,
        history,
        model,
        interrupted,
        dist.rank,
        dist.world_size,
        swa_path,
        averaged.module if swa_path is not None else None,
    )


def _finish_weight_average(
    config: TrainConfig,
    ctx: StepContext,
    averaged: AveragedModel,
    train_loader,
    steps: int,
    val_loader,
    out_dir: Path,
    dist: DistInfo,
    info: dict[str, Any],
    config_dict: dict[str, Any],
) -> Path:
    """BatchNorm statistics for the averaged weights, its validation, and swa.pt.

    The running statistics of the last epoch belong to the last weights, not to their average:
    `update_bn` recomputes them with one pass over the training frames (as the SWA paper does),
    `steps` batches: an epoch's.
    """
    from tqdm import tqdm

    show = config.progress and dist.is_main
    update_bn(
        tqdm(
            itertools.islice(train_loader, steps),
            total=steps,
            desc="swa: BatchNorm statistics",
            disable=not show,
            leave=False,
        ),
        averaged.module,
        device=dist.device,
    )
    # Each rank saw its own shard: average the statistics so that every rank validates, and rank
    # 0 saves, the same model (update_bn's variance is itself a mean of per-batch variances).
    for module in averaged.module.modules():
        if isinstance(module, torch.nn.modules.batchnorm._BatchNorm) and module.running_mean is not None:
            for buffer in (module.running_mean, module.running_var):
                all_reduce_sum(buffer).div_(dist.world_size)
    bar = tqdm(total=len(val_loader), desc="swa: validate", disable=not show, leave=False)
    val, _ = evaluate(
        dataclasses.replace(ctx, model=averaged.module), val_loader, threshold=config.threshold, progress=bar
    )
    bar.close()
    path = out_dir / "swa.pt"
    if dist.is_main:
        metrics = {
            "val_loss": val["loss"],
            "val_iou": val["iou"],
            "val_pixel_acc": val["pixel_acc"],
            "swa_epochs": float(averaged.n_averaged),
        }
        write_training_checkpoint(
            path, model=averaged.module, info=info, epoch=config.epochs, metrics=metrics, config=config_dict
        )
        print(
            f"swa: average of epochs {config.swa_start_epoch}-{config.epochs} "
            f"({int(averaged.n_averaged)} epochs): val loss {val['loss']:.4f}  IoU {val['iou']:.4f}  "
            f"acc {val['pixel_acc']:.4f}  -> {path}",
            flush=True,
        )
    barrier()
    return path


def _describe_data(config: TrainConfig) -> str:
    d = config.data
    text = f"{d.root} domains={d.domains or 'all'}"
    if d.val_domains:
        text += f"; val {d.val_root or d.root} domains={d.val_domains}"
    return text
