"""What a camera frame becomes before the network sees it: the model-input size rule and ImageNet stats.

Training, export verification and the robot-side `OnnxSegmenter` must prepare frames the same
way, or the verified agreement says nothing about the robot: this module is that one way.
No torch here: the robot runtime imports it.
"""

from __future__ import annotations

import numpy as np

# The backbone's ImageNet statistics (RGB, on 0..1 values); the ONNX graph folds them in.
IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)
# MobileNetV3's overall stride. Training takes only input sides that are multiples of it, so a model
# is never known to work at any other side.
INPUT_STRIDE = 32


def check_input_side(side: int, name: str) -> None:
    """Refuse, in one line naming `name`, a side no model trains at (training's image_size, eval-seg's --size)."""
    if side < INPUT_STRIDE or side % INPUT_STRIDE:
        raise ValueError(f"{name}={side}: must be a positive multiple of {INPUT_STRIDE} (MobileNetV3 stride)")


def resize_to_input(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """`image` at the model input `size` (height, width); returned as is when already that size.

    INTER_AREA when shrinking in both directions (it averages, so thin rows do not alias away),
    INTER_LINEAR otherwise.
    """
    import cv2

    height, width = size
    if image.shape[:2] == (height, width):
        return image
    shrinking = image.shape[0] >= height and image.shape[1] >= width
    interp = cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR
    return cv2.resize(image, (width, height), interpolation=interp)
