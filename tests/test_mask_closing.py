"""The canopy region for any segmenter (nav_eval.sim.mask_closing): the oracle as a perfect model
of the label the networks learn."""

from __future__ import annotations

import types

import numpy as np
import pytest

from segmin.data.canopy_region import canopy_region
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
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="perception.mask_closing"):
            Perception(mask_closing=bad)
