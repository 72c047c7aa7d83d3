"""Augmentation presets (albumentations 2.x) that keep image and mask aligned.

The paper's recipe: random square crop of 50-100 % of the side (25-100 % of the area) resized
back to the input size, horizontal flip p = 0.5, greyscale p = 0.1, brightness/contrast jitter
0.4, ImageNet normalisation. Geometric transforms act on image and mask together (the mask is
resampled with nearest neighbour, so it stays binary); colour transforms touch the image only.

A transform is called as `transform(image_rgb_uint8, mask_uint8, seed)`; a given seed always
gives the same augmentation, which is what makes `--resume` exact with any number of workers.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from segmin.data.model_input import IMAGENET_MEAN, IMAGENET_STD


@dataclass
class AugmentConfig:
    """Training augmentation; the defaults are the paper's recipe. `enabled: false` = eval only."""

    enabled: bool = True
    crop_scale: tuple[float, float] = (0.25, 1.0)  # area fraction: 50-100 % of the side
    crop_ratio: tuple[float, float] = (1.0, 1.0)  # square crops of the (resized) square frame
    hflip_p: float = 0.5
    gray_p: float = 0.1
    brightness: float = 0.4
    contrast: float = 0.4
    saturation: float = 0.0
    hue: float = 0.0
    jitter_p: float = 1.0

    def __post_init__(self) -> None:
        lo, hi = self.crop_scale
        if not 0 < lo <= hi <= 1:
            raise ValueError(f"crop_scale={self.crop_scale}: need 0 < low <= high <= 1")
        for name in ("hflip_p", "gray_p", "jitter_p"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be a probability in [0, 1]")
        for name in ("brightness", "contrast", "saturation"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be in [0, 1)")
        if not 0 <= self.hue <= 0.5:
            raise ValueError(f"hue={self.hue}: must be in [0, 0.5]")


class SegTransform:
    """An albumentations pipeline on (image, mask) returning normalised CHW tensors."""

    def __init__(self, transforms: Sequence[object]) -> None:
        import albumentations as A

        self.compose = A.Compose(list(transforms))

    def apply(self, image: np.ndarray, mask: np.ndarray, seed: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Augmented (float32 HxWx3 normalised image, uint8 HxW mask) as numpy arrays."""
        if seed is not None:
            # One shared generator for the whole pipeline, so the transforms draw independent numbers.
            self.compose.set_random_state(np.random.default_rng(seed), random.Random(seed))
        out = self.compose(image=image, mask=mask)
        return out["image"], out["mask"]

    def __call__(self, image: np.ndarray, mask: np.ndarray, seed: int | None = None):
        import torch

        image, mask = self.apply(image, mask, seed)
        x = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1), dtype=np.float32))
        y = torch.from_numpy(np.ascontiguousarray(mask, dtype=np.float32))[None]
        return x, y


def _size(image_size: int | Sequence[int]) -> tuple[int, int]:
    return (int(image_size), int(image_size)) if isinstance(image_size, int) else (int(image_size[0]), int(image_size[1]))


def eval_transform(image_size: int | Sequence[int]) -> SegTransform:
    """Resize to `image_size` (area for the image, nearest for the mask) and normalise."""
    import albumentations as A
    import cv2

    h, w = _size(image_size)
    return SegTransform([
        A.Resize(h, w, interpolation=cv2.INTER_AREA, mask_interpolation=cv2.INTER_NEAREST_EXACT),
        A.Normalize(mean=IMAGENET_MEAN, std=IMAGENET_STD),
    ])


def train_transform(image_size: int | Sequence[int], config: AugmentConfig | None = None) -> SegTransform:
    """The paper's training augmentation (see module docstring); `enabled=False` gives eval."""
    import albumentations as A
    import cv2

    config = config or AugmentConfig()
    if not config.enabled:
        return eval_transform(image_size)
    h, w = _size(image_size)
    steps: list[object] = [
        A.Resize(h, w, interpolation=cv2.INTER_AREA, mask_interpolation=cv2.INTER_NEAREST_EXACT),
        A.RandomResizedCrop(size=(h, w), scale=tuple(config.crop_scale), ratio=tuple(config.crop_ratio),
                            interpolation=cv2.INTER_LINEAR, mask_interpolation=cv2.INTER_NEAREST_EXACT, p=1.0),
    ]
    if config.hflip_p > 0:
        steps.append(A.HorizontalFlip(p=config.hflip_p))
    if config.gray_p > 0:
        steps.append(A.ToGray(num_output_channels=3, p=config.gray_p))
    if config.jitter_p > 0 and (config.brightness or config.contrast or config.saturation or config.hue):
        steps.append(A.ColorJitter(brightness=config.brightness, contrast=config.contrast,
                                   saturation=config.saturation, hue=config.hue, p=config.jitter_p))
    steps.append(A.Normalize(mean=IMAGENET_MEAN, std=IMAGENET_STD))
    return SegTransform(steps)


def denormalize(image: np.ndarray) -> np.ndarray:
    """CHW or HWC normalised float image -> RGB uint8 HxWx3 (for previews)."""
    if image.ndim == 3 and image.shape[0] == 3:
        image = image.transpose(1, 2, 0)
    rgb = image * np.asarray(IMAGENET_STD) + np.asarray(IMAGENET_MEAN)
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)
