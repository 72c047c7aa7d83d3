"""How a figure prints in every table and card: undefined figures read n/a, never nan or a crash."""

from __future__ import annotations

import math

from segmin.common.figures import format_figure, format_mean_std


def test_a_figure_prints_with_its_digits_and_an_undefined_one_as_n_a() -> None:
    assert format_figure(0.12345) == "0.123"
    assert format_figure(3.0796, 2) == "3.08"
    assert format_figure(None) == format_figure(math.nan) == "n/a"


def test_mean_and_spread_print_together_and_n_a_when_no_run_gave_the_figure() -> None:
    assert format_mean_std(0.0524, 0.0161) == "0.052 ± 0.016"
    assert format_mean_std(1.5, 0.25, 2) == "1.50 ± 0.25"
    assert format_mean_std(math.nan, math.nan) == "n/a"
