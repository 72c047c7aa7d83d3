"""Photometric augmentation (light and camera effects): image only, seeded, validated."""

from __future__ import annotations

import numpy as np
import pytest

from segmin.data.augment import AugmentConfig, photometric_steps, train_transform

ALL_ON = dict(gamma_p=1.0, hsv_p=1.0, blur_p=1.0, noise_p=1.0, jpeg_p=1.0, shadow_p=1.0, flare_p=1.0)


def _sample():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (48, 48, 3), dtype=np.uint8)
    mask = (rng.uniform(size=(48, 48)) > 0.5).astype(np.uint8)
    return image, mask


def test_off_by_default_and_each_effect_can_be_switched_on():
    assert photometric_steps(AugmentConfig()) == []
    assert len(photometric_steps(AugmentConfig(**ALL_ON))) == len(ALL_ON)


def test_effects_touch_the_image_only_and_repeat_per_seed():
    image, mask = _sample()
    off = AugmentConfig(crop_scale=(1.0, 1.0), hflip_p=0.0, gray_p=0.0, brightness=0.0, contrast=0.0)
    on = AugmentConfig(crop_scale=(1.0, 1.0), hflip_p=0.0, gray_p=0.0, brightness=0.0, contrast=0.0, **ALL_ON)
    plain_img, plain_mask = train_transform(48, off).apply(image, mask, seed=3)
    t = train_transform(48, on)
    img_a, mask_a = t.apply(image, mask, seed=3)
    img_b, mask_b = t.apply(image, mask, seed=3)
    assert np.array_equal(mask_a, plain_mask) and np.array_equal(mask_a, mask)
    assert not np.allclose(img_a, plain_img)
    assert np.array_equal(img_a, img_b) and np.array_equal(mask_a, mask_b)


@pytest.mark.parametrize(
    "changes",
    [
        {"blur_p": 1.5},
        {"gamma": (0.0, 120.0)},
        {"noise_std": (0.2, 0.1)},
        {"jpeg_quality": (0, 90)},
        {"blur_limit": 1},
        {"hue_shift": -1.0},
    ],
)
def test_invalid_settings_are_rejected(changes):
    with pytest.raises(ValueError):
        AugmentConfig(**changes)
