"""Which frames train and which validate, and the samplers and loaders that feed them to a run.

The first steps of a run (data -> sampler -> loader), apart from the model side in `train.state`
and the epochs in `train.run`. An empty split is refused here with the reason and the fix, before
any model is built.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
from torch.utils.data import DataLoader, DistributedSampler

from segmin.data.agriseg_loader import AgriSegDataset, DatasetError, Frame, find_frames, load_split, make_splits
from segmin.data.augment import eval_transform, train_transform
from segmin.data.real_sets import check_frames_not_real
from segmin.train.config import DataConfig, TrainConfig
from segmin.train.distributed import DistInfo, EpochSampler, ShardSampler


def select_frames(config: TrainConfig) -> tuple[list[Frame], list[Frame]]:
    """(train frames, val frames) as the config says: held-out domains, split file or seeded split."""
    d = config.data
    if d.val_domains:
        train = frames = find_frames(d.root, d.domains, skip_unpaired=d.skip_unpaired)
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
        raise DatasetError(_why_no_validation_frames(d, frames))
    return train, val


def _why_no_validation_frames(d: DataConfig, frames: list[Frame]) -> str:
    """One line: why validation came out empty, and what to change.

    With `val_fraction` > 0 the seeded split holds out at least one frame of every domain of two
    or more frames (`data.splits.make_splits`), so an empty validation set there means every
    domain is a single frame: the dataset is too small, and the setting is not the thing to fix.
    """
    if d.val_domains:
        return f"{d.val_root or d.root}: no validation frames for data.val_domains {d.val_domains}"
    if d.split_file:
        return f"{d.split_file}: the split file puts no frame of {d.root} in validation"
    if d.val_fraction == 0:
        return f"{d.root}: no validation frames (set data.val_fraction > 0 or data.val_domains)"
    counts = ", ".join(f"{domain}: {n}" for domain, n in sorted(Counter(f.domain for f in frames).items()))
    return (
        f"{d.root}: dataset too small to validate on: {len(frames)} frame(s) ({counts}); "
        f"data.val_fraction={d.val_fraction} holds out frames only from a domain of at least 2 frames "
        "(add frames, or set data.val_domains to validate on other domains)"
    )


def _subsample(frames: list[Frame], limit: int | None, seed: int) -> list[Frame]:
    if limit is None or len(frames) <= limit:
        return frames
    keep = np.random.default_rng(seed).choice(len(frames), size=limit, replace=False)
    return [frames[i] for i in sorted(keep.tolist())]


def loader_worker_init(_: int) -> None:
    """Set up a loader worker process: one OpenCV thread, and Ctrl-C left to the main process."""
    import signal

    import cv2

    cv2.setNumThreads(1)  # loader workers must not fight the training threads for the cores
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to handle (it saves)


@dataclass
class Loaders:
    """The training loader with its resumable sampler, the validation loader, and the epoch length."""

    train: DataLoader
    sampler: EpochSampler
    val: DataLoader
    steps_per_epoch: int  # training steps of a full epoch (len(train), capped by max_steps_per_epoch)


def build_loaders(config: TrainConfig, dist: DistInfo, train_frames: list[Frame], val_frames: list[Frame]) -> Loaders:
    """Datasets with their transforms, this rank's shard of each, and the loaders over them."""
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
    base: DistributedSampler[int] = DistributedSampler(
        train_ds, num_replicas=dist.world_size, rank=dist.rank, shuffle=True, seed=config.seed, drop_last=False
    )
    sampler = EpochSampler(base)
    common: dict[str, Any] = {"num_workers": config.num_workers, "pin_memory": dist.device.type == "cuda"}
    if config.num_workers > 0:
        common.update(
            prefetch_factor=config.prefetch_factor, persistent_workers=True, worker_init_fn=loader_worker_init
        )
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
    steps = len(train_loader)
    if config.max_steps_per_epoch is not None:
        steps = min(steps, config.max_steps_per_epoch)
    return Loaders(train_loader, sampler, val_loader, steps)
