"""Train / validation splits: seeded per domain, saved as frame keys, reloaded exactly.

A split file lists (domain, subset, frame_id) keys rather than paths, so a run can be
reproduced on a copy of the dataset at another location.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.atomic import write_json
from segmin.data.frames import DatasetError, Frame


def make_splits(frames: Sequence[Frame], val_fraction: float = 0.1, seed: int = 0) -> dict[str, list[Frame]]:
    """Seeded split per domain: the same frames, fraction and seed always give the same split.

    Each domain is shuffled with its own generator (seeded by `seed` and the domain name), so
    adding a domain does not change the split of the others. A domain of two or more frames
    puts at least one frame in validation when `val_fraction` > 0.
    """
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction={val_fraction}: must be in [0, 1)")
    splits: dict[str, list[Frame]] = {"train": [], "val": []}
    by_domain: dict[str, list[Frame]] = {}
    for frame in sorted(frames, key=lambda f: f.key):
        by_domain.setdefault(frame.domain, []).append(frame)
    for domain, members in sorted(by_domain.items()):
        rng = np.random.default_rng([seed, zlib.crc32(domain.encode())])
        order = rng.permutation(len(members))
        n_val = int(round(len(members) * val_fraction))
        if val_fraction > 0 and n_val == 0 and len(members) >= 2:
            n_val = 1
        val_idx = set(order[:n_val].tolist())
        for i, frame in enumerate(members):
            splits["val" if i in val_idx else "train"].append(frame)
    return splits


def save_split(path: str | Path, splits: dict[str, list[Frame]], **meta: Any) -> None:
    """Write split lists as JSON of [domain, subset, frame_id] keys (plus `meta`), atomically."""
    write_json(
        path,
        {
            "format": "segmin-split-v1",
            **meta,
            **{name: [list(f.key) for f in frames] for name, frames in splits.items()},
        },
    )


def load_split(path: str | Path, frames: Sequence[Frame]) -> dict[str, list[Frame]]:
    """Re-select `frames` by a saved split file; a listed frame that is missing is an error."""
    path = Path(path)
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: bad JSON or not UTF-8 text at all
        raise DatasetError(f"{path}: cannot read split file ({exc})") from exc
    if not isinstance(content, dict) or content.get("format") != "segmin-split-v1":
        raise DatasetError(f"{path}: not a segmin split file")
    index = {f.key: f for f in frames}
    splits: dict[str, list[Frame]] = {}
    for name in ("train", "val"):
        chosen = []
        for entry in content.get(name, []):
            try:
                key = (str(entry[0]), str(entry[1]), int(entry[2]))
            except (TypeError, ValueError, IndexError, KeyError):
                raise DatasetError(f"{path}: {name} entry {entry!r} is not [domain, subset, frame_id]") from None
            if key not in index:
                raise DatasetError(f"{path}: {name} frame {key} is not in the dataset")
            chosen.append(index[key])
        splits[name] = chosen
    return splits
