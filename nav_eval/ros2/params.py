"""The row-follower node's parameters: names, defaults, checks, and the ROS 2 parameter file.

The navigator's and the runtime's parameters keep the names of `NavigatorConfig`,
`RuntimeConfig` and its sensor checks' `SensorChecks` (taken from the dataclasses, so they cannot
drift apart; the checks are flat parameters, ROS has no nested ones); the node adds its own
(`NodeSettings`: model, topics, pairing, outputs, `enabled`). A parameter file is the standard
one ROS 2 reads:

    segmin_row_follower:
      ros__parameters:
        method: segmind
        ...

`load_params_file` reads it and `node_params` checks every value (unknown names, wrong types,
out-of-range values: ValueError naming the parameter) before the node starts; the same check
answers a `ros2 param set` while it runs. `defaults_yaml` writes the defaults, commented. No ROS
import: the checks run, and are tested, without rclpy.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from segmin.common.config import parse_yaml
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.corridor import CorridorConfig
from segmin.nav_eval.runtime.follower import RuntimeConfig
from segmin.nav_eval.runtime.methods import DEPTH_METHODS, METHODS
from segmin.nav_eval.runtime.navigator import NavigatorConfig
from segmin.nav_eval.runtime.sensor_faults import SensorChecks, check_depth_range
from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES

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
    imu_max_age_s: float = 0.1
    camera_width: int = 0
    camera_height: int = 0
    camera_fx: float = 0.0
    camera_fy: float = 0.0
    camera_cx: float = 0.0
    camera_cy: float = 0.0
    camera_mount_height: float = 0.40
    camera_tilt_deg: float = 15.0
    camera_mount_forward: float = 0.2

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

    @property
    def intrinsics_given(self) -> bool:
        """The camera intrinsics are parameters (camera_fx etc.), not read from a CameraInfo topic."""
        return any(getattr(self, f"camera_{name}") for name in ("width", "height", "fx", "fy", "cx", "cy"))

    def camera_geometry(self) -> CameraGeometry:
        """The camera of the parameters (ValueError naming the parameter when one is missing or wrong)."""
        try:
            return CameraGeometry(
                width=self.camera_width,
                height=self.camera_height,
                fx=self.camera_fx,
                fy=self.camera_fy,
                cx=self.camera_cx,
                cy=self.camera_cy,
                mount_height=self.camera_mount_height,
                tilt_deg=self.camera_tilt_deg,
                mount_forward=self.camera_mount_forward,
            )
        except ValueError as exc:  # "camera fx must be ..." -> parameter camera_fx
            name = str(exc).split()[1]
            raise ValueError(f"camera_{name}: {exc}") from None


@dataclass(frozen=True)
class NodeParams:
    """Every checked parameter of the node, as the objects the runtime takes.

    `navigator` is SegCorridor's `CorridorConfig` (its other settings at their defaults) for
    method segcorridor; `camera` its camera when the intrinsics are parameters (None: from the
    CameraInfo topic, or a method that needs no camera)."""

    navigator: NavigatorConfig | CorridorConfig
    runtime: RuntimeConfig
    node: NodeSettings
    camera: CameraGeometry | None = None


DESCRIPTIONS: dict[str, str] = {
    "method": f"navigation method: {', '.join(METHODS)} (segmind and segcorridor need depth_topic; segcorridor "
    "the camera intrinsics: camera_info_topic or camera_fx ... camera_height, and takes the IMU's roll and pitch)",
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
    "frozen_s": "stop (image_frozen) when the sampled pixels stay identical this long while driving, s",
    "max_clock_offset_s": "stop (clock_offset) when a frame's stamp is further than this from the node's clock "
    "(a bag's own times: play it with --clock and set use_sim_time), s",
    "sample_pixels": "the sensor checks read a regular grid of about this many pixels",
    "model": "exported .onnx file (a relative path is read from the parameter file's folder) or a shipped "
    "model name (vineyards, trees)",
    "threads": "onnxruntime threads",
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
    "when camera_fx etc. are not set; empty: not subscribed",
    "imu_topic": "sensor_msgs/Imu: roll and pitch from its orientation (REP 103, IMU level with base_link) for "
    "SegCorridor; empty: not subscribed, level ground assumed",
    "imu_max_age_s": "an IMU message older than this at a frame is stale: ignored (level ground), logged, s",
    "camera_width": "SegCorridor's camera from parameters (all six set) instead of camera_info_topic: image width, px",
    "camera_height": "image height, px (0: intrinsics from camera_info_topic)",
    "camera_fx": "focal length in x, px",
    "camera_fy": "focal length in y, px",
    "camera_cx": "principal point x, px",
    "camera_cy": "principal point y, px",
    "camera_mount_height": "SegCorridor: camera height above the ground, m (not in CameraInfo)",
    "camera_tilt_deg": "SegCorridor: camera tilt up from horizontal, degrees",
    "camera_mount_forward": "SegCorridor: camera ahead of base_link, m",
    "controller": "SegCorridor's steering law: pursuit (the default) or centre_hold (for a "
    "skid-steer robot such as the Jackal: holds the row centre under wheel slip and on cross slopes)",
    "hold_slope_drift": "centre_hold on sloped rows: points the robot uphill by this times tan(roll) from the IMU "
    "against its creep across the slope (0: off; 0.5 for the simulated Jackal; measure your robot's)",
    "row_start_max": "SegCorridor on gappy rows: a row whose points start beyond this many metres ahead, beside a row "
    "seen nearer, is left out (inf: off; 2.5 for sloped, gappy rows)",
    "trim": "SegCorridor's row fit drops points further than this many robust spreads from their row's curve "
    "(2.5; 2.0 for sloped, gappy rows)",
}
GROUPS = (
    ("driving", ("enabled", "method", "model", "depth_threshold", "threads", "inference_spin")),
    ("topics", ("colour_topic", "depth_topic", "cmd_vel_topic", "twist_stamped", "base_frame", "slop_s")),
    ("timing", ("publish_on_timer", "command_priority")),
    ("navigator (NavigatorConfig)", tuple(f.name for f in dataclasses.fields(NavigatorConfig))[2:]),
    ("runtime (RuntimeConfig)", tuple(f.name for f in dataclasses.fields(RuntimeConfig) if f.name != "checks")),
    (
        "sensor checks (SensorChecks): each fault stops the robot",
        tuple(f.name for f in dataclasses.fields(SensorChecks)),
    ),
    ("outputs", ("publish_overlay", "publish_diagnostics", "publish_frame_acks")),
    (
        "SegCorridor: camera, IMU and steering law",
        ("camera_info_topic", "imu_topic", "imu_max_age_s", "camera_width", "camera_height", "camera_fx")
        + ("camera_fy", "camera_cx", "camera_cy", "camera_mount_height", "camera_tilt_deg", "camera_mount_forward")
        + ("controller", "hold_slope_drift", "row_start_max", "trim"),
    ),
)
# The file's defaults; depth_threshold has none in NavigatorConfig on purpose: the paper's vineyards'.
DEFAULTS: dict[str, Any] = {
    **{f.name: f.default for f in dataclasses.fields(NodeSettings)},
    **{f.name: f.default for f in dataclasses.fields(NavigatorConfig) if f.default is not dataclasses.MISSING},
    **{f.name: f.default for f in dataclasses.fields(RuntimeConfig) if f.name != "checks"},
    **{f.name: f.default for f in dataclasses.fields(SensorChecks)},
    "method": "segmind",
    "depth_threshold": 5.0,
    "controller": "pursuit",
    "hold_slope_drift": 0.0,
    "row_start_max": math.inf,
    "trim": 2.5,
}
# Parameters fixed at start-up (subscriptions and publishers are made from them).
STARTUP_ONLY = (
    "command_priority",
    "colour_topic",
    "depth_topic",
    "cmd_vel_topic",
    "twist_stamped",
    "publish_overlay",
    "publish_diagnostics",
    "publish_frame_acks",
    "camera_info_topic",
    "imu_topic",
)


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


def node_params(values: dict[str, Any], base: Path | None = None) -> NodeParams:
    """Check `values` (any subset of the parameters; the rest default) and build the configs.

    ValueError names the first bad parameter. A relative `model` is taken from `base`."""
    unknown = sorted(set(values) - set(DEFAULTS) - set(ROS_PARAMETERS))
    if unknown:
        raise ValueError(f"parameter {unknown[0]}: unknown (known: {', '.join(sorted(DEFAULTS))})")
    merged = {name: _typed(name, values[name]) if name in values else default for name, default in DEFAULTS.items()}
    if merged["method"] not in METHODS:
        raise ValueError(f"parameter method: {merged['method']!r} is not one of {', '.join(METHODS)}")
    shipped_name = merged["model"] in SHIPPED_NAMES  # "vineyards": the installed model, not a file here
    if merged["model"] and base is not None and not shipped_name and not Path(merged["model"]).is_absolute():
        merged["model"] = str(base / merged["model"])

    def build(cls: type) -> Any:
        names = [f.name for f in dataclasses.fields(cls) if f.init]
        try:
            return cls(**{name: merged[name] for name in names if name in merged})
        except ValueError as exc:
            text = str(exc).removeprefix("corridor.")
            named = next((n for n in names if text.startswith(n)), None)
            raise ValueError(f"parameter {named}: {text}" if named else f"parameters: {exc}") from None

    node = build(NodeSettings)
    merged["checks"] = build(SensorChecks)
    try:
        check_depth_range(merged["depth_threshold"], merged["checks"])
    except ValueError as exc:
        raise ValueError(f"parameter depth_threshold: {exc}") from None
    if merged["method"] == "segcorridor":
        return NodeParams(build(CorridorConfig), build(RuntimeConfig), node, _corridor_camera(node))
    params = NodeParams(build(NavigatorConfig), build(RuntimeConfig), node)
    if params.navigator.method in DEPTH_METHODS and not node.depth_topic:
        raise ValueError("parameter depth_topic: segmind needs depth (or use segmin, which runs on the mask alone)")
    return params


def _corridor_camera(node: NodeSettings) -> CameraGeometry | None:
    """SegCorridor's camera from the parameters, or None when a CameraInfo topic gives it (ValueError
    when neither does: it cannot place a pixel without the intrinsics)."""
    if not node.depth_topic:
        raise ValueError("parameter depth_topic: segcorridor needs depth")
    if node.intrinsics_given:
        try:
            return node.camera_geometry()
        except ValueError as exc:
            raise ValueError(f"parameter {exc}") from None
    if not node.camera_info_topic:
        raise ValueError(
            "parameter camera_info_topic: segcorridor needs the camera intrinsics: set camera_info_topic "
            "(sensor_msgs/CameraInfo) or camera_width, camera_height, camera_fx, camera_fy, camera_cx and camera_cy"
        )
    return None


def as_values(params: NodeParams) -> dict[str, Any]:
    """The parameters as plain name -> value (what the node declares). SegCorridor's config lacks
    the paper's navigator-only parameters (mask_closing, smooth_window, omega_gain, zeros_*): they are the defaults."""
    runtime = {k: v for k, v in dataclasses.asdict(params.runtime).items() if k != "checks"}
    values = {**DEFAULTS, **dataclasses.asdict(params.node), **runtime, **dataclasses.asdict(params.runtime.checks)}
    values.update({k: v for k, v in dataclasses.asdict(params.navigator).items() if k in DEFAULTS})
    return values


def load_params_file(path: str | Path) -> tuple[str, dict[str, Any]]:
    """(node name, parameters) of a ROS 2 parameter file (`name: ros__parameters: {...}`; `/**` allowed)."""
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
    return node, dict(section["ros__parameters"])


def defaults_yaml(node: str = NODE_NAME) -> str:
    """A parameter file of the defaults, each parameter with its description."""
    lines = [
        "# segmin row-follower node: `segmin ros2 follow --params THIS_FILE`.",
        "# Names are those of NavigatorConfig / RuntimeConfig and the node's own settings.",
        f"{node}:",
        "  ros__parameters:",
    ]
    for title, names in GROUPS:
        lines.append(f"    # --- {title}")
        for name in names:
            value = yaml.safe_dump({name: DEFAULTS[name]}, default_flow_style=True).strip()[1:-1]
            lines.append(f"    # {DESCRIPTIONS[name]}")
            lines.append(f"    {value}")
    return "\n".join(lines) + "\n"
