"""The navigation methods, in the paper's order: the one list every command, config and report uses.

Its own module (no numpy) so command-line defaults can name the methods without importing the
navigator.
"""

from __future__ import annotations

PAPER_METHODS: tuple[str, ...] = ("segmin", "segmind", "segzeros")
"""The paper's three (nav_eval.navigator), compared with its Table 3."""

METHODS: tuple[str, ...] = (*PAPER_METHODS, "segcorridor")
"""Every method: the paper's three and SegCorridor (nav_eval.corridor), which goes beyond it."""

DEPTH_METHODS: tuple[str, ...] = ("segmind", "segcorridor")
"""Methods that cannot run without depth frames."""

METHOD_STATISTICS: dict[str, tuple[str, ...]] = {"segcorridor": ("one_side_share", "trunk_share", "fallback_share")}
"""Per-run statistics a method's navigator reports (`statistics()`), by result column name: SegCorridor's
shares of commands from one row, from the trunks and from the fallback. A method without an entry
reports none."""

STATISTIC_COLUMNS: tuple[str, ...] = tuple(
    dict.fromkeys(column for method in METHODS for column in METHOD_STATISTICS.get(method, ()))
)
"""Every method's statistics as result columns, in method order: each results.json row has all of
them (NaN where its method reports none), so rows of different methods have the same columns."""
