"""Crop families and domain selection, and `find_frames`: a scan whose problems are errors.

A family (`trees`, `vineyards`, ...) names the paper's crop groups; its members are domain
names, globs or prefixes, so one config line selects real and synthetic domains alike.
"""

from __future__ import annotations

import fnmatch
import logging
from collections.abc import Iterable, Sequence
from pathlib import Path

from segmin.data.frames import DatasetError, Frame
from segmin.data.layouts import scan

log = logging.getLogger(__name__)

# Crop families of the paper. Members are domain names, globs or prefixes (see resolve_domains).
# `tree` is the domain name the distributed layout's Synthetic_Dataset_Big_Trees gets.
FAMILIES: dict[str, tuple[str, ...]] = {
    "trees": ("tree_1", "tree_2", "tree", "pear"),
    "vineyards": ("vineyard", "vineyard_pergola"),
    "synth_trees": ("synth_*tree*", "synth_*pear*"),
    "synth_vineyards": ("synth_*vineyard*", "synth_*pergola*"),
}


def available_domains(frames: Iterable[Frame]) -> list[str]:
    """The domain names present in `frames`, sorted."""
    return sorted({f.domain for f in frames})


def resolve_domains(spec: Sequence[str] | str | None, available: Sequence[str]) -> list[str]:
    """Turn a list of family names, domain names, globs or prefixes into domain names.

    Each item is, in order of precedence: a family (`trees`, `vineyards`, `synth_trees`,
    `synth_vineyards`), an exact domain, a glob (`synth_*vineyard*`), or a prefix
    (`synth_train_vineyard` matches `synth_train_vineyard_a`). An item that matches nothing is an
    error (listing what exists), except family members, of which at least one must match.
    """
    if spec is None:
        return sorted(available)
    items = [spec] if isinstance(spec, str) else list(spec)
    chosen: list[str] = []
    for item in items:
        if item in FAMILIES:
            found = [d for member in FAMILIES[item] for d in _match(member, available)]
            if not found:
                raise DatasetError(
                    f"family {item!r} ({', '.join(FAMILIES[item])}): none of its domains is present; "
                    f"available: {', '.join(available) or 'none'}"
                )
        else:
            found = _match(item, available)
            if not found:
                raise DatasetError(
                    f"domain {item!r}: no frames found for it; available: {', '.join(available) or 'none'}"
                )
        chosen.extend(d for d in found if d not in chosen)
    return chosen


def _match(pattern: str, available: Sequence[str]) -> list[str]:
    if pattern in available:
        return [pattern]
    if any(c in pattern for c in "*?["):
        return sorted(d for d in available if fnmatch.fnmatchcase(d, pattern))
    return sorted(d for d in available if d.startswith(pattern + "_") or d.startswith(pattern + "-"))


def find_frames(
    root: str | Path, domains: Sequence[str] | str | None = None, *, skip_unpaired: bool = False
) -> list[Frame]:
    """All paired frames under `root` of the chosen domains (all when None).

    Raises DatasetError naming the files when anything is unpaired (unless `skip_unpaired`, which
    logs each one), when the layout has other problems, or when a chosen domain is empty.
    """
    result = scan(root)
    if result.unpaired:
        if skip_unpaired:
            for message in result.unpaired:
                log.warning("skipping unpaired frame: %s", message)
        else:
            result.problems.extend(result.unpaired)
    if result.problems:
        shown = result.problems[:20]
        more = f"\n  ... and {len(result.problems) - 20} more" if len(result.problems) > 20 else ""
        raise DatasetError(f"{root}: {len(result.problems)} problem(s):\n  " + "\n  ".join(shown) + more)
    chosen = set(resolve_domains(domains, available_domains(result.frames)))
    return [f for f in result.frames if f.domain in chosen]
