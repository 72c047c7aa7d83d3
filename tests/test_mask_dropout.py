"""The simulated weaker segmenter (nav_eval.mask_dropout): seeded, corrupts the share it is asked to."""

from __future__ import annotations

import types

import numpy as np
import pytest

from segmin.nav_eval.sim.config import Perception
from segmin.nav_eval.sim.mask_dropout import MaskDropout, corrupt, with_dropout
from segmin.nav_eval.sim.oracle import OracleSegmenter


def _frame(width: int = 224) -> types.SimpleNamespace:
    mask = np.zeros((64, width), dtype=bool)
    mask[10:60, 20:60] = True  # a 40 px wide hedge
    return types.SimpleNamespace(rgb=None, depth=None, mask=mask)


def _corrupted(seed: int, share: float, n: int = 400) -> list[bool]:
    wrapped = MaskDropout(OracleSegmenter(), share, "drop", seed=seed)
    frame = _frame()
    return [not wrapped.segment_frame(frame).any() for _ in range(n)]


def test_the_share_of_corrupted_masks_is_the_one_asked_for() -> None:
    n = 2000
    for share in (0.1, 0.5):
        hits = sum(_corrupted(0, share, n))
        assert abs(hits - share * n) < 4 * np.sqrt(n * share * (1 - share)), (share, hits)
    assert sum(_corrupted(0, 0.0)) == 0 and all(_corrupted(0, 1.0))
    wrapped = MaskDropout(OracleSegmenter(), 0.3, seed=1)
    for _ in range(50):
        wrapped.segment_frame(_frame())
    assert wrapped.masks == 50 and 0 < wrapped.corrupted < 50


def test_the_corruption_is_seeded() -> None:
    assert _corrupted(7, 0.3) == _corrupted(7, 0.3)
    assert _corrupted(7, 0.3) != _corrupted(8, 0.3)


def test_it_reads_colour_when_the_wrapped_segmenter_does() -> None:
    """nav-eval renders colour for a segmenter that reads it; the wrapper must not hide that."""
    reader = OracleSegmenter()
    reader.reads_colour = True  # as a model on images does
    assert not MaskDropout(OracleSegmenter(), 0.1).reads_colour and MaskDropout(reader, 0.1).reads_colour


def test_erode_shrinks_the_vegetation_and_drop_empties_the_mask() -> None:
    mask = _frame().mask
    eroded = corrupt(mask, "erode")  # 1/16 of 224 px: a 15 px kernel, 7 px off each side
    cols = np.flatnonzero(eroded.any(axis=0))
    assert cols[0] == 27 and cols[-1] == 52
    assert not (eroded & ~mask).any()  # only removes
    assert not corrupt(mask, "drop").any()
    assert corrupt(mask, "drop").shape == mask.shape


def test_the_perception_config_decides_whether_masks_are_wrapped() -> None:
    oracle = OracleSegmenter()
    assert with_dropout(oracle, Perception(), seed=0) is oracle
    wrapped = with_dropout(oracle, Perception(mask_dropout=0.4, mask_dropout_mode="drop"), seed=3)
    assert isinstance(wrapped, MaskDropout) and wrapped.share == 0.4 and wrapped.mode == "drop"
    with pytest.raises(ValueError, match="mode"):
        MaskDropout(oracle, 0.2, "blur")
