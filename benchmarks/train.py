"""`python -m benchmarks train`: is the data pipeline ever the bottleneck?

Measures training images/s twice on the same model and batch size: (a) the model step alone
on one fixed batch already in memory, (b) the full pipeline (PNG decode, augmentation,
collation, loader workers) feeding the same step. The ratio b/a is printed against `TARGETS`.
It also times (c) decode + augmentation alone in this process, which gives a load-independent
bound: with loading done serially the ratio would be 1 / (1 + a/c).
Without `--root` a small formatted-layout dataset of 320x240 PNGs is written to a temp folder.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from segmin.common.speed_targets import SpeedTarget
from segmin.train.loop import SegLoss, StepContext, train_step

TARGETS: tuple[SpeedTarget, ...] = (SpeedTarget("ratio", "full pipeline / model step", 0.9, at_least=True),)


@dataclass(frozen=True)
class TrainBenchOptions:
    """What `python -m benchmarks train` takes (benchmarks/cli.py has the command-line help)."""

    root: Path | None = None  # dataset root; None: a generated 320x240 PNG set
    image_size: int = 224
    batch_size: int = 8
    threads: int = 2
    steps: int = 6  # timed steps per measurement
    warmup: int = 2
    workers: int = 1  # loader worker processes
    repeats: int = 2  # measurements of each kind; the best counts
    device: str = "cpu"

    def __post_init__(self) -> None:
        # (field, its command-line spelling, least value)
        for name, flag, least in (
            ("image_size", "--size", 32),
            ("batch_size", "--batch", 1),
            ("threads", "--threads", 1),
            ("steps", "--steps", 1),
            ("warmup", "warmup", 0),
            ("workers", "--workers", 0),
            ("repeats", "--repeats", 1),
        ):
            if getattr(self, name) < least:
                raise ValueError(f"{flag} {getattr(self, name)}: must be >= {least}")


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


def bench_train(options: TrainBenchOptions) -> dict[str, Any]:
    """Images/s of the model step alone and of the full pipeline (best of `repeats`, alternating).

    The model step is timed in the channels-last layout training uses and, alternating with it, in the
    plain NCHW layout, so the layout's gain is a ratio measured under the same load.
    """
    import cv2

    torch.set_num_threads(options.threads)
    cv2.setNumThreads(1)  # OpenCV's own thread pool would fight torch's threads for the cores
    torch.manual_seed(0)
    with tempfile.TemporaryDirectory(prefix="segmin-bench-") as tmp:
        root = options.root if options.root is not None else write_bench_dataset(Path(tmp))
        timers = _Timers(root, options)
        timers.warm_up(options.warmup)
        seconds = timers.best_of(options.repeats, options.steps)
        timers.close()
        images = options.steps * options.batch_size
        ips = {name: images / s for name, s in seconds.items()}
        return {
            "image_size": options.image_size,
            "batch_size": options.batch_size,
            "threads": options.threads,
            "workers": options.workers,
            "device": str(timers.device),
            "frames": len(timers.dataset),
            "model_step_ips": ips["model"],
            "model_step_nchw_ips": ips["nchw"],
            "channels_last_speedup": ips["model"] / ips["nchw"],
            "full_pipeline_ips": ips["full"],
            "data_only_ips": ips["data"],
            "ratio": ips["full"] / ips["model"],
            # what the ratio would be if loading ran serially in the training process (workers=0)
            "serial_bound": 1.0 / (1.0 + ips["model"] / ips["data"]),
        }


class _Timers:
    """The four timed loops: the model step on one fixed batch (channels-last and NCHW), the same
    step fed by the loader, and the loader's work (decode + augment) alone in this process."""

    def __init__(self, root: Path, options: TrainBenchOptions) -> None:
        from segmin.data.agriseg_loader import AgriSegDataset
        from segmin.data.augment import train_transform

        self.device = torch.device(options.device)
        self.batch_size = options.batch_size
        self.dataset = AgriSegDataset(
            root, split="all", transform=train_transform(options.image_size), image_size=options.image_size
        )
        amp = self.device.type == "cuda"
        self.ctx = _step_context(self.device, channels_last=True, amp=amp)  # what training uses
        self.ctx_nchw = _step_context(self.device, channels_last=False, amp=amp)  # the plain layout
        self.batches = iter(_loader(self.dataset, options, self.device))
        self.fixed = next(self.batches)

    def _sync(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize()

    def model(self, n: int, ctx: StepContext | None = None) -> None:
        for _ in range(n):
            train_step(ctx or self.ctx, *self.fixed)
        self._sync()

    def nchw(self, n: int) -> None:
        self.model(n, self.ctx_nchw)

    def full(self, n: int) -> None:
        for _ in range(n):
            train_step(self.ctx, *next(self.batches))
        self._sync()

    def data(self, n: int) -> None:  # the same work the loader does, in this process
        for i in range(n * self.batch_size):
            self.dataset[(1, i % len(self.dataset))]

    def warm_up(self, steps: int) -> None:
        self.model(steps)
        self.nchw(steps)
        self.full(steps)

    def best_of(self, repeats: int, steps: int) -> dict[str, float]:
        """Shortest seconds of each loop over `repeats` alternating rounds (alike under changing load)."""
        loops: dict[str, Callable[[int], None]] = {
            "model": self.model,
            "nchw": self.nchw,
            "full": self.full,
            "data": self.data,
        }
        times: dict[str, list[float]] = {name: [] for name in loops}
        for _ in range(repeats):
            for name, loop in loops.items():
                start = time.perf_counter()
                loop(steps)
                times[name].append(time.perf_counter() - start)
        return {name: min(t) for name, t in times.items()}

    def close(self) -> None:
        """Stop the loader's worker processes (before the generated dataset is removed)."""
        del self.batches


def _step_context(device: torch.device, *, channels_last: bool, amp: bool) -> StepContext:
    from segmin.models import build_model

    model = build_model("none").to(device)
    if channels_last:
        model.to(memory_format=torch.channels_last)
    return StepContext(
        model,
        torch.optim.Adam(model.parameters(), lr=3e-4),
        SegLoss(),
        device,
        torch.amp.GradScaler("cuda") if amp else None,
        amp=amp,
        channels_last=channels_last,
    )


def _loader(dataset, options: TrainBenchOptions, device: torch.device):
    """An endless shuffled loader (sampling with replacement), as training's but never exhausted."""
    from torch.utils.data import DataLoader, RandomSampler

    from segmin.train.distributed import EpochSampler
    from segmin.train.loaders import loader_worker_init

    sampler = EpochSampler(
        RandomSampler(dataset, replacement=True, num_samples=10**6, generator=torch.Generator().manual_seed(0))
    )
    extra: dict[str, Any] = {}
    if options.workers > 0:
        extra = {"prefetch_factor": 4, "persistent_workers": True, "worker_init_fn": loader_worker_init}
    return DataLoader(
        dataset,
        batch_size=options.batch_size,
        sampler=sampler,
        num_workers=options.workers,
        pin_memory=device.type == "cuda",
        drop_last=True,
        **extra,
    )


def report_lines(r: dict[str, Any]) -> list[str]:
    """What `python -m benchmarks train` prints, the ratio against `TARGETS` included."""
    from segmin.common.machine import load_average

    return [
        f"train bench: {r['image_size']}x{r['image_size']}, batch {r['batch_size']}, {r['threads']} threads, "
        f"{r['workers']} loader worker(s), {r['device']}, {r['frames']} frames; {load_average()}",
        f"  model step alone : {r['model_step_ips']:7.2f} images/s (channels-last)",
        f"  same, plain NCHW : {r['model_step_nchw_ips']:7.2f} images/s; channels-last gain "
        f"{r['channels_last_speedup']:.2f}x",
        f"  full pipeline    : {r['full_pipeline_ips']:7.2f} images/s",
        f"  ratio            : {r['ratio']:.3f}",
        f"  data alone       : {r['data_only_ips']:7.2f} images/s (decode + augment, 1 process); "
        f"serial-loading bound {r['serial_bound']:.3f}",
        *(target.verdict(r[target.key]) for target in TARGETS),
    ]
