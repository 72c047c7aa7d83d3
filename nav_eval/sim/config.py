"""The closed-loop evaluation config (`configs/nav/default.yaml`), validated by segmin.common.config.

Every number of the simulation a user may change lives here: rates, robot limits, run length,
start noise, depth thresholds per field. The robot runtime's own settings are its
`FollowerConfig` (nav_eval.runtime.follower_config), under `follower:` with the same keys as
`segmin replay --follower` and the ROS 2 node, but for two things each run sets: the method
(from `--methods`) and the depth threshold (from the field). As one evaluation drives several
methods, it keeps the settings of both kinds of navigator: `follower.navigator` for the paper's
three, `follower.corridor` for SegCorridor.

The keys before the follower config (`rates.segment_hz`, `rates.command_hz`,
`perception.fuse_frames`, `navigator`, `corridor`, `sensor_checks`) are still read, for one
release, with a one-line deprecation warning (`migrate_old_keys`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path
from typing import Any, Literal

from segmin.common.config import ConfigError
from segmin.data.canopy_region import check_closing_radius
from segmin.nav_eval.runtime.corridor import CorridorConfig
from segmin.nav_eval.runtime.follower import RuntimeConfig
from segmin.nav_eval.runtime.follower_config import (
    INTRINSICS,
    CameraConfig,
    FollowerConfig,
    navigator_class,
    navigator_from_dict,
)
from segmin.nav_eval.runtime.sensor_faults import check_depth_range
from segmin.nav_eval.sim.robot import RobotConfig

log = logging.getLogger(__name__)

DEFAULT_CONFIG = "default"  # the shipped configs/nav/default.yaml


@dataclasses.dataclass
class Rates:
    """Simulated-time rates in Hz (the paper: physics 60, camera 30); the runtime's own rates
    (inference 20, commands 5) are `follower.runtime`'s.

    The physics tick must be a whole multiple of every other rate, so all events fall on ticks.
    """

    physics_hz: int = 60
    camera_hz: int = 30

    def __post_init__(self) -> None:
        for name in ("physics_hz", "camera_hz"):
            if getattr(self, name) <= 0:
                raise ValueError(f"rates.{name} must be > 0")
        if self.physics_hz % self.camera_hz:
            raise ValueError(f"rates.physics_hz ({self.physics_hz}) must be a multiple of rates.camera_hz")


@dataclasses.dataclass
class Perception:
    """How masks reach the navigator."""

    width: int | None = None  # camera resolution override (None: the CameraModel default, 224)
    height: int | None = None
    depth_noise: bool = True  # the D435i-like depth-noise model of data.synth.camera
    depth_noise_scale: float = 1.0  # multiplies that model's sigma coefficient and dropout share
    # Where the noise's random draws come from (data.synth.noise_field): "pixels" per pixel (the
    # reference), "field" a window of fixed random fields (the same model, a fraction of the time),
    # "auto" field with the gl backend (the fast path), pixels with TinyRenderer.
    depth_noise_sampling: Literal["auto", "pixels", "field"] = "auto"
    # A weaker segmenter, simulated: this share of the masks is corrupted (nav_eval.mask_dropout),
    # "erode" shrinks the vegetation (missed leaves), "drop" empties the mask (a lost inference).
    mask_dropout: float = 0.0
    mask_dropout_mode: Literal["erode", "drop"] = "erode"
    # The masks closed with a disc of this radius (px) before the navigator (and any dropout)
    # sees them (nav_eval.sim.mask_closing): with the oracle and the models' data.label_closing,
    # a perfect model of the canopy-region label. 0: the masks as the segmenter gives them.
    mask_closing: int = 0
    # The robot's IMU roll and pitch reach the navigator (SegCorridor levels its depth points
    # with them; the paper's methods do not use them). false: level ground is assumed.
    imu: bool = True

    def __post_init__(self) -> None:
        if self.depth_noise_scale < 0:
            raise ValueError(f"perception.depth_noise_scale must be >= 0, got {self.depth_noise_scale}")
        if self.depth_noise_sampling not in ("auto", "pixels", "field"):
            raise ValueError(
                f"perception.depth_noise_sampling must be auto, pixels or field, got {self.depth_noise_sampling!r}"
            )
        if not 0.0 <= self.mask_dropout <= 1.0:
            raise ValueError(f"perception.mask_dropout must be within [0, 1], got {self.mask_dropout}")
        check_closing_radius(self.mask_closing, "perception.mask_closing")
        for name in ("width", "height"):
            v = getattr(self, name)
            if v is not None and v < 8:
                raise ValueError(f"perception.{name} must be >= 8, got {v}")


@dataclasses.dataclass
class RunSettings:
    """Start, goal and the failure rules of one run."""

    length_m: float = 20.0  # distance to cover along the row (success)
    start_s: float = 0.0  # where on the centreline a run starts (0 = row entrance)
    time_limit_s: float = 120.0  # failure "timeout" past this
    start_lateral_max: float = 0.15  # uniform start offset in [-max, max], m
    start_heading_max_deg: float = 5.0  # uniform heading error in [-max, max], deg
    stall_time_s: float = 20.0  # failure "stalled" when progress over this window ...
    stall_distance_m: float = 0.25  # ... is below this distance
    gap: int | None = None  # which row gap (None: the middle one)
    back_margin_m: float = 1.0  # failure "left_row" when this far behind the start

    def __post_init__(self) -> None:
        if self.length_m <= 0 or self.time_limit_s <= 0:
            raise ValueError("run.length_m and run.time_limit_s must be > 0")
        if self.start_lateral_max < 0 or self.start_heading_max_deg < 0:
            raise ValueError("run.start_lateral_max and run.start_heading_max_deg must be >= 0")
        if self.stall_time_s <= 0 or self.stall_distance_m < 0:
            raise ValueError("run.stall_time_s must be > 0 and run.stall_distance_m >= 0")
        if self.back_margin_m < 0:  # the "left_row" line would lie ahead of the start: every run fails at t = 0
            raise ValueError(f"run.back_margin_m must be >= 0, got {self.back_margin_m}")


@dataclasses.dataclass
class RenderSettings:
    """Which rasteriser draws the camera frames (data.synth.render): `tiny` (pybullet's TinyRenderer,
    the reference), `gl` (OpenGL through EGL, several times faster, same masks and depth), or None
    for each field's own `render.backend`."""

    backend: Literal["tiny", "gl"] | None = None


FAULT_KINDS = ("depth_dropout", "zero_depth", "frozen_frame", "frozen_depth", "black_frame")
REGIONS = ("all", "left", "right")


@dataclasses.dataclass
class SimFault:
    """One fault: `kind` (FAULT_KINDS) from `start_s` for `duration_s` seconds of the run."""

    kind: str
    start_s: float
    duration_s: float
    region: str = "all"  # depth faults: the whole image or one half
    share: float = 1.0  # depth_dropout: share of the region's pixels that read NaN

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"kind {self.kind!r} is not one of {', '.join(FAULT_KINDS)}")
        if not (math.isfinite(self.start_s) and self.start_s >= 0):
            raise ValueError(f"start_s must be a number of seconds >= 0, got {self.start_s!r}")
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f"duration_s must be a number of seconds > 0, got {self.duration_s!r}")
        if self.region not in REGIONS:
            raise ValueError(f"region {self.region!r} is not one of {', '.join(REGIONS)}")
        if self.region != "all" and self.kind not in ("depth_dropout", "zero_depth"):
            raise ValueError(f"region {self.region!r} applies to depth faults only, not {self.kind}")
        if not 0.0 < self.share <= 1.0:
            raise ValueError(f"share must be within (0, 1], got {self.share!r}")
        if self.share != 1.0 and self.kind != "depth_dropout":
            raise ValueError(f"share applies to depth_dropout only, not {self.kind} (which spoils its whole region)")

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    def active(self, t: float) -> bool:
        """Whether a frame at run time `t` (seconds) is spoilt."""
        return self.start_s <= t < self.end_s


def check_faults(faults: list[SimFault]) -> None:
    """Fault windows must not overlap: each fault's metrics need a window of its own."""
    for i, fault in enumerate(faults):
        for other in faults[i + 1 :]:
            if fault.start_s < other.end_s and other.start_s < fault.end_s:
                raise ValueError(
                    f"faults: {fault.kind} at {fault.start_s:g}-{fault.end_s:g} s overlaps "
                    f"{other.kind} at {other.start_s:g}-{other.end_s:g} s"
                )


# What each run sets, not the config: the method (--methods) and the depth cut (the field's).
RUN_SET = ("method", "depth_threshold")
STAND_IN_THRESHOLD = 1.0  # any valid depth cut, to check a navigator section before the fields are known


@dataclasses.dataclass
class EvalFollower:
    """The robot runtime nav-eval drives: `FollowerConfig`'s sections less what each run sets
    (`RUN_SET`), with both navigators' settings since one evaluation drives both: `navigator`
    (NavigatorConfig's fields) for SegMin, SegMinD and SegZeros, `corridor` (CorridorConfig's)
    for SegCorridor. The camera's intrinsics are the simulator's (perception.width / height):
    only its mount is set here, and the simulated camera is mounted the same way."""

    runtime: RuntimeConfig = dataclasses.field(default_factory=RuntimeConfig)
    navigator: dict[str, Any] = dataclasses.field(default_factory=dict)
    corridor: dict[str, Any] = dataclasses.field(default_factory=dict)
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)

    def __post_init__(self) -> None:
        given = [name for name in INTRINSICS if getattr(self.camera, name)]
        if given:
            raise ValueError(
                f"camera.{given[0]}: the simulator's camera gives the intrinsics (perception.width / height); "
                "only the mount (mount_height, tilt_deg, mount_forward) is set here"
            )
        for section, method in (("navigator", "segmind"), ("corridor", "segcorridor")):
            values = getattr(self, section)
            forbidden = sorted(set(RUN_SET) & set(values))
            if forbidden:
                raise ValueError(f"{section}: {forbidden} are set by each run, not the config")
            navigator_from_dict(method, {"depth_threshold": STAND_IN_THRESHOLD, **values}, section)

    def config(self, method: str, depth_threshold: float) -> FollowerConfig:
        """The FollowerConfig of one run: `method` with the field's `depth_threshold`."""
        section = self.corridor if navigator_class(method) is CorridorConfig else self.navigator
        navigator = navigator_from_dict(method, {"depth_threshold": depth_threshold, **section}, "follower.navigator")
        return FollowerConfig(navigator, self.runtime, self.camera)


@dataclasses.dataclass
class NavEvalConfig:
    """The whole evaluation config."""

    rates: Rates = dataclasses.field(default_factory=Rates)
    follower: EvalFollower = dataclasses.field(default_factory=EvalFollower)
    robot: RobotConfig = dataclasses.field(default_factory=RobotConfig)
    perception: Perception = dataclasses.field(default_factory=Perception)
    run: RunSettings = dataclasses.field(default_factory=RunSettings)
    render: RenderSettings = dataclasses.field(default_factory=RenderSettings)
    # Paper section 2: 5 m vineyards, 8 m pear and pergola, 10 m tall trees.
    depth_thresholds: dict[str, float] = dataclasses.field(
        default_factory=lambda: {
            "straight_vineyard": 5.0,
            "curved_vineyard": 5.0,
            "pergola_vineyard": 8.0,
            "pear_field": 8.0,
            "high_trees": 10.0,
        }
    )
    # For user fields not named above: by WorldSpec.family.
    family_depth_thresholds: dict[str, float] = dataclasses.field(
        default_factory=lambda: {"vineyards": 5.0, "trees": 8.0}
    )
    # Sensor faults injected into every run (nav_eval.sim.faults), none by default.
    faults: list[SimFault] = dataclasses.field(default_factory=list)

    def __post_init__(self) -> None:
        for table in (self.depth_thresholds, self.family_depth_thresholds):
            for k, v in table.items():
                if not isinstance(v, (int, float)) or v <= 0:
                    raise ValueError(f"depth threshold for {k!r} must be > 0, got {v!r}")
        runtime = self.follower.runtime
        for name in ("segment_hz", "command_hz"):
            if self.rates.physics_hz % getattr(runtime, name):
                raise ValueError(
                    f"rates.physics_hz ({self.rates.physics_hz}) must be a multiple of follower.runtime.{name}"
                )
        check_faults(self.faults)
        for name, threshold in {**self.depth_thresholds, **self.family_depth_thresholds}.items():
            try:
                check_depth_range(threshold, runtime.checks)
            except ValueError as exc:
                raise ValueError(f"depth threshold for {name!r}: {exc} (follower.runtime.checks.max_depth_m)") from None

    def depth_threshold(self, name: str, family: str) -> float:
        """The depth cut for a field: by name, else by crop family."""
        if name in self.depth_thresholds:
            return float(self.depth_thresholds[name])
        if family in self.family_depth_thresholds:
            return float(self.family_depth_thresholds[family])
        raise ValueError(f"no depth threshold for field {name!r} (family {family!r}); add it to depth_thresholds")


# Keys of the config before the follower config -> where they are now (read for one release).
OLD_KEYS: dict[tuple[str, ...], tuple[str, ...]] = {
    ("rates", "segment_hz"): ("follower", "runtime", "segment_hz"),
    ("rates", "command_hz"): ("follower", "runtime", "command_hz"),
    ("sensor_checks",): ("follower", "runtime", "checks"),
    ("navigator",): ("follower", "navigator"),
    ("corridor",): ("follower", "corridor"),
}
OLD_FUSE_FRAMES = ("perception", "fuse_frames")  # one window for both navigators then, one each now


def migrate_old_keys(raw: dict[str, Any], where: str = "config") -> dict[str, Any]:
    """`raw` with the keys of the config before the follower config moved to their new places
    (`OLD_KEYS`; `perception.fuse_frames` into both navigator sections) and one warning line
    naming them. A value given both ways is refused (ConfigError naming both keys)."""
    moves = [(old, new) for old, new in OLD_KEYS.items() if _pop(raw, old, probe=True)[0]]
    if _pop(raw, OLD_FUSE_FRAMES, probe=True)[0]:
        moves += [(OLD_FUSE_FRAMES, ("follower", section, "fuse_frames")) for section in ("navigator", "corridor")]
    if not moves:
        return raw
    values = {old: _pop(raw, old)[1] for old in dict(moves)}
    for old, new in moves:
        _merge(raw, new, values[old], f"{where}: {'.'.join(old)} (old) and {'.'.join(new)}")
    _warn_old(where, moves)
    return raw


def migrate_old_overrides(overrides: list[str] | tuple[str, ...]) -> list[str]:
    """The `key=value` overrides with old keys (`OLD_KEYS`, `perception.fuse_frames`) renamed, and
    one warning line naming them; applied after the file's keys, they win over them as before."""
    renamed, moves = [], []
    for item in overrides:
        key, sep, value = item.partition("=")
        parts = tuple(p for p in key.strip().split(".") if p)
        targets = [new + parts[len(old) :] for old, new in OLD_KEYS.items() if parts[: len(old)] == old]
        if parts == OLD_FUSE_FRAMES:
            targets = [("follower", section, "fuse_frames") for section in ("navigator", "corridor")]
        renamed += [".".join(target) + sep + value for target in targets] or [item]
        moves += [(parts, target) for target in targets]
    if moves:
        _warn_old("overrides", moves)
    return renamed


def _warn_old(where: str, moves: list[tuple[tuple[str, ...], tuple[str, ...]]]) -> None:
    log.warning(
        "%s: old nav config keys %s read as %s; they are dropped in the next release",
        where,
        ", ".join(dict.fromkeys(".".join(old) for old, _ in moves)),
        ", ".join(".".join(new) for _, new in moves),
    )


def _pop(raw: dict[str, Any], path: tuple[str, ...], probe: bool = False) -> tuple[bool, Any]:
    """(found, value) of the dotted `path` in `raw`, removed unless `probe`; an emptied parent
    section is removed too (`rates: {}` then reads as the defaults)."""
    parent: Any = raw
    for key in path[:-1]:
        parent = parent.get(key)
        if not isinstance(parent, dict):
            return False, None
    if path[-1] not in parent:
        return False, None
    value = parent[path[-1]] if probe else parent.pop(path[-1])
    if not probe and len(path) > 1 and not parent:
        raw.pop(path[0])
    return True, value


def _merge(raw: dict[str, Any], path: tuple[str, ...], value: Any, conflict: str) -> None:
    """Put `value` at `path`; mappings merge key by key, a key set both ways is a ConfigError."""
    node = raw
    for key in path[:-1]:
        node = node.setdefault(key, {})
        if not isinstance(node, dict):
            raise ConfigError(f"{conflict}: {key!r} is not a section")
    last = path[-1]
    if isinstance(value, dict) and isinstance(node.get(last), dict):
        both = sorted(set(value) & set(node[last]))
        if both:
            raise ConfigError(f"{conflict} both set {both}: keep the new key only")
        node[last].update(value)
    elif last in node and node[last] is not None:
        raise ConfigError(f"{conflict} are both set: keep the new key only")
    else:
        node[last] = value


def load_nav_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> NavEvalConfig:
    """Load the evaluation config (a shipped name or a YAML path; the shipped default when None),
    old keys read with a warning (`migrate_old_keys`)."""
    from segmin.common.config import apply_overrides, from_dict, read_yaml
    from segmin.common.shipped import resolve_config

    resolved = resolve_config("nav", DEFAULT_CONFIG if path is None else path)
    raw = apply_overrides(migrate_old_keys(read_yaml(resolved), str(resolved)), migrate_old_overrides(overrides))
    return from_dict(NavEvalConfig, raw, where=str(resolved))
