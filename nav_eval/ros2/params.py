"""The row-follower node's parameters: names, defaults, checks, and the ROS 2 parameter file.

The runtime's parameters are its `FollowerConfig` (nav_eval.runtime.follower_config), under
`follower.` with the keys nav-eval and `segmin replay --follower` use: `follower.method`,
`follower.navigator.<field>` (NavigatorConfig's fields, or CorridorConfig's for segcorridor),
`follower.runtime.<field>`, `follower.runtime.checks.<field>` and `follower.camera.<field>`
(taken from the dataclasses, so they cannot drift apart). The node adds its own (`NodeSettings`:
model, topics, pairing, outputs, `enabled`). A parameter file is the standard one ROS 2 reads,
nested sections standing for dotted names as ROS reads them:

    segmin_row_follower:
      ros__parameters:
        model: vineyards
        follower:
          method: segmind
          navigator: {depth_threshold: 5.0}

`load_params_file` reads it and `node_params` checks every value (unknown names, wrong types,
out-of-range values: ValueError naming the parameter) before the node starts; the same check
answers a `ros2 param set` while it runs. The method is fixed at start-up: it chooses which
navigator parameters exist. The flat names of the release before (`method`, `v_max`,
`segment_hz`, `camera_fx`, ...) are still read, with one deprecation line (`migrate_flat_names`).
`defaults_yaml` writes the defaults, commented. No ROS import: the checks run, and are tested,
without rclpy.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from segmin.common.config import ConfigError, parse_yaml
from segmin.nav_eval.replay.imu import IMU_MAX_AGE_S
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.corridor import CorridorConfig
from segmin.nav_eval.runtime.follower import RuntimeConfig
from segmin.nav_eval.runtime.follower_config import (
    DEFAULT_METHOD,
    CameraConfig,
    FollowerConfig,
    follower_from_dict,
    follower_to_dict,
    navigator_class,
)
from segmin.nav_eval.runtime.methods import DEPTH_METHODS, METHODS
from segmin.nav_eval.runtime.navigator import NavigatorConfig
from segmin.nav_eval.runtime.sensor_faults import SensorChecks
from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES

log = logging.getLogger(__name__)

NODE_NAME = "segmin_row_follower"
# ROS's own parameters a node always has: passed through to rclpy, not checked here.
ROS_PARAMETERS = ("use_sim_time",)
MAX_PRIORITY = 98  # SCHED_FIFO's 99 is left to the kernel's own threads, as real-time guides advise


@dataclass(frozen=True)
class NodeSettings:
    """What the node adds to the navigator and the runtime (see the docs of each in `DESCRIPTIONS`)."""

    model: str = ""
    threads: int = 2
    inference_spin: bool = False
    enabled: bool = False
    colour_topic: str = topics.COLOUR
    depth_topic: str = topics.DEPTH
    cmd_vel_topic: str = topics.CMD_VEL
    twist_stamped: bool = False
    publish_on_timer: bool = True
    command_priority: int = 0
    base_frame: str = topics.BASE_FRAME
    slop_s: float = 0.01
    publish_overlay: bool = False
    publish_diagnostics: bool = True
    publish_frame_acks: bool = False
    camera_info_topic: str = ""
    imu_topic: str = ""
    imu_max_age_s: float = IMU_MAX_AGE_S
    live_port: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.threads, bool) or not isinstance(self.threads, int) or self.threads < 1:
            raise ValueError(f"threads must be an integer >= 1, got {self.threads!r}")
        if not 0 <= self.command_priority <= MAX_PRIORITY:
            raise ValueError(
                f"command_priority must be 0 (normal scheduling) or a SCHED_FIFO priority 1-{MAX_PRIORITY}, "
                f"got {self.command_priority!r}"
            )
        if not (math.isfinite(self.slop_s) and 0 <= self.slop_s < 0.5):
            raise ValueError(f"slop_s must be a number of seconds within [0, 0.5), got {self.slop_s!r}")
        for name in ("colour_topic", "cmd_vel_topic"):
            if not getattr(self, name):
                raise ValueError(f"{name} must name a topic")
        if not (math.isfinite(self.imu_max_age_s) and self.imu_max_age_s > 0):
            raise ValueError(f"imu_max_age_s must be a number of seconds > 0, got {self.imu_max_age_s!r}")
        if not 0 <= self.live_port <= 65535:
            raise ValueError(f"live_port must be 0 (off) or a TCP port 1-65535, got {self.live_port!r}")


@dataclass(frozen=True)
class NodeParams:
    """Every checked parameter of the node: the runtime's `follower` config and the node's own.

    `navigator` and `runtime` are the follower's; `camera` SegCorridor's camera when the
    intrinsics are parameters (None: from the CameraInfo topic, or a method that needs no camera)."""

    follower: FollowerConfig
    node: NodeSettings

    @property
    def navigator(self) -> NavigatorConfig | CorridorConfig:
        return self.follower.navigator

    @property
    def runtime(self) -> RuntimeConfig:
        return self.follower.runtime

    @property
    def camera(self) -> CameraGeometry | None:
        camera = self.follower.camera
        return camera.geometry() if self.follower.method == "segcorridor" and camera.intrinsics_given else None


# The follower's parameters by field name (the same text for the field of any section that has it);
# a field without an entry is described by its config class (`describe`).
FIELD_DESCRIPTIONS: dict[str, str] = {
    "method": f"navigation method: {', '.join(METHODS)} (segmind and segcorridor need depth_topic; segcorridor "
    "the camera intrinsics: camera_info_topic or follower.camera.width ... cy, and takes the IMU's roll and pitch); "
    "it chooses the navigator's parameters, so it is fixed at start-up",
    "depth_threshold": "depth cut d_th in metres (paper: 5 vineyards, 8 pear rows and pergolas, 10 tall trees)",
    "fuse_frames": "masks ORed per command (paper: 3)",
    "mask_closing": "SegMin, SegMinD, SegZeros: each mask closed with a disc of this radius (px at 224 px of image "
    "width, whatever the camera's) before the fusion, so small holes inside a crown do not read as free columns "
    "(0: off, the paper's; 8 with the shipped trees model)",
    "smooth_window": "columns of the histogram's moving average (odd)",
    "v_max": "top forward speed, m/s",
    "omega_max": "top turn rate, rad/s",
    "omega_gain": "turn rate per pixel of target offset, rad/s/px",
    "ema_lambda": "EMA weight of a new command, (0, 1]",
    "zeros_min_width": "SegZeros: narrowest free run of columns",
    "zeros_startup_border": "SegZeros: share of each image border ignored at start-up",
    "zeros_track_tolerance": "SegZeros: tracking tolerance, share of the width",
    "segment_hz": "segmentation rate on the latest frame (paper: 20)",
    "command_hz": "command rate, divides segment_hz (paper: 5); the stop watchdog runs at this rate too",
    "max_mask_age_s": "a mask older than this at a command is not fused, s",
    "frame_timeout_s": "no paired frame for this long: the robot is stopped, s",
    "min_valid_depth": "stop (depth_invalid) when under this share of the fused mask's vegetation pixels has a valid "
    "depth reading (> 0, finite, <= max_depth_m); 0: off",
    "min_valid_depth_side": "stop (depth_invalid_left / depth_invalid_right) when under this share has a valid "
    "reading on one image half; 0: off",
    "min_judged_pixels": "a share is judged only on at least this many sampled vegetation pixels",
    "max_depth_m": "the depth sensor's range: a reading beyond it is invalid, m",
    "black_level": "a pixel whose every channel is at most this is black (0-255)",
    "white_level": "a pixel whose every channel is at least this is white (0-255)",
    "blank_share": "stop (image_black / image_white) when at least this share of the sampled pixels is black "
    "(white); 0: off",
    "frozen_s": "stop (image_frozen, depth_frozen) when the sampled image or depth pixels stay identical this long "
    "while driving, s",
    "max_clock_offset_s": "stop (clock_offset) when a frame's stamp is further than this from the node's clock "
    "(a bag's own times: play it with --clock and set use_sim_time), s",
    "sample_pixels": "the sensor checks read a regular grid of about this many pixels",
    "width": "SegCorridor's camera intrinsics as parameters (all six set) instead of camera_info_topic: image width, px "
    "(0: intrinsics from camera_info_topic)",
    "height": "image height, px",
    "fx": "focal length in x, px",
    "fy": "focal length in y, px",
    "cx": "principal point x, px",
    "cy": "principal point y, px",
    "mount_height": "SegCorridor: camera height above the ground, m (not in CameraInfo)",
    "tilt_deg": "SegCorridor: camera tilt up from horizontal, degrees",
    "mount_forward": "SegCorridor: camera ahead of base_link, m",
    "controller": "SegCorridor's steering law: pursuit (the default) or centre_hold (for a "
    "skid-steer robot such as the Jackal: holds the row centre under wheel slip and on cross slopes)",
    "hold_slope_drift": "centre_hold on sloped rows: points the robot uphill by this times tan(roll) from the IMU "
    "against its creep across the slope (0: off; 0.5 for the simulated Jackal; measure your robot's)",
    "row_start_max": "SegCorridor on gappy rows: a row whose points start beyond this many metres ahead, beside a row "
    "seen nearer, is left out (inf: off; 2.5 for sloped, gappy rows)",
    "trim": "SegCorridor's row fit drops points further than this many robust spreads from their row's curve "
    "(2.5; 2.0 for sloped, gappy rows)",
}
# The node's own parameters.
DESCRIPTIONS: dict[str, str] = {
    "model": "exported .onnx file (a relative path is read from the parameter file's folder) or a shipped "
    "model name (vineyards, trees)",
    "threads": "the segmenter's threads (onnxruntime or LiteRT)",
    "inference_spin": "let onnxruntime's threads busy-wait between operations and frames: lower latency on a "
    "computer with a core to spare (image to command 7 instead of 10 ms median on 2 idle cores), but it takes CPU "
    "from the camera driver, DDS and the rest of the robot on a busy one",
    "enabled": "drive: publish commands. Off at start-up (a robot must not move because a node came up); "
    "switch with the ~/enable service (std_srvs/SetBool) or this parameter",
    "colour_topic": "sensor_msgs Image (rgb8, bgr8, rgba8, bgra8) or CompressedImage (jpeg, png): "
    "a CompressedImage topic ends in /compressed",
    "depth_topic": "aligned depth: Image 16UC1 (mm) or 32FC1 (m), or CompressedImage (png, compressedDepth) on "
    "a topic ending in /compressed or /compressedDepth; empty: no depth (segmin, segzeros only)",
    "cmd_vel_topic": "where commands go",
    "twist_stamped": "publish geometry_msgs/TwistStamped (stamped with the image that gave the command) "
    "instead of Twist",
    "publish_on_timer": "true: commands go out from the command_hz timer (a regular period), whose ticks lock "
    "onto the runtime's command deadlines just after a command is usually ready (one that misses its tick goes "
    "out at once); false: a fresh command goes out as soon as it is computed (a little lower latency; its period "
    "jitters with the frames and the inference time; what a player feeding frame by frame needs)",
    "command_priority": "0: the command thread is scheduled as any other; 1-98: it runs SCHED_FIFO at this "
    "priority, so a busy computer does not delay its ticks (needs the rtprio limit or CAP_SYS_NICE; without them "
    "the node logs one line and runs at normal priority)",
    "base_frame": "frame id of TwistStamped commands",
    "slop_s": "colour and depth pair when their stamps differ by at most this, s",
    "publish_overlay": "publish ~/overlay: the camera image with the fused mask and the chosen column",
    "publish_diagnostics": "publish /diagnostics (diagnostic_msgs/DiagnosticArray) once a second",
    "publish_frame_acks": "publish ~/frame_acks (std_msgs/Header, reliable): the header of every image message the "
    "node has handled (stepped, waiting for its partner, or refused), so a bag player can feed the node frame by "
    "frame and a monitor can see which frames it dropped",
    "camera_info_topic": "sensor_msgs/CameraInfo of the colour camera: SegCorridor's intrinsics (k, width, height) "
    "when follower.camera's are not set; empty: not subscribed",
    "imu_topic": "sensor_msgs/Imu: roll and pitch from its orientation (REP 103, IMU level with base_link) for "
    "SegCorridor; empty: not subscribed, level ground assumed",
    "imu_max_age_s": "an IMU message older than this at a frame is stale: ignored (level ground), logged, s",
    "live_port": "stream the live view to Foxglove on ws://127.0.0.1:<this port> (8765: Foxglove's default): the "
    "camera with the mask and target, the histogram, the command and SegCorridor's rows; needs the [live] extra; "
    "0: off",
}
GROUPS = (  # the node's own parameters, in the file's order; the follower section comes after them
    ("driving", ("enabled", "model", "threads", "inference_spin")),
    ("topics", ("colour_topic", "depth_topic", "cmd_vel_topic", "twist_stamped", "base_frame", "slop_s")),
    ("timing", ("publish_on_timer", "command_priority")),
    ("outputs", ("publish_overlay", "publish_diagnostics", "publish_frame_acks", "live_port")),
    ("SegCorridor's inputs: camera intrinsics and IMU", ("camera_info_topic", "imu_topic", "imu_max_age_s")),
)
DEFAULTS: dict[str, Any] = {f.name: f.default for f in dataclasses.fields(NodeSettings)}
# The node's depth cut when none is set (NavigatorConfig has none on purpose): the paper's vineyards'.
DEFAULT_DEPTH_THRESHOLD = 5.0
FOLLOWER = "follower"
# Parameters fixed at start-up (subscriptions and publishers are made from them; the method
# chooses which navigator parameters exist).
STARTUP_ONLY = (
    "command_priority",
    "colour_topic",
    "depth_topic",
    "cmd_vel_topic",
    "twist_stamped",
    "publish_overlay",
    "publish_diagnostics",
    "publish_frame_acks",
    "live_port",
    "camera_info_topic",
    "imu_topic",
    f"{FOLLOWER}.method",
)
SECTION_TITLES = {
    "runtime": "RuntimeConfig: rates and timing limits",
    "checks": "SensorChecks: each fault stops the robot",
    "camera": "CameraConfig: the mount on the robot, and the intrinsics (0: from camera_info_topic)",
}


def _field_names(*classes: type) -> set[str]:
    return {f.name for cls in classes for f in dataclasses.fields(cls) if f.init}


# Every field a follower section may have: a check's message that starts with one names it.
FOLLOWER_FIELDS = _field_names(NavigatorConfig, CorridorConfig, RuntimeConfig, SensorChecks, CameraConfig)


def describe(name: str) -> str:
    """The description of parameter `name` (the node's, or a follower field's by its last part)."""
    leaf = name.rpartition(".")[2]
    if name in DESCRIPTIONS:
        return DESCRIPTIONS[name]
    return FIELD_DESCRIPTIONS.get(leaf, f"{leaf}: see the navigator's config class (the follower config reference)")


def flatten(raw: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested sections as dotted names, as ROS 2 reads a parameter file (`a: {b: 1}` is `a.b`)."""
    flat: dict[str, Any] = {}
    for key, value in raw.items():
        name = f"{prefix}{key}"
        flat.update(flatten(value, f"{name}.") if isinstance(value, dict) and value else {name: value})
    return flat


def _nest(values: dict[str, Any]) -> dict[str, Any]:
    """Dotted names as nested sections (the inverse of `flatten`)."""
    nested: dict[str, Any] = {}
    for name, value in values.items():
        *sections, leaf = name.split(".")
        node = nested
        for section in sections:
            node = node.setdefault(section, {})
        node[leaf] = value
    return nested


def _navigator_names(cls: type) -> set[str]:
    """A navigator config's keys, and those it removed (so that the config names them as removed)."""
    return _field_names(cls) - {"method"} | set(getattr(cls, "REMOVED_KEYS", {}))


def migrate_flat_names(values: dict[str, Any]) -> dict[str, Any]:
    """`values` with the flat names of the release before renamed (`method` -> `follower.method`,
    `v_max` -> `follower.navigator.v_max`, `segment_hz` -> `follower.runtime.segment_hz`,
    `min_valid_depth` -> `follower.runtime.checks.min_valid_depth`, `camera_fx` ->
    `follower.camera.fx`) and one warning line naming them. Navigator names of the other method's
    class (a Jackal file kept SegCorridor's settings beside SegMinD) are dropped, said in the line."""
    method = values.get("method", values.get(f"{FOLLOWER}.method", DEFAULT_METHOD))
    try:
        own = _navigator_names(navigator_class(method))
    except ValueError:
        own = set()  # refused with its name when the config is built
    other = (_navigator_names(NavigatorConfig) | _navigator_names(CorridorConfig)) - own
    runtime, checks, camera = (
        _field_names(RuntimeConfig) - {"checks"},
        _field_names(SensorChecks),
        _field_names(CameraConfig),
    )
    renamed: dict[str, Any] = {}
    moved, dropped = [], []
    for name, value in values.items():
        new = None
        if name == "method":
            new = f"{FOLLOWER}.method"
        elif name in own:
            new = f"{FOLLOWER}.navigator.{name}"
        elif name in runtime:
            new = f"{FOLLOWER}.runtime.{name}"
        elif name in checks:
            new = f"{FOLLOWER}.runtime.checks.{name}"
        elif name.startswith("camera_") and name.removeprefix("camera_") in camera:
            new = f"{FOLLOWER}.camera.{name.removeprefix('camera_')}"
        if new is None and name in other:
            dropped.append(name)
            continue
        if new is not None and new in values:
            raise ValueError(f"parameter {name}: also set as {new}; keep the new name only")
        renamed[new or name] = value
        if new is not None:
            moved.append(name)
    if moved or dropped:
        log.warning(
            "old flat parameter names %s read as follower.*%s; they are dropped in the next release",
            ", ".join(moved),
            f" ({', '.join(dropped)}: not {method}'s, ignored)" if dropped else "",
        )
    return renamed


def _parameter_error(text: str) -> str:
    """A follower config error as the parameter it names ("follower.runtime: segment_hz (20) must
    ..." -> "parameter follower.runtime.segment_hz: segment_hz (20) must ...")."""
    where, _, rest = text.partition(": ")
    field = re.match(r"(?:corridor\.)?(\w+)", rest)
    if field and field.group(1) in FOLLOWER_FIELDS and not where.endswith(f".{field.group(1)}"):
        return f"parameter {where}.{field.group(1)}: {rest}"
    return f"parameter {text}"


def _typed(name: str, value: Any) -> Any:
    """`value` as the type of the default (an integer where a float is due is taken: YAML writes 5 for 5.0)."""
    default = DEFAULTS[name]
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    else:
        ok = isinstance(value, str)
    if not ok:
        raise ValueError(f"parameter {name}: expected {type(default).__name__}, got {value!r}")
    return value


def _node_settings(values: dict[str, Any], base: Path | None) -> NodeSettings:
    """The node's own settings of `values` (the rest default); a relative `model` is taken from `base`."""
    merged = {name: _typed(name, values[name]) if name in values else default for name, default in DEFAULTS.items()}
    shipped_name = merged["model"] in SHIPPED_NAMES  # "vineyards": the installed model, not a file here
    if merged["model"] and base is not None and not shipped_name and not Path(merged["model"]).is_absolute():
        merged["model"] = str(base / merged["model"])
    try:
        return NodeSettings(**merged)
    except ValueError as exc:
        named = next((n for n in DEFAULTS if str(exc).startswith(n)), None)
        raise ValueError(f"parameter {named}: {exc}" if named else f"parameters: {exc}") from None


def _follower(values: dict[str, Any]) -> FollowerConfig:
    """The follower config of the `follower.*` parameters (the depth cut defaults to the vineyards')."""
    raw = _nest({k: v for k, v in values.items() if k.startswith(f"{FOLLOWER}.")}).get(FOLLOWER, {})
    if isinstance(raw.get("navigator", {}), dict):
        raw["navigator"] = {"depth_threshold": DEFAULT_DEPTH_THRESHOLD, **raw.get("navigator", {})}
    try:
        return follower_from_dict(raw, FOLLOWER)
    except ConfigError as exc:
        raise ValueError(_parameter_error(str(exc))) from None


def node_params(values: dict[str, Any], base: Path | None = None) -> NodeParams:
    """Check `values` (any subset of the parameters; the rest default) and build the configs.

    ValueError names the first bad parameter. A relative `model` is taken from `base`. The flat
    names of the release before are read too (`migrate_flat_names`)."""
    values = migrate_flat_names(values)
    unknown = sorted(
        n for n in values if n not in DEFAULTS and n not in ROS_PARAMETERS and not n.startswith(f"{FOLLOWER}.")
    )
    if unknown:
        raise ValueError(f"parameter {unknown[0]}: unknown (known: {', '.join(sorted(DEFAULTS))} and follower.*)")
    node = _node_settings(values, base)
    follower = _follower(values)
    method = follower.method
    if method in DEPTH_METHODS and not node.depth_topic:
        alone = " (or use segmin, which runs on the mask alone)" if method == "segmind" else ""
        raise ValueError(f"parameter depth_topic: {method} needs depth{alone}")
    if method == "segcorridor" and not follower.camera.intrinsics_given and not node.camera_info_topic:
        raise ValueError(
            "parameter camera_info_topic: segcorridor needs the camera intrinsics: set camera_info_topic "
            "(sensor_msgs/CameraInfo) or follower.camera.width, height, fx, fy, cx and cy"
        )
    return NodeParams(follower, node)


def as_values(params: NodeParams) -> dict[str, Any]:
    """The parameters as plain name -> value (what the node declares): the node's own, and the
    follower's under `follower.` (the navigator's of its method only)."""
    return {**dataclasses.asdict(params.node), **flatten({FOLLOWER: follower_to_dict(params.follower)})}


def load_params_file(path: str | Path) -> tuple[str, dict[str, Any]]:
    """(node name, parameters) of a ROS 2 parameter file (`name: ros__parameters: {...}`; `/**`
    allowed); nested sections are read as dotted names, as ROS 2 reads them."""
    path = Path(path)
    try:
        data = parse_yaml(path.read_text())  # 1e-3 is a float, as rclpy's own parser reads it
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not YAML ({' '.join(str(exc).split())})") from None
    shape = f"{path}: expected one node section, '{NODE_NAME}: ros__parameters: {{...}}'"
    if not isinstance(data, dict) or len(data) != 1:
        raise ValueError(shape)
    ((name, section),) = data.items()
    if (
        not isinstance(section, dict)
        or set(section) != {"ros__parameters"}
        or not isinstance(section["ros__parameters"], dict)
    ):
        raise ValueError(shape)
    node = NODE_NAME if str(name) in ("/**", "**") else str(name).lstrip("/")
    return node, flatten(section["ros__parameters"])


def defaults_yaml(node: str = NODE_NAME, method: str = DEFAULT_METHOD) -> str:
    """A parameter file of the defaults for `method`, each parameter with its description."""
    lines = [
        "# segmin row-follower node: `segmin ros2 follow --params THIS_FILE`.",
        "# The node's own settings, then the runtime's follower config (the keys of nav-eval's follower",
        "# section and of `segmin replay --follower`).",
        f"{node}:",
        "  ros__parameters:",
    ]
    for title, names in GROUPS:
        lines.append(f"    # --- {title}")
        for name in names:
            lines += [f"    # {DESCRIPTIONS[name]}", f"    {_yaml_item(name, DEFAULTS[name])}"]
    follower = _follower({f"{FOLLOWER}.method": method})
    lines.append(f"    # --- the runtime ({method}: {type(follower.navigator).__name__} under navigator)")
    _section_lines(lines, FOLLOWER, follower_to_dict(follower), "    ")
    return "\n".join(lines) + "\n"


def _section_lines(lines: list[str], name: str, values: dict[str, Any], indent: str) -> None:
    """`name:` and its values, nested, each leaf after its description."""
    lines.append(f"{indent}{name}:" + (f"  # {SECTION_TITLES[name]}" if name in SECTION_TITLES else ""))
    for key, value in values.items():
        if isinstance(value, dict):
            _section_lines(lines, key, value, indent + "  ")
        else:
            lines += [f"{indent}  # {describe(key)}", f"{indent}  {_yaml_item(key, value)}"]


def _yaml_item(name: str, value: Any) -> str:
    return yaml.safe_dump({name: value}, default_flow_style=True, width=1 << 16).strip()[1:-1]
