"""Checks shared by the world spec's sections: each raises a ValueError naming the field.

Every section of a world spec (`spec_field`, `spec_looks`, `spec`) validates itself in its
`__post_init__` with these, so a typo or an impossible number fails before pybullet starts and
the message reads the same whichever section it comes from.
"""

from __future__ import annotations

import dataclasses
import math

Range = tuple[float, float]


def check_range(name: str, value: Range, *, low: float | None = 0.0, strict: bool = False) -> None:
    """A `[low, high]` pair in order, whose low end is at least (or, `strict`, above) `low`."""
    a, b = value
    if a > b:
        raise ValueError(f"{name}: range [{a}, {b}] has low > high")
    if low is not None and (a < low or (strict and a <= low)):
        raise ValueError(f"{name}: values must be {'>' if strict else '>='} {low}, got [{a}, {b}]")


def check_finite(value, name: str) -> None:
    """NaN compares false with everything, so range checks would let it through: reject it (and
    infinities) in every number of the spec, naming the field."""
    if dataclasses.is_dataclass(value):
        for f in dataclasses.fields(value):
            check_finite(getattr(value, f.name), f"{name}.{f.name}" if name else f.name)
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            check_finite(v, f"{name}[{i}]")
    elif isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{name}: must be a finite number, got {value}")


def check_positive(name: str, value: float) -> None:
    """Lengths and spacings: zero would divide or build nothing."""
    if not value > 0:
        raise ValueError(f"{name}: must be > 0, got {value}")


def check_fraction(name: str, value: float) -> None:
    """Probabilities and shares."""
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{name}: must be within [0, 1], got {value}")


def check_names(name: str, values: list[str], allowed: tuple[str, ...]) -> None:
    """A non-empty list of names out of `allowed` (styles, colours)."""
    if not values:
        raise ValueError(f"{name}: at least one of {list(allowed)}")
    for v in values:
        if v not in allowed:
            raise ValueError(f"{name}: unknown value {v!r}; choose from {list(allowed)}")
