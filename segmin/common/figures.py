"""How one measured figure reads in every table and card: three decimals, or n/a when undefined.

One formatter, so eval-seg's summary, the contact sheets, the pipeline report, the model cards
and `segmin models list` print the same figure the same way.
"""

from __future__ import annotations

import math
from typing import Any


def format_figure(value: Any, digits: int = 3) -> str:
    """`digits` decimals, or n/a for a figure that is undefined (None or NaN) or not measured."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    return f"{value:.{digits}f}"


def format_mean_std(mean: float, std: float, digits: int = 3) -> str:
    """ "mean ± std" over runs, or n/a when no run gave the figure (mean NaN)."""
    if math.isnan(mean):
        return "n/a"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"
