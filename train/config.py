"""Training configuration: one YAML file per crop family in configs/train/ (strict keys).

Defaults are the paper's recipe: Adam lr 3e-4, 50 epochs, 224 x 224, batch 64, BCE on one
logit channel, flip / square crop / greyscale / colour jitter, ImageNet backbone. Dice term and
LR schedule exist but are off by default.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from segmin.common.config import load_config
from segmin.common.mask_closing import check_closing_radius
from segmin.data.augment import AugmentConfig
from segmin.data.model_input import check_input_side
from segmin.data.real_sets import check_not_real_data
from segmin.models.architectures import check_architecture

_DEVICE = re.compile(r"auto|cpu|cuda(:\d+)?")


@dataclass
class DataConfig:
    """Where frames come from. `domains` are families, domain names, globs or prefixes.

    Validation is either a seeded split per domain (`val_fraction`, `split_seed`, or a saved
    `split_file`), or, when `val_domains` is set, all frames of those domains under `val_root`
    (default: `root`); then every training-domain frame trains. The second is how rendered
    frames are evaluated on held-out worlds.
    """

    root: Path = Path("data/agriseg")
    domains: list[str] | None = None
    val_root: Path | None = None
    val_domains: list[str] | None = None
    val_fraction: float = 0.1
    split_seed: int = 0
    split_file: Path | None = None
    skip_unpaired: bool = False
    max_train_frames: int | None = None  # subsample (seeded) for quick demos
    max_val_frames: int | None = None
    # Canopy-region label: close the gaps between leaves with a disc of this radius in px of the
    # stored frames, in training and validation masks (data/canopy_region.py); 0 = exact masks.
    label_closing: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"data.val_fraction={self.val_fraction}: must be in [0, 1)")
        for name in ("max_train_frames", "max_val_frames"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"data.{name}={value}: must be >= 1 or null")
        check_closing_radius(self.label_closing, "data.label_closing")
        # The shipped real photos are a test set: no training config may read them.
        check_not_real_data(
            "training data",
            paths={"data.root": self.root, "data.val_root": self.val_root},
            names={"data.domains": self.domains, "data.val_domains": self.val_domains},
        )


@dataclass
class TrainConfig:
    family: str = "custom"
    data: DataConfig = field(default_factory=DataConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    backbone_weights: str = "imagenet"  # "imagenet", "none" or a state-dict path
    # The network (models.lraspp.ARCHITECTURES): torchvision's full LR-ASPP MobileNetV3-Large, or
    # the backbone cut after an earlier block (`..._cut13` is the paper's cut: 1.3 M parameters,
    # about 0.6x the full network's time a frame on 2 CPU cores; `python -m benchmarks architectures`).
    architecture: str = "lraspp_mobilenet_v3_large"
    image_size: int = 224
    epochs: int = 50
    batch_size: int = 64  # paper: 64 (per process under torchrun); lower it on small GPUs / CPU
    lr: float = 3e-4
    weight_decay: float = 0.0
    dice_weight: float = 0.0  # loss = BCE + dice_weight * soft Dice
    schedule: Literal["none", "cosine", "step"] = "none"
    step_size: int = 20  # epochs, for schedule=step
    gamma: float = 0.1
    threshold: float = 0.5
    # BatchNorm momentum for training; null keeps torchvision's (0.01 in the MobileNetV3 backbone,
    # tuned for ImageNet-length runs). From random init, 0.1 lets the running statistics catch up
    # within an epoch instead of leaving eval-mode predictions off for the first few epochs.
    bn_momentum: float | None = None
    # Stochastic weight averaging (Izmailov et al. 2018, torch.optim.swa_utils): from this epoch
    # (1-based) on, the weights at every epoch end are averaged; after the last epoch the average
    # gets BatchNorm statistics recomputed over the training frames, is validated and saved as
    # swa.pt, and is the run's result instead of best.pt. Why: with a constant LR the weights
    # wander between epochs, and the rendered validation IoU does not tell which epoch transfers
    # to real photos (docs/sim_to_real.md). null = off (the paper keeps the best epoch).
    swa_start_epoch: int | None = None
    seed: int = 0
    device: str = "auto"  # "auto", "cpu", "cuda", "cuda:N"
    amp: bool = True  # GPU only
    channels_last: bool = True  # every device: on CPUs the model step ran 1.4x faster (python -m benchmarks train)
    threads: int | None = None  # torch CPU threads (None = torch's default)
    num_workers: int = 2
    prefetch_factor: int = 2
    max_steps_per_epoch: int | None = None
    # Mid-epoch checkpoints (last.pt, resumable): every N steps and/or every M minutes of
    # training, so a kill -9 during a long (first) epoch loses at most that much work. Ctrl-C and
    # epoch ends always save. null turns either trigger off.
    checkpoint_every_steps: int | None = None
    checkpoint_every_minutes: float | None = 10.0
    eval_batch_size: int | None = None
    preview_images: int = 4
    tensorboard: bool = True
    progress: bool = True

    def __post_init__(self) -> None:
        positive = ("image_size", "epochs", "batch_size", "step_size", "prefetch_factor")
        for name in positive:
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")
        check_input_side(self.image_size, "image_size")
        check_architecture(self.architecture)
        if self.lr <= 0:
            raise ValueError(f"lr={self.lr}: must be > 0")
        if self.dice_weight < 0:
            raise ValueError(f"dice_weight={self.dice_weight}: must be >= 0")
        if self.bn_momentum is not None and not 0 < self.bn_momentum <= 1:
            raise ValueError(f"bn_momentum={self.bn_momentum}: must be in (0, 1] or null")
        if self.swa_start_epoch is not None and not 1 <= self.swa_start_epoch <= self.epochs:
            raise ValueError(f"swa_start_epoch={self.swa_start_epoch}: must be in [1, epochs={self.epochs}] or null")
        if not 0 < self.threshold < 1:
            raise ValueError(f"threshold={self.threshold}: must be in (0, 1)")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads={self.threads}: must be >= 1 or null (torch's default)")
        if not _DEVICE.fullmatch(self.device):
            raise ValueError(f"device={self.device!r}: expected auto, cpu, cuda or cuda:N")
        if self.num_workers < 0:
            raise ValueError(f"num_workers={self.num_workers}: must be >= 0")
        if self.checkpoint_every_steps is not None and self.checkpoint_every_steps < 1:
            raise ValueError(f"checkpoint_every_steps={self.checkpoint_every_steps}: must be >= 1 or null")
        if self.checkpoint_every_minutes is not None and not self.checkpoint_every_minutes > 0:
            raise ValueError(f"checkpoint_every_minutes={self.checkpoint_every_minutes}: must be > 0 or null")
        if self.max_steps_per_epoch is not None and self.max_steps_per_epoch < 1:
            raise ValueError(f"max_steps_per_epoch={self.max_steps_per_epoch}: must be >= 1 or null")


def load_train_config(path: str | Path | None, overrides: list[str] | tuple[str, ...] = ()) -> TrainConfig:
    """Load a training config (a shipped name such as `vineyards`, or a YAML path) plus `key=value` overrides."""
    from segmin.common.shipped import resolve_config

    return load_config(TrainConfig, None if path is None else resolve_config("train", path), overrides)
