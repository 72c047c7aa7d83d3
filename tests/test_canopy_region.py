"""The canopy-region label (data.canopy_region): gaps between leaves close, open space stays."""

from __future__ import annotations

import numpy as np
import pytest

from segmin.data.canopy_region import canopy_region


def test_a_narrow_gap_between_leaves_closes_and_the_corridor_stays_open():
    mask = np.zeros((40, 60), np.uint8)
    mask[10:30, 0:20] = 1  # left canopy with a 3 px slit of sky
    mask[10:30, 9:12] = 0
    mask[10:30, 40:60] = 1  # right canopy; 20 px of free corridor between them
    closed = canopy_region(mask, 3)
    assert closed[12:28, 9:12].all()  # the slit is canopy now (its open ends round off)
    assert not closed[10:30, 22:38].any()  # the corridor is not
    assert not closed[:8].any() and not closed[32:].any()  # nothing grows above or below
    assert closed.dtype == mask.dtype and closed.shape == mask.shape
    assert (closed >= mask).all()  # closing never removes canopy


def test_vegetation_at_the_frame_edge_is_not_eaten_and_zero_keeps_the_mask():
    mask = np.zeros((20, 20), bool)
    mask[:, :4] = True
    assert np.array_equal(canopy_region(mask, 5), mask)
    assert canopy_region(mask, 0) is mask


@pytest.mark.parametrize("bad", [-1, 2.5, True, "3", 113, 100000])
def test_a_bad_radius_is_refused(bad):
    with pytest.raises(ValueError, match="label closing radius"):
        canopy_region(np.zeros((4, 4), np.uint8), bad)


def test_the_training_config_refuses_a_bad_label_closing():
    from segmin.train.config import DataConfig

    with pytest.raises(ValueError, match="data.label_closing"):
        DataConfig(label_closing=-2)
