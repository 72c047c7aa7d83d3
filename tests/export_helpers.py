"""Builders for the export and segmenter tests: a tiny trained checkpoint and toy frames (conftest shares them).

The checkpoint is LR-ASPP MobileNetV3 with random init trained for a few Adam steps on synthetic
64 x 64 "field" images (green row bands on soil under a sky), so its probabilities are spread out
and depend on the image content: a round trip that broke the normalisation or the channel order
would show up as large differences, which a constant-output random model could hide.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from segmin.data.model_input import IMAGENET_MEAN, IMAGENET_STD

SIZE = 64


def field_image(rng: np.random.Generator, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 H x W x 3, mask bool H x W) of a toy crop-row frame."""
    image = np.zeros((height, width, 3), np.float32)
    horizon = int(height * rng.uniform(0.2, 0.4))
    image[:horizon] = (150, 190, 235)
    image[horizon:] = (120, 95, 70)
    mask = np.zeros((height, width), bool)
    cols = np.arange(width)
    for centre in (width * rng.uniform(0.1, 0.35), width * rng.uniform(0.65, 0.9)):
        band = np.abs(cols - centre) < width * rng.uniform(0.08, 0.18)
        mask[horizon // 2 :, band] = True
    image[mask] = (40, 140, 35)
    image += rng.normal(0, 10, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8), mask


def make_checkpoint(
    path: Path,
    steps: int = 4,
    size: int = SIZE,
    threshold: float = 0.5,
    architecture: str = "lraspp_mobilenet_v3_large",
) -> Path:
    """A few Adam steps of build_model("none", architecture=...) on toy frames, saved with models.checkpoint.

    BatchNorm stays in eval mode while training: with a handful of steps its running statistics
    would not settle, and the eval-mode output would then be nearly constant.
    """
    import torch

    from segmin.models import build_model
    from segmin.models.checkpoint import model_info, save_checkpoint

    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = build_model("none", architecture=architecture)
    mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
    optimizer = torch.optim.Adam(model.parameters(), lr=5e-3)
    model.eval()
    for _ in range(steps):
        pairs = [field_image(rng, size, size) for _ in range(4)]
        images = torch.from_numpy(np.stack([p[0] for p in pairs])).permute(0, 3, 1, 2).float() / 255.0
        masks = torch.from_numpy(np.stack([p[1] for p in pairs])).float()[:, None]
        loss = torch.nn.functional.binary_cross_entropy_with_logits(model((images - mean) / std), masks)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    model.eval()
    info = model_info(
        backbone_weights="none",
        input_size=(size, size),
        family="vineyards",
        train_data="toy",
        threshold=threshold,
        architecture=architecture,
    )
    save_checkpoint(path, {"model": model.state_dict(), "model_info": info, "epoch": 0, "metrics": {}})
    return path


def write_frames(folder: Path, count: int = 6, height: int = 72, width: int = 96, seed: int = 1) -> Path:
    """`count` toy frames as PNG/JPG files (sizes differ from the model size, so they get resized)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for i in range(count):
        image, _ = field_image(rng, height, width)
        suffix = ".jpg" if i % 3 == 2 else ".png"
        cv2.imwrite(str(folder / f"frame{i}{suffix}"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return folder
