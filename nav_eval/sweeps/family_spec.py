"""Families of worlds, the plan: a spec with `families:` and the validated worlds and settings it makes.

One world per field recipe chooses a default on that world's chance layout of plants, gaps and
terrain: a setting can win a field by a millimetre that the next layout takes back. A family is
a recipe (a test field or a sloped world) rendered with `world_seeds` seeds: the recipe's own
seed (the shipped world itself) and seeds `WORLD_SEED_STRIDE` apart, everything else in the recipe unchanged. A
family spec runs every candidate setting (a robot and nav config overrides) on every world of
every family, and the report (`family_report`) judges each setting on the families' means.

Everything is built and validated here, before any run: each recipe through `WorldSpec`'s checks
(training worlds refused), each setting's nav config through `NavEvalConfig`'s and its navigators
on every family; errors are one line naming the spec file and the key.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Literal

from segmin.common.config import ConfigError, from_dict, read_yaml, to_dict
from segmin.common.shipped import resolve_config
from segmin.nav_eval.evaluation.report import PAPER_TABLE3, TABLE_METRICS
from segmin.nav_eval.sweeps.spec import check_runs

# The spec key that makes a sweep file a family comparison rather than a parameter sweep.
FAMILIES_KEY = "families"
# World k of a family has the recipe's seed + k x this. Every shipped world's seed is below it and
# no two are equal, so no family world repeats a shipped world or another family's world (seeds
# next to each other would: slope_vineyard_s4 is 3101 and slope_vineyard_s8 3102).
WORLD_SEED_STRIDE = 10_000


@dataclasses.dataclass
class Setting:
    """One candidate: the robot it drives and the nav config overrides that make it."""

    robot: Literal["kinematic", "skid_steer"]
    overrides: list[str] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class FamilySpec:
    """A family comparison file: which recipes, how many worlds each, which settings to compare."""

    families: list[str]  # world recipes: shipped names or world spec YAML paths
    settings: dict[str, Setting]  # name -> setting, in table order
    world_seeds: int = 6  # worlds per family: the recipe's seed + k x WORLD_SEED_STRIDE, k < world_seeds
    model: str = "oracle"
    methods: list[str] = dataclasses.field(default_factory=lambda: ["segcorridor"])
    runs: int = 1  # seeded runs per world, setting and method (the same starts for every setting)
    seed: int = 0
    nav_config: str = "default"
    overrides: list[str] = dataclasses.field(default_factory=list)  # nav config key=value for every setting
    paper_method: str = "segmind"  # whose Table 3 MAE a family with a paper figure must beat
    flat_reference: str = "straight_vineyard"  # the family a family without a paper figure is held to
    sloped_within: float = 2.0  # ... within this multiple of its mean

    def __post_init__(self) -> None:
        if not self.families:
            raise ValueError("families: name at least one world recipe")
        if len(set(self.families)) != len(self.families):
            raise ValueError(f"families: a recipe is repeated in {self.families}")
        if not self.settings:
            raise ValueError("settings: name at least one setting to compare")
        if self.world_seeds < 2:
            raise ValueError(
                f"world_seeds: must be >= 2 (a family's interval needs two worlds), got {self.world_seeds}"
            )
        check_runs(self.methods, self.runs, self.seed)
        if self.paper_method not in {method for _, method in PAPER_TABLE3}:
            raise ValueError(f"paper_method: the paper's Table 3 has no {self.paper_method!r}")
        if not self.sloped_within > 0:
            raise ValueError(f"sloped_within: must be > 0, got {self.sloped_within}")


@dataclasses.dataclass
class Member:
    """One world of a family: the recipe with its seed replaced."""

    family: str  # the recipe's label (file stem for a path)
    world_seed: int
    field: str  # the recipe as named (the shipped world itself) or the file name to write it under
    world: dict  # the world spec as plain data
    shipped: bool  # True: `field` is the recipe itself; False: write `world` as `field` before running

    @property
    def label(self) -> str:
        """The world's name in tables and its run seeds (a field label, as nav-eval's)."""
        return Path(self.field).stem if not self.shipped else self.family


@dataclasses.dataclass
class FamilyPlan:
    """Everything a family comparison runs, validated."""

    spec: FamilySpec
    where: str  # the spec file, for messages
    name: str  # the file's stem
    members: list[Member]
    configs: dict[str, dict]  # setting name -> its NavEvalConfig as plain data
    base_config: Any  # the first setting's NavEvalConfig (the workers' default)


def is_family_spec(name_or_path: str | Path) -> bool:
    """Whether a sweep file (shipped name or path) is a family comparison (it has `families:`)."""
    raw = read_yaml(resolve_config("sweeps", name_or_path))
    return isinstance(raw, dict) and FAMILIES_KEY in raw


def load_family_spec(name_or_path: str | Path) -> tuple[FamilySpec, Path]:
    """A family spec (shipped name or YAML path), validated; errors name the file and the key."""
    path = resolve_config("sweeps", name_or_path)
    return from_dict(FamilySpec, read_yaml(path), where=str(path)), path


def plan_families(spec: FamilySpec, where: str, overrides: list[str] | tuple[str, ...] = ()) -> FamilyPlan:
    """Build and validate every world and setting; raises ConfigError naming `where` and the key.
    `overrides` (nav config key=value) come after the spec's and each setting's own."""
    from segmin.data.synth.spec import load_world_spec
    from segmin.nav_eval.evaluation.evaluate import check_navigators
    from segmin.nav_eval.sim.config import load_nav_config
    from segmin.nav_eval.sim.factories import field_label

    recipes = {}
    for recipe in spec.families:
        try:
            world = load_world_spec(recipe)
        except ConfigError as exc:
            raise ConfigError(f"{where}: families: {recipe}: {exc}") from exc
        if world.name.startswith("train_"):
            raise ConfigError(f"{where}: families: {recipe!r} is a training world; compare on test fields")
        recipes[recipe] = world
    labels = [field_label(recipe) for recipe in spec.families]
    unjudged = [
        label
        for label in labels
        if paper_mae(spec.paper_method, label) is None and label != field_label(spec.flat_reference)
    ]
    if unjudged and field_label(spec.flat_reference) not in labels:
        raise ConfigError(
            f"{where}: families: {', '.join(unjudged)} has no paper figure and is held to "
            f"{spec.sloped_within:g}x the flat_reference family ({spec.flat_reference}), which is not in families"
        )
    configs: dict[str, Any] = {}
    for name, setting in spec.settings.items():
        try:
            config = load_nav_config(
                spec.nav_config, [f"robot.model={setting.robot}", *spec.overrides, *setting.overrides, *overrides]
            )
            for recipe, world in recipes.items():
                check_navigators(world, field_label(recipe), spec.methods, config)
        except (ConfigError, ValueError) as exc:
            raise ConfigError(f"{where}: settings.{name}: {' '.join(str(exc).split())}") from exc
        configs[name] = config
    members = []
    for recipe, world in recipes.items():
        raw, label = to_dict(world), field_label(recipe)
        for k in range(spec.world_seeds):
            seed = world.seed + k * WORLD_SEED_STRIDE
            member_world = {**raw, "seed": seed}
            if k == 0:
                members.append(Member(label, seed, recipe, member_world, shipped=True))
            else:
                members.append(Member(label, seed, f"{label}-seed{seed}.yaml", member_world, shipped=False))
    plain = {name: to_dict(config) for name, config in configs.items()}
    return FamilyPlan(spec, where, Path(where).stem, members, plain, next(iter(configs.values())))


def paper_mae(method: str, family: str) -> float | None:
    """The paper's Table 3 MAE of `method` in the field `family`, if the paper has one."""
    row = PAPER_TABLE3.get((family, method))
    return None if row is None else row[TABLE_METRICS.index("mae")]
