"""Speed targets as data (segmin.common.speed_targets), and the benches' typed parameters.

Nothing here times anything: the targets' verdicts and the refusal of bad parameters are logic.
"""

from __future__ import annotations

import pytest

from segmin.common.speed_targets import SpeedTarget, verdict_lines, verdicts


def test_a_target_judges_both_directions_and_prints_its_limit_with_the_unit():
    at_most = SpeedTarget("ms", "fp32 median", 6.0, "ms")
    at_least = SpeedTarget("factor", "closed loop", 3.0, "x real time", at_least=True)
    assert at_most.met(6.0) and not at_most.met(6.01)
    assert at_least.met(3.0) and not at_least.met(2.99)
    assert str(at_most) == "fp32 median <= 6 ms" and str(at_least) == "closed loop >= 3x real time"
    assert at_most.verdict(13.114) == "target fp32 median <= 6 ms: NOT met (13.1 ms)"
    assert SpeedTarget("r", "ratio", 0.9, at_least=True).verdict(0.944) == "target ratio >= 0.9: met (0.944)"


def test_verdicts_cover_the_measured_figures_only():
    targets = (SpeedTarget("a", "a", 1.0, "ms"), SpeedTarget("b", "b", 2.0, "ms"))
    assert verdicts(targets, {"b": 3.0}) == {"b <= 2 ms": False}
    assert verdict_lines(targets, {"a": 0.5, "b": 1.0}) == [
        "target a <= 1 ms: met (0.5 ms)",
        "target b <= 2 ms: met (1 ms)",
    ]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["export", "--runs", "0"], "--runs 0: must be >= 1"),
        (["export", "--size", "16"], "--size 16: must be >= 32"),
        (["train", "--repeats", "0"], "--repeats 0: must be >= 1"),
        (["synth", "--frames", "0"], "--frames 0: must be >= 1"),
        (["synth", "--workers", "1", "0"], "--workers 1 0: each must be >= 1"),
        (["nav-eval", "--workers", "0"], "--workers 0: must be >= 1"),
        (["nav-eval", "--seconds", "0"], "--seconds 0.0: must be > 0"),
        (["nav-eval", "--backends", "tiny", "vulkan"], "--backends tiny vulkan: each must be one of auto, tiny, gl"),
        (["nav-eval", "--rounds", "0"], "--rounds 0: must be >= 1"),
        (["synth", "--backends", "egl"], "--backends egl: each must be tiny or gl"),
        (["render-agreement", "--poses", "0"], "--poses 0: must be >= 1"),
        (["live-view", "--frames", "10"], "--frames 10: must be >= 30"),
        (["live-view", "--rounds", "0"], "--rounds 0: must be >= 1"),
    ],
)
def test_benches_refuse_bad_parameters_with_one_line(argv, message, capsys):
    from benchmarks.cli import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
