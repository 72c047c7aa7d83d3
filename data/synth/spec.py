"""World specs: every number that shapes a procedural field, validated before anything is built.

A spec is a YAML file in `configs/worlds/` loaded strictly (unknown keys are errors, see
`segmin.common.config`). Geometry is in metres and degrees; ranges are `[low, high]` pairs that the
world builder samples per plant. Validation raises an error naming the field, so a typo or an
impossible field (negative spacing, rows that would intersect) fails before pybullet starts.

This module is the one to import from: `WorldSpec` and its loaders live here, its sections are
split by job and re-exported here: `spec_field` (rows, plants, structures and nets, terrain),
`spec_looks` (appearance, render, sky, capture, backdrop) and `spec_checks` (the shared checks).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from segmin.common.config import apply_overrides, from_dict, read_yaml
from segmin.common.shipped import resolve_config
from segmin.data.synth.spec_checks import check_finite
from segmin.data.synth.spec_field import (
    MAX_NET_HEIGHT,
    MAX_POLYLINE_FOLD,
    NET_COLOUR_NAMES,
    POST_STYLE_NAMES,
    NetsSpec,
    PlantsSpec,
    RowsSpec,
    StructuresSpec,
    TerrainSpec,
)
from segmin.data.synth.spec_looks import (
    GROUND_STYLE_NAMES,
    AppearanceSpec,
    BackdropSpec,
    CaptureSpec,
    RenderSpec,
    SkySpec,
)

log = logging.getLogger(__name__)

# Shipped worlds renamed for what they hold (they were named for the experiment that made them):
# the old names load the new worlds, with a warning, for one release.
RENAMED_WORLDS: dict[str, str] = {
    "train_vineyard_a_levers": "train_vineyard_under_nets",
    "train_vineyard_b_levers": "train_vineyard_winter_dormant",
    "train_pergola_a_levers": "train_pergola_under_net",
    "train_pear_a_levers": "train_pear_under_nets",
    "train_apple_wall_a_levers": "train_apple_wall_under_nets",
}

TEST_FIELDS: tuple[str, ...] = (
    "straight_vineyard",
    "curved_vineyard",
    "pergola_vineyard",
    "pear_field",
    "high_trees",
)


# The narrowest free gap a world may have: the evaluation robot's footprint (a Clearpath Jackal,
# 0.43 m wide, see nav_eval.robot.RobotConfig; data must not import nav_eval) plus 0.1 m either
# side. A narrower gap is a field no run can drive, so every run would "collide" by construction.
MIN_GAP_WIDTH = 0.63
# How far an anti-hail net's ridge (over a row line) stays above the tallest plant.
NET_CLEARANCE = 0.2


@dataclass
class WorldSpec:
    """A whole field. `family` groups training worlds like the paper's crop families."""

    name: str
    crop: Literal["vineyard", "pergola", "pear", "tree"]
    family: Literal["vineyards", "trees"]
    seed: int
    domain: str = ""  # AgriSeg-style domain for the writer; default synth_<name>
    rows: RowsSpec = field(default_factory=RowsSpec)
    plants: PlantsSpec = field(default_factory=PlantsSpec)
    structures: StructuresSpec = field(default_factory=StructuresSpec)
    terrain: TerrainSpec = field(default_factory=TerrainSpec)
    appearance: AppearanceSpec = field(default_factory=AppearanceSpec)
    render: RenderSpec = field(default_factory=RenderSpec)
    sky: SkySpec = field(default_factory=SkySpec)
    capture: CaptureSpec = field(default_factory=CaptureSpec)
    backdrop: BackdropSpec = field(default_factory=BackdropSpec)

    def __post_init__(self) -> None:
        check_finite(self, "")
        if not self.name or not self.name.replace("_", "").replace("-", "").isalnum():
            raise ValueError(f"name: must be a non-empty word (letters, digits, _ or -), got {self.name!r}")
        if not self.domain:
            base = self.name[len("train_") :] if self.name.startswith("train_") else self.name
            self.domain = f"synth_{base}"
        if not self.domain.replace("_", "").replace("-", "").isalnum():
            raise ValueError(f"domain: must be a word usable as a folder name, got {self.domain!r}")
        if self.seed < 0:
            raise ValueError(f"seed: must be >= 0, got {self.seed}")
        # Rows intersect when the trunk lines (plus jitter) of neighbouring rows can touch.
        trunk_clearance = 2 * (self.plants.trunk_radius[1] + 3 * self.rows.lateral_jitter)
        if self.rows.spacing <= trunk_clearance:
            raise ValueError(
                f"rows.spacing: {self.rows.spacing} m is too small, neighbouring rows would intersect "
                f"(trunks and jitter need > {trunk_clearance:.2f} m)"
            )
        free = self.free_gap_width
        if free <= MIN_GAP_WIDTH:
            raise ValueError(
                f"rows.spacing: {self.rows.spacing} m leaves a free gap of {free:.2f} m between the rows "
                f"(canopy and trunks subtracted); the robot needs more than {MIN_GAP_WIDTH} m"
            )
        self._check_levers()
        if (
            self.structures.pergola
            and self.structures.free_band_width / 2 + abs(self.structures.free_band_offset) >= self.rows.spacing / 2
        ):
            raise ValueError(
                "structures.free_band_width: the free band (with its offset) must fit between the rows "
                f"({self.structures.free_band_width} + 2*{abs(self.structures.free_band_offset)} >= {self.rows.spacing})"
            )

    def _check_levers(self) -> None:
        """Data-engine levers that only make sense for some fields: say which key is wrong and why."""
        nets, plants = self.structures.nets, self.plants
        if nets.probability > 0:
            top = max(plants.height[1], self.structures.pergola_height if self.structures.pergola else 0.0)
            if nets.height[0] < top + NET_CLEARANCE - 1e-9:  # 3.1 + 0.2 is a hair above 3.3
                raise ValueError(
                    f"structures.nets.height: {list(nets.height)} must clear the plants' top {top} m by "
                    f"{NET_CLEARANCE} m, or the net would cut through the canopy"
                )
        if plants.dormant_probability > 0 and self.crop != "vineyard":
            raise ValueError(f"plants.dormant_probability: dormant canes are built for vineyards, not {self.crop!r}")

    @property
    def free_gap_width(self) -> float:
        """Free width of a gap at the robot's height: spacing minus what reaches in from both rows.

        Hedge crops (vineyard, pear) fill the gap from the canopy down; trees and pergolas
        leave the trunk line (plus jitter and low branches) as the obstacle at robot height.
        """
        p, r = self.plants, self.rows
        if self.crop in ("vineyard", "pear"):
            reach = 0.5 * p.canopy_width[1]
        else:
            reach = p.trunk_radius[1] + 2 * r.lateral_jitter
            if p.low_branches[1] > 0:
                reach += p.low_branch_reach
        return r.spacing - 2 * reach

    @property
    def n_gaps(self) -> int:
        return self.rows.count - 1

    @property
    def eval_gap(self) -> int:
        """Index of the gap a closed-loop run drives through (the middle one by default)."""
        return self.rows.eval_gap if self.rows.eval_gap >= 0 else (self.rows.count - 1) // 2


def load_world_spec(name_or_path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> WorldSpec:
    """Load and validate a world spec (a shipped name or a YAML path); errors name the file and the field."""
    new_name = RENAMED_WORLDS.get(str(name_or_path))
    if new_name is not None:
        log.warning("world %s is now called %s; the old name goes in the next release", name_or_path, new_name)
        name_or_path = new_name
    path = resolve_config("worlds", name_or_path)
    raw = apply_overrides(read_yaml(path), list(overrides))
    return from_dict(WorldSpec, raw, where=str(path))


def spec_from_dict(raw: dict, overrides: list[str] | tuple[str, ...] = (), where: str = "world") -> WorldSpec:
    """Build a spec from a mapping (tests, programmatic worlds)."""
    return from_dict(WorldSpec, apply_overrides(raw, list(overrides)), where=where)


def pergola_reach(spec: WorldSpec) -> tuple[float, float]:
    """(right, left) reach of a pergola row's canopy towards the gaps on each side (m)."""
    s = spec.structures
    half = spec.rows.spacing / 2
    left = half + s.free_band_offset - s.free_band_width / 2  # towards the gap on the left
    right = half - s.free_band_offset - s.free_band_width / 2  # towards the gap on the right
    return max(right, 0.0), max(left, 0.0)


__all__ = [
    "GROUND_STYLE_NAMES",
    "MAX_NET_HEIGHT",
    "MAX_POLYLINE_FOLD",
    "MIN_GAP_WIDTH",
    "NET_COLOUR_NAMES",
    "POST_STYLE_NAMES",
    "RENAMED_WORLDS",
    "TEST_FIELDS",
    "AppearanceSpec",
    "BackdropSpec",
    "CaptureSpec",
    "NetsSpec",
    "PlantsSpec",
    "RenderSpec",
    "RowsSpec",
    "SkySpec",
    "StructuresSpec",
    "TerrainSpec",
    "WorldSpec",
    "load_world_spec",
    "pergola_reach",
    "spec_from_dict",
]
