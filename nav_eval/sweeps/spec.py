"""Robustness sweeps, the plan: a spec (`configs/sweeps/*.yaml`) and the validated variants it makes.

A sweep takes one base field and changes one parameter at a time through a list of values; each
(parameter, value) is a variant: the base world spec and nav config with that one key changed.
`PARAMETERS` is the whole vocabulary, an explicit table from the name a spec uses to the world
spec or nav config key it sets; anything else is an error that lists the known names.

Every variant is built and validated here, before any run: the world through `WorldSpec`'s own
checks, the nav config through `NavEvalConfig`'s, the navigators of every method through
`check_navigators`, so a value that makes an invalid field stops the sweep with one line naming
the sweep file, the parameter, the value and what the validation said. A parameter that cannot
act from the base (a robot.skid one on the kinematic robot, the downhill creep on a field without
a cross slope) is refused as well: every value would drive the same, and the flat lines would
read as robustness. A spec drives the skid-steer robot unless it says `robot: kinematic`.
"""

from __future__ import annotations

import copy
import dataclasses
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

from segmin.common.config import ConfigError, from_dict, read_yaml, to_dict
from segmin.common.shipped import resolve_config
from segmin.nav_eval.evaluation.run_store import digest
from segmin.nav_eval.runtime.methods import METHODS


def _as_written(value: Any, current: Any) -> Any:
    return value


def _radius(value: Any, current: Any) -> Any:
    """'straight' reads better in a list of radii than 0 (the world spec's "no bend")."""
    return 0.0 if value == "straight" else value


def _range_from(value: Any, current: Any) -> Any:
    """A [low, high] range moved so that it starts at `value`, keeping its spread."""
    low, high = current
    return [value, value + (high - low)] if isinstance(value, (int, float)) and not isinstance(value, bool) else value


def _across(value: Any, current: Any) -> Any:
    """The cross component (dz/dy) of the terrain slope; the slope along the rows is kept."""
    return [current[0], value]


# The skid-steer coefficients that say how much the ground lets the wheels slide (robot.skid): the
# `slip` parameter scales them together, as a more or less slippery ground would. The drive's
# calibrated ICR expansion, the latency and the actuator noise belong to the robot and stay.
SLIP_COEFFICIENTS = (
    "icr_expansion_per_roughness",
    "icr_x",
    "longitudinal_slip",
    "slip_per_roughness",
    "slip_per_slope",
    "cross_slope_drift",
)


def _slip_scaled(value: Any, current: Any) -> Any:
    """robot.skid with every slip coefficient times `value` (1: as configured, 0: no slip)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise ValueError(f"slip is a factor >= 0 on robot.skid's slip coefficients, got {value!r}")
    return {**current, **{key: current[key] * value for key in SLIP_COEFFICIENTS}}


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One sweepable quantity: which config it changes, the key, and how a written value maps to it."""

    target: Literal["world", "nav"]
    key: str
    unit: str
    meaning: str
    to_key: Callable[[Any, Any], Any] = _as_written  # (value as written, the key's base value) -> new value


PARAMETERS: dict[str, Parameter] = {
    "curve_radius": Parameter(
        "world",
        "rows.curve_radius",
        "m",
        "radius of the rows' bend after rows.curve_start ('straight' or 0: none)",
        _radius,
    ),
    "row_spacing": Parameter("world", "rows.spacing", "m", "distance between neighbouring rows"),
    "crown_bottom": Parameter(
        "world",
        "plants.canopy_bottom",
        "m",
        "lowest leaves above the ground (the base range moved to start here)",
        _range_from,
    ),
    "gap_probability": Parameter("world", "plants.gap_probability", "", "chance that a plant is missing"),
    "roughness": Parameter("world", "terrain.roughness", "m", "terrain height standard deviation"),
    "cross_slope": Parameter("world", "terrain.slope", "dz/dy", "ground slope across the rows", _across),
    "start_offset": Parameter("nav", "run.start_lateral_max", "m", "start offsets drawn uniformly within +-value"),
    "heading_error": Parameter(
        "nav", "run.start_heading_max_deg", "deg", "start heading errors drawn uniformly within +-value"
    ),
    "depth_noise": Parameter(
        "nav", "perception.depth_noise_scale", "x", "depth noise, in multiples of the D435i-like model"
    ),
    "seg_dropout": Parameter(
        "nav",
        "perception.mask_dropout",
        "",
        "share of masks corrupted (perception.mask_dropout_mode), a weaker segmenter",
    ),
    "latency": Parameter("nav", "robot.skid.latency_ticks", "ticks", "command latency of the skid-steer robot"),
    "slip": Parameter(
        "nav",
        "robot.skid",
        "x",
        "how slippery the ground is: every slip coefficient of the skid-steer robot "
        f"({', '.join(SLIP_COEFFICIENTS)}) times the value (1: as configured, 0: no slip)",
        _slip_scaled,
    ),
    "cross_slope_drift": Parameter(
        "nav",
        "robot.skid.cross_slope_drift",
        "",
        "sideways creep downhill of the skid-steer robot, v_y = -value tan(roll) |v_x| "
        "(acts only on a base with a cross slope)",
    ),
    "robot_model": Parameter("nav", "robot.model", "", "kinematic unicycle or skid_steer"),
}


@dataclasses.dataclass
class SweepSpec:
    """A sweep file: the base, what to run, and the parameters with their values (in plot order)."""

    base: str  # shipped world name or world spec YAML path
    parameters: dict[str, list[Any]]  # name (PARAMETERS) -> values, easiest first
    model: str = "oracle"  # or an exported .onnx file, or a shipped model name (vineyards, trees)
    methods: list[str] = dataclasses.field(default_factory=lambda: list(METHODS))
    runs: int = 2  # seeded runs per value and method (seeds shared across values)
    seed: int = 0
    robot: Literal["kinematic", "skid_steer"] = "skid_steer"  # the harder robot unless a spec says otherwise
    nav_config: str = "default"  # shipped nav config name or path
    overrides: list[str] = dataclasses.field(default_factory=list)  # nav config key=value for every variant

    def __post_init__(self) -> None:
        if not self.parameters:
            raise ValueError("parameters: name at least one parameter to sweep")
        unknown = sorted(set(self.parameters) - set(PARAMETERS))
        if unknown:
            raise ValueError(f"parameters: unknown {unknown}; known: {', '.join(PARAMETERS)}")
        for name, values in self.parameters.items():
            if not values:
                raise ValueError(f"parameters.{name}: empty value list")
            labels = [value_label(v) for v in values]
            if len(set(labels)) != len(labels):
                raise ValueError(f"parameters.{name}: repeated value in {labels}")
        check_runs(self.methods, self.runs, self.seed)


def check_runs(methods: list[str], runs: int, seed: int) -> None:
    """The keys every sweep spec has for what it runs: known methods, runs >= 1, seed >= 0."""
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"methods: unknown {bad}; choose from {list(METHODS)}")
    if runs < 1:
        raise ValueError(f"runs: must be >= 1, got {runs}")
    if seed < 0:
        raise ValueError(f"seed: must be >= 0, got {seed}")


def value_label(value: Any) -> str:
    """How a value is written in tables, plots and file names."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


@dataclasses.dataclass
class Variant:
    """The base with one parameter set to one value: the whole world spec and nav config, as data."""

    parameter: str
    value: Any
    world: dict
    config: dict

    @property
    def label(self) -> str:
        return value_label(self.value)

    @property
    def setting(self) -> str:
        """Identity of what the runs see (world and config); equal variants share their runs."""
        return digest({"world": self.world, "config": self.config})


@dataclasses.dataclass
class SweepPlan:
    """Everything a sweep runs, validated."""

    spec: SweepSpec
    where: str  # the sweep file, for messages
    name: str  # the file's stem: the sweep's name in outputs
    base_label: str  # the base field's name (its file stem for a path)
    base_world: dict
    base_config: Any  # NavEvalConfig of every variant before its one change
    variants: list[Variant]


def load_sweep(name_or_path: str | Path) -> tuple[SweepSpec, Path]:
    """A sweep spec (shipped name or YAML path), validated; errors name the file and the key."""
    path = resolve_config("sweeps", name_or_path)
    return from_dict(SweepSpec, read_yaml(path), where=str(path)), path


def plan_sweep(spec: SweepSpec, where: str, overrides: list[str] | tuple[str, ...] = ()) -> SweepPlan:
    """Build and validate every variant (world, nav config, navigators); raises ConfigError naming
    `where` and the parameter. `overrides` (nav config key=value) come after the spec's own."""
    from segmin.data.synth.spec import WorldSpec, load_world_spec
    from segmin.nav_eval.evaluation.evaluate import check_navigators
    from segmin.nav_eval.sim.config import NavEvalConfig, load_nav_config
    from segmin.nav_eval.sim.factories import field_label

    try:
        base = load_world_spec(spec.base)
    except ConfigError as exc:
        raise ConfigError(f"{where}: base: {exc}") from exc
    if base.name.startswith("train_"):
        raise ConfigError(f"{where}: base: {spec.base!r} is a training world ({base.name}); sweep a test field")
    try:
        config = load_nav_config(spec.nav_config, [f"robot.model={spec.robot}", *spec.overrides, *overrides])
    except ConfigError as exc:
        raise ConfigError(f"{where}: nav_config / overrides: {exc}") from exc
    world_raw, config_raw = to_dict(base), to_dict(config)
    variants = []
    for name, values in spec.parameters.items():
        parameter = PARAMETERS[name]
        inert = _inert_reason(name, world_raw, config_raw)
        if inert:
            raise ConfigError(f"{where}: parameters.{name}: {inert}, so every value would drive the same")
        for value in values:
            variant = Variant(name, value, copy.deepcopy(world_raw), copy.deepcopy(config_raw))
            raw, cls, what = (
                (variant.world, WorldSpec, "world")
                if parameter.target == "world"
                else (variant.config, NavEvalConfig, "nav config")
            )
            try:
                _set(raw, parameter, value)
                checked = from_dict(cls, raw, where=what)
                if parameter.target == "nav":
                    check_navigators(base, field_label(spec.base), spec.methods, checked)
            except (ConfigError, ValueError) as exc:
                raise ConfigError(
                    f"{where}: parameters.{name}: value {variant.label} makes an invalid "
                    f"{what} ({' '.join(str(exc).split())})"
                ) from exc
            # As validated (5 -> 5.0): a value equal to the base's then gives the base's setting.
            if parameter.target == "world":
                variant.world = to_dict(checked)
            else:
                variant.config = to_dict(checked)
            variants.append(variant)
    check_navigators(base, field_label(spec.base), spec.methods, config)
    return SweepPlan(spec, where, Path(where).stem, field_label(spec.base), world_raw, config, variants)


def _inert_reason(name: str, world: dict, config: dict) -> str | None:
    """Why sweeping `name` from this base changes nothing the robot meets (None: it does)."""
    if PARAMETERS[name].key.startswith("robot.skid") and config["robot"]["model"] != "skid_steer":
        return f"robot.skid acts on the skid-steer robot only and this sweep's robot is {config['robot']['model']}"
    if name == "cross_slope_drift" and world["terrain"]["slope"][1] == 0:
        return "the base field has no cross slope (terrain.slope[1] = 0) for the creep to act on"
    return None


def _set(raw: dict, parameter: Parameter, value: Any) -> None:
    """Set the parameter's key in a plain config mapping (the key exists: `to_dict` wrote them all)."""
    *sections, last = parameter.key.split(".")
    node = raw
    for section in sections:
        node = node[section]
    node[last] = parameter.to_key(value, node[last])


def variant_file_name(base_label: str, variant: Variant) -> str:
    """A file name for a variant's world spec: base, parameter, value."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", f"{base_label}-{variant.parameter}-{variant.label}") + ".yaml"
