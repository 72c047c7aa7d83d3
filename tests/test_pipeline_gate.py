"""A candidate stage's gate (segmin.app.pipeline.gate): its model ships only if it does no worse on held-out frames."""

from __future__ import annotations

import pytest

from segmin.app.pipeline.config import load_pipeline_config
from segmin.app.pipeline.gate import GateRule, judge
from segmin.common.config import ConfigError

BEFORE = {
    "pooled_iou": 0.80,
    "target_error_median_px": 4.0,
    "targets_outside_corridor": 2,
    "blank_frames_worst": 0.2,
}
GOOD = {**BEFORE, "pooled_iou": 0.795, "target_error_median_px": 3.5, "blank_frames_worst": 0.004}


def test_a_candidate_no_worse_on_every_figure_ships() -> None:
    verdict = judge(GateRule(), "hard_cases", GOOD, BEFORE)
    assert verdict.passed and verdict.failures == () and verdict.as_dict()["stage"] == "hard_cases"


@pytest.mark.parametrize(
    ("change", "failure"),
    [
        ({"pooled_iou": 0.785}, "pooled IoU 0.785 is more than 0.01 below 0.800"),
        ({"pooled_iou": None}, "pooled IoU nan"),
        ({"target_error_median_px": 4.5}, "steering error median 4.5 px above 4.0 px"),
        ({"targets_outside_corridor": 3}, "3 targets outside the corridor, against 2"),
        ({"blank_frames_worst": 0.01}, "a uniform frame painted 1.00% (limit 1%)"),
    ],
)
def test_each_figure_that_gets_worse_keeps_the_stage_before(change: dict, failure: str) -> None:
    verdict = judge(GateRule(), "hard_cases", {**GOOD, **change}, BEFORE)
    assert not verdict.passed and len(verdict.failures) == 1 and failure in verdict.failures[0]


def test_without_held_out_figures_nothing_ships() -> None:
    assert not judge(GateRule(), "x", None, BEFORE).passed
    assert not judge(GateRule(), "x", GOOD, {"pooled_iou": 0.8}).passed


def test_only_the_last_stage_may_be_a_candidate_and_its_limits_are_shares() -> None:
    gated = "{name: a, gate: {max_iou_drop: 0.01}}"
    with pytest.raises(ConfigError, match="only the last stage may have a gate"):
        load_pipeline_config("release_micro", [f"families.vineyards.finetune=[{gated}, {{name: b}}]"])
    with pytest.raises(ConfigError, match=r"gate.max_iou_drop must be a share within \[0, 1\], got 2"):
        load_pipeline_config("release_micro", ["families.vineyards.finetune=[{name: a, gate: {max_iou_drop: 2}}]"])
    chain = load_pipeline_config("release").training_chain("vineyards")
    assert chain[-1].name == "hard_cases" and chain[-1].gate == GateRule(0.01, 0.01)
    assert all(step.gate is None for step in chain[:-1])
