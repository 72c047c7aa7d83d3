"""The shipping gate of a candidate stage: does its model replace the model of the stage before it?

A recipe may end a family's chain with a candidate stage (`finetune[-1].gate`): a change that
should help on the real rows' hard cases but has not been shown to. Its rule is written in the
profile before the stage is trained, and the pipeline applies it itself, on the held-out
validation frames both stages were scored on (`stages.held_out_eval`), before anything is
exported or any real photo is scored: the candidate's model is exported only if

1. its pooled IoU (against the canopy region) is at most `max_iou_drop` below the stage before it,
2. its steering target error median is no larger, and no more of its targets leave the truth's
   free corridor (`nav_eval.seg_eval.steering`),
3. it paints less than `max_uniform_painted` of every uniform frame;

otherwise the stage before it is exported, and the run records why. The photos are then scored
once, on the model the rule chose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class GateRule:
    """The limits a candidate stage must meet against the stage before it (module docstring)."""

    max_iou_drop: float = 0.01
    max_uniform_painted: float = 0.01

    def __post_init__(self) -> None:
        for name in ("max_iou_drop", "max_uniform_painted"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 1:
                raise ValueError(f"gate.{name} must be a share within [0, 1], got {value!r}")


@dataclass(frozen=True)
class GateVerdict:
    """Whether the candidate ships, and every rule it broke (empty when it ships)."""

    stage: str
    passed: bool
    failures: tuple[str, ...]

    def as_dict(self) -> dict[str, Any]:
        return {"stage": self.stage, "passed": self.passed, "failures": list(self.failures)}


def judge(rule: GateRule, stage: str, candidate: dict[str, Any] | None, before: dict[str, Any] | None) -> GateVerdict:
    """The verdict on `candidate`'s held-out figures against `before`'s (None: the stage was not
    scored on held-out frames, so nothing shows it is better: it does not ship)."""
    if (
        not candidate
        or not before
        or "target_error_median_px" not in candidate
        or "target_error_median_px" not in before
    ):
        return GateVerdict(stage, False, ("no held-out figures for both stages",))
    failures = []
    if not _figure(candidate, "pooled_iou") >= _figure(before, "pooled_iou") - rule.max_iou_drop:  # NaN fails
        failures.append(
            f"pooled IoU {_figure(candidate, 'pooled_iou'):.3f} is more than {rule.max_iou_drop:g} below "
            f"{_figure(before, 'pooled_iou'):.3f}"
        )
    if candidate["target_error_median_px"] > before["target_error_median_px"]:
        failures.append(
            f"steering error median {candidate['target_error_median_px']:.1f} px above "
            f"{before['target_error_median_px']:.1f} px"
        )
    if candidate["targets_outside_corridor"] > before["targets_outside_corridor"]:
        failures.append(
            f"{candidate['targets_outside_corridor']} targets outside the corridor, against "
            f"{before['targets_outside_corridor']}"
        )
    painted = candidate.get("blank_frames_worst")
    if painted is None or painted >= rule.max_uniform_painted:
        failures.append(f"a uniform frame painted {_share(painted)} (limit {rule.max_uniform_painted:.0%})")
    return GateVerdict(stage, not failures, tuple(failures))


def _figure(figures: dict[str, Any], name: str) -> float:
    """A figure that may be null in JSON (undefined): NaN, which fails every comparison."""
    value = figures.get(name)
    return math.nan if value is None else float(value)


def _share(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2%}"
