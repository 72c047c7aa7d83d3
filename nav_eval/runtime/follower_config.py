"""`FollowerConfig`: everything the robot runtime is set up with, one typed object that nav-eval,
`segmin replay` and the ROS 2 node all load, so a setting tried in simulation is the same key on
the robot. In YAML:

    method: segmind           # segmin, segmind, segzeros (the paper's) or segcorridor
    navigator:                # NavigatorConfig's fields, or CorridorConfig's for segcorridor
      depth_threshold: 5.0
    runtime:                  # RuntimeConfig: rates, timing limits and its sensor `checks`
      segment_hz: 20
      checks: {max_depth_m: 20.0}
    camera:                   # CameraConfig: the mount, and the intrinsics unless the camera gives them
      mount_height: 0.40

The navigator is a tagged choice: `method` says which class the `navigator` section builds, and
the section takes that class's fields only (a SegCorridor key under a SegMinD config is a typo,
refused with the key's name rather than ignored). The fields are read from the dataclasses, never
listed here, so a navigator that gains or loses a setting is configured the new way everywhere.
`make_navigator` is the one place a config becomes a navigator.

Loading goes through `segmin.common.config` (unknown keys, wrong types and out-of-range values
raise `ConfigError`, one line naming the key); `load_follower_config` also reads the follower out
of a ROS 2 parameter file (`node: ros__parameters: follower: ...`), so the robot's own file
replays offline unchanged.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from segmin.common.config import ConfigError, apply_overrides, check_removed_keys, from_dict, read_yaml, to_dict

from .camera import CameraGeometry
from .corridor import CorridorConfig, CorridorNavigator
from .follower import RuntimeConfig
from .methods import METHODS, PAPER_METHODS
from .navigator import Navigator, NavigatorConfig
from .protocols import MaskNavigator
from .sensor_faults import check_depth_range

DEFAULT_METHOD = "segmind"
SECTIONS = ("method", "navigator", "runtime", "camera")
INTRINSICS = ("width", "height", "fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class CameraConfig:
    """The camera a navigator places its pixels with (SegCorridor; the paper's methods need none).

    The mount (height, tilt, forward offset from the robot's origin) is in no camera message, so
    it is always configured; the defaults are the paper's Jackal with its D435 (as the simulator's
    camera). The intrinsics are 0 when the camera itself gives them: a CameraInfo topic on the
    robot or in a bag, the simulator's camera in nav-eval; set all six to fix them instead.
    """

    width: int = 0
    height: int = 0
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    mount_height: float = 0.40
    tilt_deg: float = 15.0
    mount_forward: float = 0.2

    def __post_init__(self) -> None:
        if self.intrinsics_given:
            unset = [name for name in INTRINSICS if not getattr(self, name)]
            if unset:
                raise ValueError(
                    f"{unset[0]}: unset beside the other intrinsics: give all six, or none (0: from the camera)"
                )
            self.geometry()  # valid together
        else:  # the mount alone, on a stand-in image
            self.mounted(width=1, height=1, fx=1.0, fy=1.0, cx=0.0, cy=0.0)

    @property
    def intrinsics_given(self) -> bool:
        """The intrinsics are set here (any of the six non-zero), not taken from the camera."""
        return any(getattr(self, name) for name in INTRINSICS)

    def geometry(self) -> CameraGeometry:
        """The camera of the config's own intrinsics (ValueError naming the field when one is unset or wrong)."""
        return self.mounted(**{name: getattr(self, name) for name in INTRINSICS})

    def mounted(self, *, width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> CameraGeometry:
        """A camera of the given intrinsics (a CameraInfo's, the simulator's) on this config's mount
        (ValueError naming the field, "camera fx must be ...")."""
        return CameraGeometry(
            width=width,
            height=height,
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
            mount_height=self.mount_height,
            tilt_deg=self.tilt_deg,
            mount_forward=self.mount_forward,
        )


NavigatorChoice = NavigatorConfig | CorridorConfig


@dataclass(frozen=True)
class FollowerConfig:
    """The navigator (its class is the method: `NavigatorConfig` or `CorridorConfig`), the
    runtime's rates and checks, and the camera. `method` is read off the navigator, so the two
    cannot disagree."""

    navigator: NavigatorChoice
    runtime: RuntimeConfig = field(default_factory=RuntimeConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)

    def __post_init__(self) -> None:
        if not isinstance(self.navigator, (NavigatorConfig, CorridorConfig)):
            raise ValueError(f"navigator must be a NavigatorConfig or a CorridorConfig, got {self.navigator!r}")
        try:
            check_depth_range(self.navigator.depth_threshold, self.runtime.checks)
        except ValueError as exc:  # named here: RowFollower would refuse it later, unnamed
            raise ValueError(f"navigator.depth_threshold: {exc} (runtime.checks.max_depth_m)") from None

    @property
    def method(self) -> str:
        return "segcorridor" if isinstance(self.navigator, CorridorConfig) else self.navigator.method


def navigator_class(method: str) -> type[NavigatorChoice]:
    """The config class of `method`'s navigator (ValueError naming the methods for another)."""
    if method not in METHODS:
        raise ValueError(f"method: {method!r} is not one of {', '.join(METHODS)}")
    return NavigatorConfig if method in PAPER_METHODS else CorridorConfig


def navigator_fields(method: str) -> tuple[str, ...]:
    """The keys of `method`'s `navigator` section: its config class's fields, `method` aside."""
    return tuple(f.name for f in dataclasses.fields(navigator_class(method)) if f.init and f.name != "method")


def navigator_from_dict(method: str, raw: Any, where: str = "navigator") -> NavigatorChoice:
    """`method`'s navigator config from its section (ConfigError naming `where` and the key;
    ValueError for an unknown method)."""
    cls = navigator_class(method)
    if not isinstance(raw, dict):
        return from_dict(cls, raw, where=where)  # refused, naming `where`
    if "method" in raw:
        raise ConfigError(f"{where}.method: the method is chosen once, by the follower's `method`")
    check_removed_keys(cls, raw, where)  # a setting that was removed: says so, and why
    fields = navigator_fields(method)
    unknown = sorted(set(raw) - set(fields))
    if unknown:  # named with the method: a key of the other navigator is the likely slip
        raise ConfigError(f"{where}: unknown key(s) {unknown} for method {method}; allowed: {sorted(fields)}")
    # The loader refuses non-finite numbers, but an infinite default means "off" (SegCorridor's
    # row_start_max): that value, written out, reads back.
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    off: dict[str, Any] = {
        k: v for k, v in raw.items() if isinstance(v, float) and math.isinf(v) and defaults.get(k) == v
    }
    finite = {k: v for k, v in raw.items() if k not in off}
    config = from_dict(cls, {"method": method, **finite} if cls is NavigatorConfig else finite, where=where)
    return dataclasses.replace(config, **off) if off else config


def follower_from_dict(raw: Any, where: str = "follower") -> FollowerConfig:
    """A FollowerConfig from its mapping (`SECTIONS`; ConfigError naming `where` and the key)."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(raw).__name__}")
    unknown = sorted(set(raw) - set(SECTIONS))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(SECTIONS)}")
    method = raw.get("method", DEFAULT_METHOD)
    try:
        navigator_class(method)
    except ValueError as exc:
        raise ConfigError(f"{where}.{exc}") from None
    if "navigator" not in raw:
        raise ConfigError(f"{where}.navigator: missing (it needs at least depth_threshold)")
    navigator = navigator_from_dict(method, raw["navigator"], f"{where}.navigator")
    runtime = from_dict(RuntimeConfig, raw.get("runtime") or {}, where=f"{where}.runtime")
    camera = from_dict(CameraConfig, raw.get("camera") or {}, where=f"{where}.camera")
    try:
        return FollowerConfig(navigator, runtime, camera)
    except ValueError as exc:
        raise ConfigError(f"{where}.{exc}") from None


def follower_to_dict(config: FollowerConfig) -> dict[str, Any]:
    """The plain mapping `follower_from_dict` reads back (`method` at the top, not in `navigator`)."""
    navigator = {k: v for k, v in to_dict(config.navigator).items() if k != "method"}
    return {"method": config.method, "navigator": navigator, **{k: to_dict(getattr(config, k)) for k in SECTIONS[2:]}}


def follower_section(raw: dict[str, Any]) -> tuple[dict[str, Any], str]:
    """(the follower mapping, where it sits) of a follower file or of a ROS 2 parameter file
    (`node: ros__parameters: follower: ...`), so the robot's file replays as it is."""
    if len(raw) == 1:
        ((node, section),) = raw.items()
        if isinstance(section, dict) and isinstance(section.get("ros__parameters"), dict):
            params = section["ros__parameters"]
            if "follower" not in params:
                raise ConfigError(f"{node}.ros__parameters: no follower section")
            return params["follower"], f"{node}.ros__parameters.follower"
    return raw, "follower"


def load_follower_config(path: str | Path | None, overrides: Iterable[str] = ()) -> FollowerConfig:
    """A FollowerConfig from a YAML file (None: an empty one) with `key=value` overrides on top
    (`method=segcorridor`, `navigator.depth_threshold=8`); ConfigError names the file and the key."""
    raw, where = follower_section(read_yaml(path)) if path is not None else ({}, "follower")
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: {where}: expected a mapping, got {type(raw).__name__}")
    prefix = f"{path}: " if path is not None else ""
    try:
        return follower_from_dict(apply_overrides(raw, tuple(overrides)), where)
    except ConfigError as exc:
        raise ConfigError(f"{prefix}{exc}") from None


def make_navigator(config: FollowerConfig, camera: CameraGeometry | None = None) -> MaskNavigator:
    """The navigator of `config`: the paper's `Navigator`, or SegCorridor on `camera` (the
    delivered frames' camera: the simulator's, a CameraInfo's; None: the config's own intrinsics).
    ValueError when SegCorridor has no camera: it cannot place a pixel without the intrinsics."""
    navigator = config.navigator
    if isinstance(navigator, NavigatorConfig):
        return Navigator(navigator)
    if camera is None:
        if not config.camera.intrinsics_given:
            raise ValueError(
                "camera: segcorridor needs the camera intrinsics: from the camera (a CameraInfo) or "
                f"camera.{', camera.'.join(INTRINSICS)}"
            )
        camera = config.camera.geometry()
    return CorridorNavigator(navigator, camera)
