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
from collections.abc import Sequence
from dataclasses import dataclass

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
    # Photometric camera/light effects (off in the paper's recipe; on in the synth configs, where
    # rendered frames lack the real camera's gamma, colour cast, blur, noise, JPEG and shadows).
    gamma_p: float = 0.0
    gamma: tuple[float, float] = (70.0, 150.0)  # albumentations gamma limits, percent
    hsv_p: float = 0.0
    hue_shift: float = 8.0  # degrees-ish (OpenCV hue units)
    sat_shift: float = 30.0
    val_shift: float = 20.0
    blur_p: float = 0.0  # Gaussian, motion or defocus blur
    blur_limit: int = 5
    noise_p: float = 0.0  # Gaussian or ISO sensor noise
    noise_std: tuple[float, float] = (0.02, 0.08)  # fraction of the full range
    jpeg_p: float = 0.0
    jpeg_quality: tuple[int, int] = (30, 95)
    shadow_p: float = 0.0  # random dark polygons (cast shadows)
    fog_p: float = 0.0  # slow (~0.2 s a frame at 224 px)
    flare_p: float = 0.0

    def __post_init__(self) -> None:
        lo, hi = self.crop_scale
        if not 0 < lo <= hi <= 1:
            raise ValueError(f"crop_scale={self.crop_scale}: need 0 < low <= high <= 1")
        if not 0 < self.crop_ratio[0] <= self.crop_ratio[1]:
            raise ValueError(f"crop_ratio={self.crop_ratio}: need 0 < low <= high (width / height)")
        for name in (
            "hflip_p",
            "gray_p",
            "jitter_p",
            "gamma_p",
            "hsv_p",
            "blur_p",
            "noise_p",
            "jpeg_p",
            "shadow_p",
            "fog_p",
            "flare_p",
        ):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be a probability in [0, 1]")
        for name in ("brightness", "contrast", "saturation"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be in [0, 1)")
        if not 0 <= self.hue <= 0.5:
            raise ValueError(f"hue={self.hue}: must be in [0, 0.5]")
        if not 0 < self.gamma[0] <= self.gamma[1]:
            raise ValueError(f"gamma={self.gamma}: need 0 < low <= high (percent)")
        if not 0 <= self.noise_std[0] <= self.noise_std[1] <= 1:
            raise ValueError(f"noise_std={self.noise_std}: need 0 <= low <= high <= 1")
        if not 1 <= self.jpeg_quality[0] <= self.jpeg_quality[1] <= 100:
            raise ValueError(f"jpeg_quality={self.jpeg_quality}: need 1 <= low <= high <= 100")
        if self.blur_limit < 3:
            raise ValueError(f"blur_limit={self.blur_limit}: must be >= 3 (kernel size)")
        for name in ("hue_shift", "sat_shift", "val_shift"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 0")


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
    return (
        (int(image_size), int(image_size)) if isinstance(image_size, int) else (int(image_size[0]), int(image_size[1]))
    )


def eval_transform(image_size: int | Sequence[int]) -> SegTransform:
    """Resize to `image_size` (area for the image, nearest for the mask) and normalise."""
    import albumentations as A
    import cv2

    h, w = _size(image_size)
    return SegTransform(
        [
            A.Resize(h, w, interpolation=cv2.INTER_AREA, mask_interpolation=cv2.INTER_NEAREST_EXACT),
            A.Normalize(mean=IMAGENET_MEAN, std=IMAGENET_STD),
        ]
    )


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
        A.RandomResizedCrop(
            size=(h, w),
            scale=tuple(config.crop_scale),
            ratio=tuple(config.crop_ratio),
            interpolation=cv2.INTER_LINEAR,
            mask_interpolation=cv2.INTER_NEAREST_EXACT,
            p=1.0,
        ),
    ]
    if config.hflip_p > 0:
        steps.append(A.HorizontalFlip(p=config.hflip_p))
    if config.gray_p > 0:
        steps.append(A.ToGray(num_output_channels=3, p=config.gray_p))
    if config.jitter_p > 0 and (config.brightness or config.contrast or config.saturation or config.hue):
        steps.append(
            A.ColorJitter(
                brightness=config.brightness,
                contrast=config.contrast,
                saturation=config.saturation,
                hue=config.hue,
                p=config.jitter_p,
            )
        )
    steps += photometric_steps(config)
    steps.append(A.Normalize(mean=IMAGENET_MEAN, std=IMAGENET_STD))
    return SegTransform(steps)


def photometric_steps(config: AugmentConfig) -> list[object]:
    """Image-only light and camera effects (the mask is untouched): each is skipped at p = 0."""
    import albumentations as A

    c = config
    odd = c.blur_limit | 1
    steps: list[object] = []
    if c.shadow_p > 0:  # before the camera effects: a shadow is part of the scene
        steps.append(
            A.RandomShadow(
                shadow_roi=(0, 0.3, 1, 1), num_shadows_limit=(1, 3), shadow_intensity_range=(0.3, 0.7), p=c.shadow_p
            )
        )
    if c.fog_p > 0:
        steps.append(A.RandomFog(fog_coef_range=(0.05, 0.3), alpha_coef=0.08, p=c.fog_p))
    if c.flare_p > 0:
        steps.append(A.RandomSunFlare(flare_roi=(0, 0, 1, 0.45), src_radius=60, p=c.flare_p))
    if c.gamma_p > 0:
        steps.append(A.RandomGamma(gamma_limit=tuple(c.gamma), p=c.gamma_p))
    if c.hsv_p > 0:
        steps.append(
            A.HueSaturationValue(
                hue_shift_limit=c.hue_shift, sat_shift_limit=c.sat_shift, val_shift_limit=c.val_shift, p=c.hsv_p
            )
        )
    if c.blur_p > 0:
        steps.append(
            A.OneOf(
                [
                    A.GaussianBlur(blur_limit=(3, odd), sigma_limit=(0.3, 1.5)),
                    A.MotionBlur(blur_limit=(3, odd)),
                    A.Defocus(radius=(1, max(2, odd // 2)), alias_blur=(0.1, 0.3)),
                ],
                p=c.blur_p,
            )
        )
    if c.noise_p > 0:
        steps.append(
            A.OneOf(
                [
                    A.GaussNoise(std_range=tuple(c.noise_std)),
                    A.ISONoise(color_shift=(0.01, 0.05), intensity=(0.1, 0.5)),
                ],
                p=c.noise_p,
            )
        )
    if c.jpeg_p > 0:
        steps.append(A.ImageCompression(quality_range=tuple(c.jpeg_quality), p=c.jpeg_p))
    return steps


def denormalize(image: np.ndarray) -> np.ndarray:
    """CHW or HWC normalised float image -> RGB uint8 HxWx3 (for previews)."""
    if image.ndim == 3 and image.shape[0] == 3:
        image = image.transpose(1, 2, 0)
    rgb = image * np.asarray(IMAGENET_STD) + np.asarray(IMAGENET_MEAN)
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)
