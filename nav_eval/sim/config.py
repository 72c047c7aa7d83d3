"""The closed-loop evaluation config (`configs/nav/default.yaml`), validated by segmin.common.config.

Every number of the simulation a user may change lives here: rates, robot limits, run length,
start noise, depth thresholds per field. The navigator's own constants (v_max, omega_gain, ...)
are the paper's and live in `NavigatorConfig`; the `navigator` section may override them, and
its keys are checked against `NavigatorConfig` at load time.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Literal

from segmin.data.canopy_region import check_closing_radius
from segmin.nav_eval.runtime.sensor_faults import SensorChecks, check_depth_range
from segmin.nav_eval.sim.robot import RobotConfig

DEFAULT_CONFIG = "default"  # the shipped configs/nav/default.yaml


@dataclasses.dataclass
class Rates:
    """Simulated-time rates in Hz (the paper: camera 30, inference 20, commands 5).

    The physics tick must be a whole multiple of every other rate, so all events fall on ticks.
    """

    physics_hz: int = 60
    camera_hz: int = 30
    segment_hz: int = 20
    command_hz: int = 5

    def __post_init__(self) -> None:
        for name in ("physics_hz", "camera_hz", "segment_hz", "command_hz"):
            if getattr(self, name) <= 0:
                raise ValueError(f"rates.{name} must be > 0")
        for name in ("camera_hz", "segment_hz", "command_hz"):
            if self.physics_hz % getattr(self, name):
                raise ValueError(f"rates.physics_hz ({self.physics_hz}) must be a multiple of rates.{name}")
        if self.segment_hz % self.command_hz:
            raise ValueError(
                f"rates.segment_hz ({self.segment_hz}) must be a multiple of rates.command_hz "
                f"({self.command_hz}): every command falls on a segmentation deadline"
            )


@dataclasses.dataclass
class Perception:
    """How masks reach the navigator."""

    fuse_frames: int = 3  # OR of the last N segmentation masks (paper: 3)
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
        if self.fuse_frames < 1:
            raise ValueError("perception.fuse_frames must be >= 1")
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


FAULT_KINDS = ("depth_dropout", "zero_depth", "frozen_frame", "black_frame")
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


@dataclasses.dataclass
class NavEvalConfig:
    """The whole evaluation config."""

    rates: Rates = dataclasses.field(default_factory=Rates)
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
    navigator: dict[str, Any] = dataclasses.field(default_factory=dict)
    corridor: dict[str, Any] = dataclasses.field(default_factory=dict)  # SegCorridor (nav_eval.corridor)
    # The runtime's sensor checks (nav_eval.runtime.sensor_faults): each fault stops the robot.
    sensor_checks: SensorChecks = dataclasses.field(default_factory=SensorChecks)
    # Sensor faults injected into every run (nav_eval.sim.faults), none by default.
    faults: list[SimFault] = dataclasses.field(default_factory=list)

    def __post_init__(self) -> None:
        for table in (self.depth_thresholds, self.family_depth_thresholds):
            for k, v in table.items():
                if not isinstance(v, (int, float)) or v <= 0:
                    raise ValueError(f"depth threshold for {k!r} must be > 0, got {v!r}")
        for section in ("navigator", "corridor"):
            _check_section(section, getattr(self, section), self.perception.fuse_frames)
        check_faults(self.faults)
        for name, threshold in {**self.depth_thresholds, **self.family_depth_thresholds}.items():
            try:
                check_depth_range(threshold, self.sensor_checks)
            except ValueError as exc:
                raise ValueError(f"depth threshold for {name!r}: {exc} (sensor_checks.max_depth_m)") from None

    def depth_threshold(self, name: str, family: str) -> float:
        """The depth cut for a field: by name, else by crop family."""
        if name in self.depth_thresholds:
            return float(self.depth_thresholds[name])
        if family in self.family_depth_thresholds:
            return float(self.family_depth_thresholds[family])
        raise ValueError(f"no depth threshold for field {name!r} (family {family!r}); add it to depth_thresholds")


def _check_section(section: str, values: dict[str, Any], fuse_frames: int) -> None:
    """The `navigator` / `corridor` overrides, built into NavigatorConfig / CorridorConfig.

    Building them checks the values too (ranges and limits that only fail together), when the
    config loads: the evaluation builds them per field, after a pipeline's render and training.
    The depth threshold is the evaluation's, per field; no other check depends on it, so any
    valid one stands in for it here.
    """
    forbidden = {"method", "depth_threshold", "fuse_frames"} & set(values)
    if forbidden:
        raise ValueError(f"{section}: {sorted(forbidden)} are set by the evaluation, not the config")
    try:
        if section == "navigator":
            from segmin.nav_eval.runtime.navigator import NavigatorConfig as Target
        else:
            from segmin.nav_eval.runtime.corridor import CorridorConfig as Target
    except ImportError:  # navigator not installed yet: checked when a run builds it
        return
    from segmin.common.config import check_removed_keys

    check_removed_keys(Target, values, section)  # a key that was removed: says so, in one line
    allowed = {f.name for f in dataclasses.fields(Target)} - {"method", "depth_threshold", "fuse_frames"}
    unknown = sorted(set(values) - allowed)
    if unknown:
        raise ValueError(f"{section}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    method = {"method": "segmind"} if section == "navigator" else {}
    try:
        Target(**method, depth_threshold=1.0, fuse_frames=fuse_frames, **values)
    except ValueError as exc:
        message = str(exc)
        raise ValueError(message if message.startswith(f"{section}.") else f"{section}.{message}") from exc


def load_nav_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> NavEvalConfig:
    """Load the evaluation config (a shipped name or a YAML path; the shipped default when None)."""
    from segmin.common.config import load_config
    from segmin.common.shipped import resolve_config

    return load_config(NavEvalConfig, resolve_config("nav", DEFAULT_CONFIG if path is None else path), overrides)
