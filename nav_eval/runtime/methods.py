"""The navigation methods, in the paper's order: the one list every command, config and report uses.

Its own module (no numpy) so command-line defaults can name the methods without importing the
navigator.
"""

from __future__ import annotations

PAPER_METHODS: tuple[str, ...] = ("segmin", "segmind", "segzeros")
"""The paper's three (nav_eval.navigator), compared with its Table 3."""

METHODS: tuple[str, ...] = PAPER_METHODS + ("segcorridor",)
"""Every method: the paper's three and SegCorridor (nav_eval.corridor), which goes beyond it."""

DEPTH_METHODS: tuple[str, ...] = ("segmind", "segcorridor")
"""Methods that cannot run without depth frames."""
