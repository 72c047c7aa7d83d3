"""Shared tiny worlds for the synth tests (short rows, few plants, small frames)."""

from __future__ import annotations

import copy

import yaml

TINY = {
    "name": "tiny_vineyard",
    "crop": "vineyard",
    "family": "vineyards",
    "seed": 5,
    "rows": {"count": 3, "length": 6.0, "spacing": 1.8},
    "plants": {"spacing": 1.3, "gap_probability": 0.0},
    "structures": {"poles": True, "pole_spacing": 3.0},
    "terrain": {"roughness": 0.03, "margin": 3.0, "grass_tufts": 0.3},
}


def tiny(**changes) -> dict:
    """A copy of TINY with top-level sections updated (nested dicts are merged one level)."""
    raw = copy.deepcopy(TINY)
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(raw.get(key), dict):
            raw[key].update(value)
        else:
            raw[key] = value
    return raw


def write_spec(path, raw: dict) -> str:
    path.write_text(yaml.safe_dump(raw))
    return str(path)
