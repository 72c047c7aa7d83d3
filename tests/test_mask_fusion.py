"""The mask window every navigator keeps (nav_eval.runtime.mask_fusion): the OR of the last N
masks, stale ones left out by stamp, and the same window in the paper's navigator and SegCorridor."""

from __future__ import annotations

import numpy as np
import pytest

from segmin.nav_eval.runtime.corridor import CorridorConfig, CorridorNavigator
from segmin.nav_eval.runtime.mask_fusion import MaskFusion, validated_mask
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from tests.test_corridor import SIZE, scene_camera


def _masks(count: int, shape: tuple[int, int] = (4, 6)) -> list[np.ndarray]:
    """Masks with one vegetation pixel each, in a different place: the OR shows which are fused."""
    masks = []
    for k in range(count):
        mask = np.zeros(shape, dtype=bool)
        mask.flat[k] = True
        masks.append(mask)
    return masks


def test_the_window_is_the_or_of_the_last_n_masks() -> None:
    fusion = MaskFusion(3)
    assert fusion.fused() is None
    masks = _masks(5)
    for k, mask in enumerate(masks):
        fusion.push(mask, stamp=0.1 * k)
    np.testing.assert_array_equal(fusion.fused(), masks[2] | masks[3] | masks[4])
    np.testing.assert_array_equal(fusion.fused(not_before=0.35), masks[4])  # stale ones left out
    assert fusion.fused(not_before=1.0) is None
    fusion.push(np.ones((2, 2), dtype=bool))  # another size: a new window
    np.testing.assert_array_equal(fusion.fused(), np.ones((2, 2), dtype=bool))
    fusion.reset()
    assert fusion.fused() is None


def test_a_probability_map_is_refused() -> None:
    with pytest.raises(ValueError, match="probability map"):
        validated_mask(np.full((2, 2), 0.7))
    np.testing.assert_array_equal(validated_mask(np.array([[0, 255]], np.uint8)), [[False, True]])


def test_both_navigators_fuse_the_same_window() -> None:
    """SegCorridor keeps the paper's window (its fallback is SegMinD on the same fused mask)."""
    paper = Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0, fuse_frames=2))
    corridor = CorridorNavigator(CorridorConfig(depth_threshold=5.0, fuse_frames=2), scene_camera())
    for k, mask in enumerate(_masks(4, (SIZE, SIZE))):
        paper.push_mask(mask, stamp=k)
        corridor.push_mask(mask.astype(np.uint8), stamp=k)
        np.testing.assert_array_equal(corridor.fused_mask(), paper.fused_mask())
        np.testing.assert_array_equal(corridor.fused_mask(not_before=k), paper.fused_mask(not_before=k))
