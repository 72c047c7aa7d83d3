"""Speed targets as data: each bench (`segmin bench ...`, `python -m benchmarks ...`) declares a small table and
prints its figures against it.

A target names the figure a bench measures (its key in the bench's results), a limit and the
side of it that is good. Benches print "target ...: met / NOT met" lines and put the verdicts in
their JSON; no test times anything (a shared machine would make it flaky). Keeping the numbers in
one typed table per bench, not in prose, means the help text, the printed verdict and the JSON
can never disagree.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class SpeedTarget:
    """`label` (the figure `key` of a bench's results) must stay at or below `limit`, or with
    `at_least` reach it. `unit` follows the limit: "ms" after a space, "x ..." attached (0.35x eager)."""

    key: str
    label: str
    limit: float
    unit: str = ""
    at_least: bool = False

    def met(self, value: float) -> bool:
        return value >= self.limit if self.at_least else value <= self.limit

    def with_unit(self, value: float) -> str:
        """A figure in this target's unit: "6 ms", "0.35x eager", "0.9" (three significant digits)."""
        if not self.unit:
            return f"{value:.3g}"
        return f"{value:.3g}{'' if self.unit.startswith('x') else ' '}{self.unit}"

    def __str__(self) -> str:
        return f"{self.label} {'>=' if self.at_least else '<='} {self.with_unit(self.limit)}"

    def verdict(self, value: float) -> str:
        """ "target <label> <= <limit>: met (<value>)", or NOT met."""
        return f"target {self}: {'met' if self.met(value) else 'NOT met'} ({self.with_unit(value)})"


def verdicts(targets: Sequence[SpeedTarget], figures: Mapping[str, float]) -> dict[str, bool]:
    """{target as text: met} for every target whose figure was measured (a bench may skip some)."""
    return {str(t): t.met(figures[t.key]) for t in targets if t.key in figures}


def verdict_lines(targets: Sequence[SpeedTarget], figures: Mapping[str, float]) -> list[str]:
    """`SpeedTarget.verdict` of every target whose figure was measured."""
    return [t.verdict(figures[t.key]) for t in targets if t.key in figures]
