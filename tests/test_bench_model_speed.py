"""`segmin bench model-speed`: configurations timed in turn, each in its own process, with ratios to
the paper's model. Nothing here judges a time: the rotation, the table and the refusals are logic."""

from __future__ import annotations

import numpy as np
import pytest

from segmin.app.cli import main
from segmin.nav_eval.bench.segmenter_speed import Setup, SetupFigure, format_figures, run_rounds
from segmin.nav_eval.runtime.shipped_models import shipped_model


def test_each_configuration_runs_in_turn_and_reports_every_round():
    model = str(shipped_model("vineyards").onnx)
    frame = np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    setups = [Setup("onnx", model, 1, True), Setup("onnx", model, 1, False)]
    said: list[str] = []
    figures = run_rounds(setups, frame, rounds=2, warmup=1, runs=3, say=said.append)
    assert [f.setup for f in figures] == setups
    assert all(len(f.round_medians_ms) == 2 and f.median_ms > 0 for f in figures)
    # the configurations alternate within each round: round 1 of both before round 2 of either
    assert [line.split(":")[0] for line in said] == [
        "round 1/2 onnx 1 thread(s), spinning on",
        "round 1/2 onnx 1 thread(s), spinning off",
        "round 2/2 onnx 1 thread(s), spinning on",
        "round 2/2 onnx 1 thread(s), spinning off",
    ]


def test_ratios_are_to_the_paper_model_at_the_same_thread_count_and_the_default_is_judged():
    figures = [
        SetupFigure(Setup("paper", "p.tflite", 2), 4.0, (4.0,)),
        SetupFigure(Setup("onnx", "m.onnx", 2, True), 6.0, (6.0,)),
        SetupFigure(Setup("onnx", "m.onnx", 2, False), 3.0, (3.0,)),
        SetupFigure(Setup("onnx", "m.onnx", 1, False), 5.0, (5.0,)),  # no paper figure at 1 thread
    ]
    lines = format_figures(figures, Setup("onnx", "m.onnx", 0, False))
    assert lines[0] == "the runtime's default: onnx, spinning off"
    assert "| onnx 2 thread(s), spinning on | 6.00 | 6.00 | 1.50 |" in lines
    assert "| onnx 2 thread(s), spinning off | 3.00 | 3.00 | 0.75 |" in lines
    assert "| onnx 1 thread(s), spinning off | 5.00 | 5.00 | n/a |" in lines
    verdicts = [line for line in lines if "target" in line]
    assert verdicts == [
        "2 thread(s): target the runtime's default configuration <= 0.8x the paper's model: met (0.75x the paper's model)"
    ]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--rounds", "0"], "--rounds 0: must be >= 1"),
        (["--threads", "0"], "--threads each >= 1"),
        (["--paper", "no/such.tflite"], "--paper no/such.tflite: no such file"),
        (["--model", "VINEYARDS_FILE"], "is a file: --frame must name the image to segment"),
    ],
)
def test_bad_parameters_are_one_line(argv, message, capsys):
    argv = [str(shipped_model("vineyards").onnx) if a == "VINEYARDS_FILE" else a for a in argv]
    assert main(["bench", "model-speed", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
