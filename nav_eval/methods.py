"""The navigation methods, in the paper's order: the one list every command, config and report uses.

Its own module (no numpy) so command-line defaults can name the methods without importing the
navigator.
"""

from __future__ import annotations

METHODS: tuple[str, ...] = ("segmin", "segmind", "segzeros")
