"""The torch Dataset of (image, mask) tensors; the only data module that imports torch.

Scanning, reading and splitting live in torch-free modules so the robot runtime can use them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from torch.utils.data import Dataset

from segmin.common.mask_closing import canopy_region, check_closing_radius
from segmin.data.domains import find_frames
from segmin.data.frames import DatasetError, Frame
from segmin.data.readers import load_frame
from segmin.data.splits import load_split, make_splits, save_split


class AgriSegDataset(Dataset):
    """(image float 3xHxW ImageNet-normalised, mask float 1xHxW of 0/1) samples.

    `domains`: families, domain names, globs or prefixes (see `resolve_domains`); None = all.
    `split`: "train", "val" or "all"; splits are seeded per domain (`make_splits`), or read from
    `split_file` when given (exact reproduction of an earlier run).
    `label_closing`: radius in px of the canopy-region label (`data.canopy_region`; 0 = exact).
    `transform`: a `data.augment.SegTransform` (or any callable `(image, mask, seed) -> (x, y)`);
    default: resize to `image_size` and normalise.
    An index may be an int or `(epoch, int)`: with the tuple the augmentation is seeded from
    (`seed`, epoch, index), so a run and its resume see exactly the same samples whatever the
    number of loader workers.
    """

    def __init__(
        self,
        root: str | Path,
        domains: Sequence[str] | str | None = None,
        split: str = "train",
        val_fraction: float = 0.1,
        seed: int = 0,
        transform: Callable[..., tuple[Any, Any]] | None = None,
        image_size: int | tuple[int, int] = 224,
        *,
        skip_unpaired: bool = False,
        split_file: str | Path | None = None,
        frames: Sequence[Frame] | None = None,
        label_closing: int = 0,
    ) -> None:
        if split not in ("train", "val", "all"):
            raise ValueError(f"split={split!r}: expected 'train', 'val' or 'all'")
        self.root = Path(root)
        all_frames = list(frames) if frames is not None else find_frames(root, domains, skip_unpaired=skip_unpaired)
        if not all_frames:
            raise DatasetError(f"{root}: no frames for domains {domains}")
        if split_file is not None:
            self.splits = load_split(split_file, all_frames)
        else:
            self.splits = make_splits(all_frames, val_fraction, seed)
        self.frames: list[Frame] = list(all_frames) if split == "all" else self.splits[split]
        if not self.frames:
            raise DatasetError(
                f"{root}: split {split!r} is empty (val_fraction={val_fraction}, {len(all_frames)} frames)"
            )
        self.split = split
        self.seed = seed
        self.image_size = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
        if len(self.image_size) != 2 or not all(isinstance(v, int) and v >= 1 for v in self.image_size):
            raise ValueError(f"image_size={image_size!r}: expected a side or (height, width) of integers >= 1")
        if transform is None:
            from segmin.data.augment import eval_transform

            transform = eval_transform(self.image_size)
        self.transform = transform
        self.label_closing = check_closing_radius(label_closing)  # now, not at the first sample

    def __len__(self) -> int:
        return len(self.frames)

    def save_split(self, path: str | Path) -> None:
        save_split(path, self.splits, seed=self.seed)

    def sample_seed(self, epoch: int, index: int) -> int:
        return int(np.random.SeedSequence([self.seed, epoch, index]).generate_state(1)[0])

    def __getitem__(self, item: int | tuple[int, int]):
        if isinstance(item, tuple):
            epoch, index = item
            seed: int | None = self.sample_seed(epoch, index)
        else:
            index, seed = item, None
        image, mask = load_frame(self.frames[index])
        return self.transform(image, canopy_region(mask, self.label_closing), seed)
