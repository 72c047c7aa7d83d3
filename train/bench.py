"""`segmin bench train`: is the data pipeline ever the bottleneck?

Measures training images/s twice on the same model and batch size: (a) the model step alone
on one fixed batch already in memory, (b) the full pipeline (PNG decode, augmentation,
collation, loader workers) feeding the same step. The ratio b/a should be >= 0.9. It also times
(c) decode + augmentation alone in this process, which gives a load-independent bound: with
loading done serially the ratio would be 1 / (1 + a/c).
Without `--root` a small formatted-layout dataset of 320x240 PNGs is written to a temp folder.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch


def write_bench_dataset(root: Path, frames: int = 48, width: int = 320, height: int = 240, seed: int = 0) -> Path:
    """A synthetic formatted-layout domain: textured 'rows' of green blobs on soil and sky."""
    import cv2

    rng = np.random.default_rng(seed)
    base = root / "bench" / "bench_1"
    for n in range(1, frames + 1):
        image = np.empty((height, width, 3), np.uint8)
        image[: height // 3] = (200, 170, 120)  # sky, BGR
        image[height // 3 :] = (40, 70, 110)  # soil
        image = np.clip(image + rng.integers(-20, 20, image.shape), 0, 255).astype(np.uint8)
        mask = np.zeros((height, width), np.uint8)
        for _ in range(12):
            centre = (int(rng.integers(0, width)), int(rng.integers(height // 4, height)))
            axes = (int(rng.integers(8, 40)), int(rng.integers(10, 60)))
            cv2.ellipse(mask, centre, axes, 0, 0, 360, 255, -1)
        image[mask > 0] = (30, int(rng.integers(100, 180)), 40)
        for kind, name, data in (("images", f"Image{n:04d}.png", image), ("masks", f"Segmentation{n:04d}.png", mask)):
            path = base / kind / f"Image{n}" / name
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), data)
    return root


def _timed(fn, steps: int) -> float:
    start = time.perf_counter()
    fn(steps)
    return time.perf_counter() - start


def bench_train(
    root: str | Path | None = None,
    *,
    image_size: int = 224,
    batch_size: int = 8,
    threads: int = 2,
    steps: int = 6,
    warmup: int = 2,
    workers: int = 1,
    repeats: int = 2,
    device: str = "cpu",
) -> dict[str, Any]:
    """Images/s of the model step alone and of the full pipeline (best of `repeats`, alternating).

    The model step is timed in the channels-last layout training uses and, alternating with it, in the
    plain NCHW layout, so the layout's gain is a ratio measured under the same load.
    """
    import cv2
    from torch.utils.data import DataLoader, RandomSampler

    from segmin.data.agriseg_loader import AgriSegDataset
    from segmin.data.augment import train_transform
    from segmin.models import build_model
    from segmin.train.distributed import EpochSampler
    from segmin.train.loaders import loader_worker_init
    from segmin.train.loop import SegLoss, StepContext, train_step

    torch.set_num_threads(threads)
    cv2.setNumThreads(1)  # OpenCV's own thread pool would fight torch's threads for the cores
    torch.manual_seed(0)
    tmp = None
    if root is None:
        tmp = tempfile.TemporaryDirectory(prefix="segmin-bench-")
        root = write_bench_dataset(Path(tmp.name))
    try:
        dev = torch.device(device)
        dataset = AgriSegDataset(root, split="all", transform=train_transform(image_size), image_size=image_size)
        sampler = EpochSampler(
            RandomSampler(dataset, replacement=True, num_samples=10**6, generator=torch.Generator().manual_seed(0))
        )
        extra: dict[str, Any] = {}
        if workers > 0:
            extra = {"prefetch_factor": 4, "persistent_workers": True, "worker_init_fn": loader_worker_init}
        loader = DataLoader(
            dataset,
            batch_size=batch_size,
            sampler=sampler,
            num_workers=workers,
            pin_memory=dev.type == "cuda",
            drop_last=True,
            **extra,
        )

        def step_context(channels_last: bool) -> StepContext:
            model = build_model("none").to(dev)
            if channels_last:
                model.to(memory_format=torch.channels_last)
            return StepContext(
                model,
                torch.optim.Adam(model.parameters(), lr=3e-4),
                SegLoss(),
                dev,
                torch.amp.GradScaler("cuda") if amp else None,
                amp=amp,
                channels_last=channels_last,
            )

        amp = dev.type == "cuda"
        ctx, ctx_nchw = step_context(True), step_context(False)  # what training uses, and the plain layout
        batches = iter(loader)
        fixed = next(batches)

        def sync() -> None:
            if dev.type == "cuda":
                torch.cuda.synchronize()

        def model_only(n: int, context: StepContext | None = None) -> None:
            for _ in range(n):
                train_step(context or ctx, *fixed)
            sync()

        def model_only_nchw(n: int) -> None:
            model_only(n, ctx_nchw)

        def full(n: int) -> None:
            for _ in range(n):
                train_step(ctx, *next(batches))
            sync()

        def data_only(n: int) -> None:  # the same work the loader does, in this process
            for i in range(n * batch_size):
                dataset[(1, i % len(dataset))]

        model_only(warmup)
        model_only_nchw(warmup)
        full(warmup)
        t_model, t_nchw, t_full, t_data = [], [], [], []
        for _ in range(repeats):
            t_model.append(_timed(model_only, steps))
            t_nchw.append(_timed(model_only_nchw, steps))
            t_full.append(_timed(full, steps))
            t_data.append(_timed(data_only, steps))
        model_ips = steps * batch_size / min(t_model)
        nchw_ips = steps * batch_size / min(t_nchw)
        full_ips = steps * batch_size / min(t_full)
        data_ips = steps * batch_size / min(t_data)
        del batches
        return {
            "image_size": image_size,
            "batch_size": batch_size,
            "threads": threads,
            "workers": workers,
            "device": str(dev),
            "frames": len(dataset),
            "model_step_ips": model_ips,
            "model_step_nchw_ips": nchw_ips,
            "channels_last_speedup": model_ips / nchw_ips,
            "full_pipeline_ips": full_ips,
            "data_only_ips": data_ips,
            "ratio": full_ips / model_ips,
            # what the ratio would be if loading ran serially in the training process (workers=0)
            "serial_bound": 1.0 / (1.0 + model_ips / data_ips),
        }
    finally:
        if tmp is not None:
            tmp.cleanup()
