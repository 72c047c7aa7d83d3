"""Masks closed before a navigator sees them: in the simulator for any segmenter
(nav_eval.sim.mask_closing, the oracle as a perfect model of the label the networks learn) and in
the robot runtime's navigator (NavigatorConfig.mask_closing)."""

from __future__ import annotations

import types

import numpy as np
import pytest

from segmin.common.config import ConfigError
from segmin.data.canopy_region import canopy_region
from segmin.nav_eval.runtime.mask_closing import close_mask
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from segmin.nav_eval.sim.config import Perception, load_nav_config
from segmin.nav_eval.sim.mask_closing import ClosedMasks, with_closing
from segmin.nav_eval.sim.oracle import OracleSegmenter


def _crown_with_branch_gap() -> types.SimpleNamespace:
    """A crown split by a 3 px bare branch, and a 40 px free corridor beside it."""
    mask = np.zeros((64, 160), dtype=bool)
    mask[5:50, 10:80] = True
    mask[5:50, 44:47] = False  # the branch: exact mask 0, canopy region 1
    mask[5:50, 120:150] = True  # the next row, beyond a 40 px corridor
    return types.SimpleNamespace(rgb=None, depth=None, mask=mask)


def test_closed_masks_fill_the_branch_and_keep_the_corridor() -> None:
    frame = _crown_with_branch_gap()
    closed = ClosedMasks(OracleSegmenter(), 4).segment_frame(frame)
    assert closed.dtype == bool
    assert closed[10:45, 44:47].all()  # the branch is canopy now, as in the training label
    assert not frame.mask[10:45, 44:47].any()
    assert not closed[:, 85:115].any()  # the corridor stays free
    np.testing.assert_array_equal(closed, canopy_region(frame.mask, 4))


def test_the_split_call_closes_too() -> None:
    """nav-eval segments through prepare_frame (a model on a helper thread): closed the same way."""
    frame = _crown_with_branch_gap()
    wrapped = ClosedMasks(OracleSegmenter(), 4)
    np.testing.assert_array_equal(wrapped.prepare_frame(frame)(), wrapped.segment_frame(frame))


def test_the_perception_config_decides_and_checks_the_radius() -> None:
    oracle = OracleSegmenter()
    assert with_closing(oracle, Perception()) is oracle
    wrapped = with_closing(oracle, Perception(mask_closing=4))
    assert isinstance(wrapped, ClosedMasks) and wrapped.radius == 4 and not wrapped.reads_colour
    assert load_nav_config(overrides=["perception.mask_closing=2"]).perception.mask_closing == 2
    for bad in (-1, 1.5, True, 113):
        with pytest.raises(ValueError, match="perception.mask_closing"):
            Perception(mask_closing=bad)
    # Bounded when the config loads: 1000000 passed the check and every run then ran out of memory.
    with pytest.raises(ConfigError, match=r"perception\.mask_closing must be an integer from 0 to 112 px, got 1000000"):
        load_nav_config(overrides=["perception.mask_closing=1000000"])


def _navigator(mask_closing: int) -> Navigator:
    return Navigator(NavigatorConfig(method="segmin", depth_threshold=5.0, smooth_window=1, mask_closing=mask_closing))


def _rows_with_branch_gap(scale: int = 1) -> np.ndarray:
    """Two rows 224 x `scale` px wide reaching the image borders, 40 x `scale` px of corridor
    between them, the left crown split by a bare branch 3 x `scale` px wide."""
    mask = np.zeros((64 * scale, 224 * scale), dtype=bool)
    mask[5 * scale : 50 * scale] = True
    mask[:, 110 * scale : 150 * scale] = False  # the corridor
    mask[5 * scale : 50 * scale, 54 * scale : 57 * scale] = False  # the branch
    return mask


def test_the_navigator_steers_past_a_bare_branch_when_it_closes_the_masks() -> None:
    """The branch's empty columns tie with the corridor's as the histogram minimum (SegMin takes
    the mean of tied columns): closed, only the corridor is free."""
    mask = _rows_with_branch_gap()
    depth = np.full(mask.shape, 2.0, dtype=np.float32)
    # Without: the mean of the branch's 3 columns and the corridor's 40, pulled towards the crown.
    assert _navigator(0).step(mask, depth).target_column == pytest.approx((3 * 55 + 40 * 129.5) / 43)
    assert _navigator(4).step(mask, depth).target_column == pytest.approx(129.5)  # the corridor's centre


def test_the_navigator_closes_each_mask_before_the_fusion_as_the_simulator_does() -> None:
    """At the simulator's 224 px, NavigatorConfig.mask_closing gives the commands of masks closed
    by perception.mask_closing."""
    rng = np.random.default_rng(0)
    depth = np.full((64, 224), 2.0, dtype=np.float32)
    closing, closed_before = _navigator(4), _navigator(0)
    for shift in range(5):
        mask = np.roll(_rows_with_branch_gap(), 3 * shift, axis=1) & (rng.random((64, 224)) > 0.1)
        by_navigator = closing.step(mask, depth)
        by_simulator = closed_before.step(canopy_region(mask, 4), depth)
        assert (by_navigator.v, by_navigator.omega) == (by_simulator.v, by_simulator.omega)
        np.testing.assert_array_equal(closing.fused_mask(), closed_before.fused_mask())
    for bad in (-1, 2.0, False, 100000):
        with pytest.raises(ValueError, match="^mask_closing must be an integer from 0 to 112 px"):
            NavigatorConfig(method="segmind", depth_threshold=5.0, mask_closing=bad)
    assert NavigatorConfig(method="segmind", depth_threshold=5.0, mask_closing=112).mask_closing == 112


@pytest.mark.parametrize("scale", [2, 3])
def test_the_radius_means_the_same_on_a_wider_camera(scale: int) -> None:
    """The same scene at 448 or 672 px: the same radius fills the branch, keeps the corridor and
    removes no vegetation, as at 224 px (the radius is in px at 224 px of width)."""
    mask = _rows_with_branch_gap(scale)
    closed = close_mask(mask, 4)
    assert closed[10 * scale : 45 * scale, 54 * scale : 57 * scale].all()  # the branch is filled
    assert not closed[:, 110 * scale : 150 * scale].any()  # the corridor stays free
    assert (closed >= mask).all()
    depth = np.full(mask.shape, 2.0, dtype=np.float32)
    assert _navigator(4).step(mask, depth).target_column == pytest.approx(130 * scale - 0.5)  # the corridor's centre


def test_every_closing_is_the_one_in_common() -> None:
    """The label, the simulator and the navigator close with one implementation (and one bound):
    the old import paths give the very same functions."""
    from segmin.common import mask_closing as common
    from segmin.data import canopy_region as label
    from segmin.nav_eval.runtime import mask_closing as runtime
    from segmin.nav_eval.sim import mask_closing as sim

    assert label.canopy_region is common.canopy_region is sim.canopy_region
    assert label.check_closing_radius is common.check_closing_radius
    assert label.MAX_CLOSING_RADIUS == common.MAX_CLOSING_RADIUS == 112
    assert runtime.close_mask is common.close_mask and runtime.REFERENCE_WIDTH == 224
