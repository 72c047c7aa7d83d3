"""The row-follower node's rules without ROS: its parameters and `FollowerCore` (what it publishes).

Messages are the `rosbags` message objects of bag_helpers, which have the fields rclpy's have.
The node under a real rclpy is tested in test_ros2_node.py (`make test-ros2`).
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from bag_helpers import depth_message, image_message
from test_replay_bags import GreenSegmenter
from test_sim_bags import _episode

from segmin.app.cli import main
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.ros2.core import LOG_EVERY_S, FollowerCore, Outgoing
from segmin.nav_eval.ros2.params import (
    DEFAULTS,
    DESCRIPTIONS,
    GROUPS,
    as_values,
    defaults_yaml,
    describe,
    load_params_file,
    node_params,
)
from segmin.nav_eval.ros2.phase import CommandPhase
from segmin.nav_eval.ros2.sensors import attitude_from_imu, geometry_from_camera_info
from segmin.nav_eval.runtime.corridor import CorridorConfig
from segmin.nav_eval.runtime.navigator import NavigatorConfig

# ---- parameters ----------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["segmind", "segcorridor"])
def test_the_defaults_file_lists_every_parameter_once_and_reads_back(tmp_path, capsys, method) -> None:
    grouped = [name for _, names in GROUPS for name in names]
    assert sorted(grouped) == sorted(DEFAULTS) == sorted(DESCRIPTIONS)
    assert main(["ros2", "params", "--method", method, "--out", str(tmp_path / "p.yaml")]) == 0
    name, values = load_params_file(tmp_path / "p.yaml")
    info = {"camera_info_topic": topics.COLOUR_INFO} if method == "segcorridor" else {}
    params = node_params({**values, **info})
    assert name == "segmin_row_follower" and values == {**as_values(params), **{k: DEFAULTS[k] for k in info}}
    assert params.follower.method == method and params.navigator.depth_threshold == 5.0
    assert params.node.enabled is False  # a robot must not move because a node came up
    capsys.readouterr()
    assert main(["ros2", "params", "--method", method]) == 0  # each parameter after its description
    assert capsys.readouterr().out.count("\n") > 2 * len(values)


def test_parameter_names_follow_the_follower_config() -> None:
    """Every field of the method's navigator class is a follower.navigator parameter, and no other."""
    for method, cls in (("segmin", NavigatorConfig), ("segcorridor", CorridorConfig)):
        values = as_values(node_params({"follower.method": method, "camera_info_topic": topics.COLOUR_INFO}))
        navigator = {k.removeprefix("follower.navigator.") for k in values if k.startswith("follower.navigator.")}
        assert navigator == {f.name for f in dataclasses.fields(cls) if f.init} - {"method"}
        assert all(describe(k) for k in values)


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"gain": 1.0}, "parameter gain: unknown"),
        ({"follower.navigator.gain": 1.0}, "parameter follower.navigator: unknown key(s) ['gain']"),
        ({"follower.navigator.v_max": -1.0}, "parameter follower.navigator.v_max: v_max must be a finite number > 0"),
        ({"follower.navigator.fuse_frames": 2.5}, "parameter follower.navigator.fuse_frames: expected an integer"),
        ({"enabled": "yes"}, "parameter enabled: expected bool"),
        ({"follower.method": "segmax"}, "parameter follower.method: 'segmax' is not one of"),
        (
            {"follower.runtime.command_hz": 3},
            "parameter follower.runtime.segment_hz: segment_hz (20) must be a multiple of command_hz (3)",
        ),
        ({"depth_topic": ""}, "parameter depth_topic: segmind needs depth"),
        ({"slop_s": 0.6}, "parameter slop_s: slop_s must be"),
        (
            {"follower.navigator.mask_closing": -2},
            "parameter follower.navigator.mask_closing: mask_closing must be an integer from 0 to 112 px",
        ),
        ({"command_priority": 99}, "parameter command_priority: command_priority must be 0 (normal scheduling)"),
        ({"method": "segmin", "follower.method": "segmin"}, "parameter method: also set as follower.method"),
    ],
)
def test_bad_parameters_are_named(values, message) -> None:
    with pytest.raises(ValueError, match=r"^" + re.escape(message)):
        node_params(values)


def test_parameter_files_the_way_ros_writes_them(tmp_path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text(
        "/**:\n  ros__parameters:\n    follower:\n      navigator: {v_max: 1}\n    model: m.onnx\n"
        "    use_sim_time: true\n    follower.navigator.omega_gain: 5e-3\n"
    )
    name, values = load_params_file(path)
    assert name == "segmin_row_follower"
    params = node_params(values, base=tmp_path)
    assert params.navigator.v_max == 1.0 and params.node.model == str(tmp_path / "m.onnx")
    assert params.navigator.omega_gain == 5e-3  # a float, as rclpy's parser reads it
    for text in (
        "v_max: 1\n",
        "a:\n  ros__parameters: {}\nb:\n  ros__parameters: {}\n",
        "a:\n  params: {}\n",
        "a: [\n",
    ):
        path.write_text(text)
        with pytest.raises(ValueError, match=str(path)):
            load_params_file(path)


# ---- FollowerCore --------------------------------------------------------------------------


class Recorder:
    def __init__(self) -> None:
        self.sent: list[Outgoing] = []
        self.logged: list[str] = []


def _core(enabled: bool = True, **values: object) -> tuple[FollowerCore, Recorder]:
    out = Recorder()
    params = node_params({"enabled": enabled, "publish_on_timer": False, **values})  # at once unless a test asks
    return FollowerCore(params, GreenSegmenter(), out.sent.append, out.logged.append), out


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> tuple[list, list]:
    """(frames as (t, colour message, depth message), the simulator's commands) of a recorded run."""
    from rosbags.highlevel import AnyReader

    bag = tmp_path_factory.mktemp("core") / "run"
    episode, _ = _episode(GreenSegmenter(), bag=bag)
    by_t: dict[int, dict] = {}
    with AnyReader([bag]) as reader:
        wanted = [c for c in reader.connections if c.topic in (topics.COLOUR, topics.DEPTH)]
        for connection, t, raw in reader.messages(connections=wanted):
            by_t.setdefault(t, {})[connection.topic] = reader.deserialize(raw, connection.msgtype)
    frames = [(t / 1e9, m[topics.COLOUR], m[topics.DEPTH]) for t, m in sorted(by_t.items())]
    return frames, episode.commands


def _stamp_s(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def test_the_core_publishes_the_simulators_commands_at_once(run) -> None:
    frames, commands = run
    core, out = _core()
    for i, (t, colour, depth) in enumerate(frames):
        first, second = (depth, colour) if i % 2 else (colour, depth)  # either may come first
        (core.on_depth if first is depth else core.on_colour)(first, t)
        (core.on_colour if second is colour else core.on_depth)(second, t)
    sent = [(_stamp_s(o.stamp), o.command.v, o.command.omega) for o in out.sent]
    assert [s[1:] for s in sent] == [c[1:3] for c in commands]
    assert [s[0] for s in sent] == pytest.approx([c[0] for c in commands], abs=1e-9)
    assert out.logged == [] and core.rejected == 0


def test_disabled_publishes_nothing_and_disabling_sends_one_stop(run) -> None:
    frames, _ = run
    core, out = _core(enabled=False)
    for t, colour, depth in frames[:12]:
        core.on_colour(colour, t)
        core.on_depth(depth, t)
        core.tick(t, t)
    assert out.sent == [] and core.frames == 12
    assert core.set_enabled(True) == "driving enabled"
    core.on_colour(frames[12][1], frames[12][0])
    core.on_depth(frames[12][2], frames[12][0])
    assert core.set_enabled(False) == "driving disabled"
    assert out.sent[-1].command.v == 0.0 and out.sent[-1].reason == "disabled"
    count = len(out.sent)
    core.tick(10.0, 10.0)
    assert len(out.sent) == count


def test_the_watchdog_holds_the_command_then_stops_a_stalled_camera(run) -> None:
    frames, _ = run
    core, out = _core()
    for t, colour, depth in frames[:13]:  # 0.4 s: commands at 0, 0.2, 0.4
        core.on_colour(colour, t)
        core.on_depth(depth, t)
    last = frames[12][0]
    in_force = out.sent[-1]
    core.tick(last + 0.2, last + 0.2)  # within 1.5 periods of the last command: silent
    assert out.sent[-1] is in_force
    core.tick(last + 0.35, last + 0.35)  # late frames: the command in force, with its image's stamp
    assert out.sent[-1].command == in_force.command and out.sent[-1].stamp == in_force.stamp
    core.tick(last + 0.7, last + 0.7)  # past frame_timeout_s: stop
    assert out.sent[-1].command.v == 0.0 and out.sent[-1].reason.startswith("frame_timeout")
    assert core.stop_reason(last + 0.7).startswith("frame_timeout")


@pytest.mark.parametrize("node_ahead", [0.3, -0.3])
def test_the_frame_timeout_runs_on_the_image_stamps_not_the_node_clock(run, node_ahead) -> None:
    """The node clock (`now`) and the images' time base (`stamp_now`) differ by a transport delay
    or a camera clock offset; only the stamps say how old the newest frame is."""
    frames, _ = run
    core, out = _core()
    for t, colour, depth in frames[:13]:
        core.on_colour(colour, t + node_ahead)
        core.on_depth(depth, t + node_ahead)
    last = frames[12][0]
    in_force = out.sent[-1]
    core.tick(last + 0.35 + node_ahead, last + 0.35)  # 0.35 s of stamp time: the command in force
    assert out.sent[-1].command == in_force.command and out.sent[-1].stamp == in_force.stamp
    core.tick(last + 0.7 + node_ahead, last + 0.7)  # 0.7 s: past frame_timeout_s (0.5 s)
    assert out.sent[-1].command.v == 0.0 and out.sent[-1].reason == "frame_timeout: no paired frame for 0.70 s"


def test_bad_frames_stop_the_robot_at_once_log_once_and_the_runtime_goes_on(run) -> None:
    frames, _ = run
    core, out = _core()
    for t, colour, depth in frames[:4]:
        core.on_colour(colour, t)
        core.on_depth(depth, t)
    t = frames[4][0]
    for k in range(3):  # a camera sending the wrong encoding
        bad = image_message(np.zeros((48, 48, 3), np.uint8), t + k * 0.01, "rgb8")
        bad.encoding = "yuv422"
        core.on_colour(bad, t + k * 0.01)
    assert [o.command.v for o in out.sent[-3:]] == [0.0, 0.0, 0.0]
    assert out.sent[-1].reason.startswith(f"{topics.COLOUR}: colour encoding 'yuv422'")
    assert len(out.logged) == 1 and "frame dropped, robot stopped" in out.logged[0]
    core.tick(t + 0.5, t + 0.1)  # the watchdog keeps it stopped
    assert out.sent[-1].command.v == 0.0
    for t, colour, depth in frames[4:10]:
        core.on_colour(colour, t)
        core.on_depth(depth, t)
    assert out.sent[-1].command.valid and core.fault is None  # a fresh command clears the fault
    # A stamp out of order and a depth frame of another size: dropped, named, robot stopped.
    core.on_colour(frames[2][1], frames[12][0])
    assert out.sent[-1].reason.startswith(f"{topics.COLOUR}: stamp") and out.sent[-1].command.v == 0.0
    t = frames[11][0]
    core.on_colour(frames[11][1], t)
    core.on_depth(depth_message(np.zeros((24, 48), np.uint16), t, "16UC1"), t)
    assert "depth is 48x24, rgb is 48x48" in out.sent[-1].reason
    assert core.rejected == 5
    assert core.status(t)["frames rejected"] == "5"
    logged = len(out.logged)
    bad.header.stamp.sec += 100
    core.on_colour(bad, t + LOG_EVERY_S)  # the colour topic's warnings come again after LOG_EVERY_S
    assert len(out.logged) == logged + 1


def test_millimetres_sent_as_32fc1_stop_the_robot_naming_the_topic(run) -> None:
    """Read as metres, every plant would be 1000 times too far: the row would look open."""
    frames, _ = run
    core, out = _core()
    t, colour, _ = frames[0]
    depth = depth_message(np.zeros((48, 48), np.uint16), t, "32FC1")
    depth.data = np.full((48, 48), 3000.0, np.float32).view(np.uint8).reshape(-1).copy()
    core.on_colour(colour, t)
    core.on_depth(depth, t)
    assert core.frames == 0 and core.rejected == 1 and out.sent[-1].command.v == 0.0
    assert out.sent[-1].reason.startswith(f"{topics.DEPTH}: 32FC1: float depth must be metres")


def test_a_depth_frame_without_a_colour_partner_is_logged_and_counted(run) -> None:
    frames, _ = run
    core, out = _core()
    t, colour, depth = frames[0]
    core.on_depth(depth_message(np.zeros((48, 48), np.uint16), t - 0.5, "16UC1"), t)
    core.on_colour(colour, t)
    core.on_depth(depth, t)
    assert core.pairer.dropped_depth == 1 and core.frames == 1
    assert len(out.logged) == 1 and "had no partner" in out.logged[0]
    assert core.status(t)["unpaired depth frames"] == "1"


def test_on_the_timer_only_the_timer_publishes_the_command_in_force(run) -> None:
    frames, commands = run
    core, out = _core(publish_on_timer=True)
    for t, colour, depth in frames[:13]:  # commands at 0, 0.2, 0.4
        core.schedule_tick(t + 0.005 - 0.2)  # the next tick 5 ms away: fresh commands wait for it
        core.on_colour(colour, t)
        core.on_depth(depth, t)
    assert out.sent == []
    now = frames[12][0] + 0.01
    core.tick(now, now)
    core.tick(now + 0.2, now + 0.2)  # every period, the command in force (no quiet time)
    assert [(o.command.v, _stamp_s(o.stamp)) for o in out.sent] == [(commands[2][1], pytest.approx(0.4))] * 2
    core.tick(now + 0.6, now + 0.6)
    assert out.sent[-1].command.v == 0.0 and out.sent[-1].reason.startswith("frame_timeout")


def test_on_the_timer_a_command_that_misses_its_tick_goes_out_at_once_unpaced(run) -> None:
    frames, commands = run
    core, out = _core(publish_on_timer=True)
    tick = frames[0][0] - 0.2 + 0.005  # ticks 5 ms after the command deadlines
    for i, (t, colour, depth) in enumerate(frames[:19]):  # commands at 0, 0.2, 0.4, 0.6
        while tick < t:
            tick = core.schedule_tick(tick)  # the command thread (free-running: fewer commands than a lock needs)
        late = 0.1 if i == 18 else 0.0  # the last command's step ends 100 ms late: its tick went by
        core.on_colour(colour, t + late)
        core.on_depth(depth, t + late)
    assert [(o.command.v, o.paced) for o in out.sent] == [(commands[3][1], False)]  # the others wait for their tick


def test_the_timer_locks_onto_the_command_deadlines_and_then_only_slews() -> None:
    phase = CommandPhase(0.2)
    assert phase.next_tick(10.05) == pytest.approx(10.25)  # free-running before any command
    leads = [0.006, 0.007, 0.008, 0.007, 0.009, 0.006, 0.007, 0.030, 0.007, 0.008]  # one slow step
    late = [0.0] * 8 + [1 / 30] * 2  # two commands waited for the next frame: the tick does not
    for k, (lead, delay) in enumerate(zip(leads, late, strict=True)):
        phase.observe(0.2 * k, 0.2 * k + delay, 0.2 * k + delay + lead)
    offset = phase.offset()
    assert offset == pytest.approx(np.quantile(leads, 0.9) + 0.001)
    grid = 0.2 * (len(leads) - 1) + offset
    tick = phase.next_tick(grid + 0.05)  # 50 ms off the grid: re-lock at once
    assert (tick - grid) / 0.2 == pytest.approx(round((tick - grid) / 0.2), abs=1e-9) and tick > grid + 0.15
    assert phase.next_tick(tick + 0.003) == pytest.approx(tick + 0.2 + 0.002)  # 3 ms off: 1 ms a tick back
    assert phase.next_tick(tick - 0.0005) == pytest.approx(tick + 0.2)  # within the slew: on the grid
    assert phase.next_tick(tick + 0.05) == pytest.approx(tick + 0.2 + 0.049)  # locked: slews, never jumps
    phase.observe(0.2 * len(leads) + 0.07, 0.2 * len(leads) + 0.07, 0.2 * len(leads) + 0.077)  # a new grid
    moved = phase.next_tick(tick)
    assert moved - tick == pytest.approx(0.2 + 0.07 - 0.2 * round(0.07 / 0.2), abs=0.02) and moved > tick + 0.1


def test_a_relock_never_gives_a_period_of_half_the_nominal_one_or_less() -> None:
    """Wherever the free-running timer stands on the runtime's grid, the jump onto it is more than
    half a period (a tick exactly halfway between two grid ticks rounds to the nearer one behind)."""
    period = 0.25
    gaps = []
    for k in range(80):  # the timer's phase in steps of 1/40 period, over two periods
        phase = CommandPhase(period)
        for i in range(10):
            phase.observe(period * i, period * i, period * i + 0.007)
        previous = period * 9 + phase.offset() + k * period / 40
        gaps.append(phase.next_tick(previous) - previous)
    assert min(gaps) > 0.5 * period + 1e-9 and max(gaps) <= 1.5 * period + 1e-9
    assert gaps[60] == pytest.approx(1.5 * period)  # exactly halfway, rounded behind: one period further


def test_without_a_depth_topic_colour_drives_alone(run) -> None:
    frames, _ = run
    core, out = _core(method="segmin", depth_topic="")
    for t, colour, _ in frames[:7]:
        core.on_colour(colour, t)
    assert len(out.sent) == 2 and core.frames == 7


def test_follow_without_rclpy_names_what_to_install(tmp_path, capsys) -> None:
    path = Path(tmp_path / "p.yaml")
    path.write_text(defaults_yaml())
    assert main(["ros2", "follow", "--params", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ros-rclpy[fastrtps]" in err[0] and "module 'rclpy' is missing" in err[0]


def test_the_shipped_jackal_parameter_file_is_complete_and_valid() -> None:
    """Every parameter of the node is in the Jackal file (a new one must be added there too), and
    its values pass the node's checks."""
    from segmin.common.shipped import resolve_config
    from segmin.nav_eval.ros2.params import load_params_file, node_params

    path = resolve_config("ros2", "jackal_d435")
    name, values = load_params_file(path)
    assert name == "segmin_row_follower"
    params = node_params(values, path.parent)
    assert params.navigator.method == "segmind" and params.runtime.command_hz == 5
    assert values["enabled"] is False and values == as_values(params)
    assert params.node.model == "vineyards"  # the shipped model: the file drives a robot on day one


# ---- SegCorridor's inputs: CameraInfo and Imu ----------------------------------------------


def _imu(q: tuple[float, float, float, float], covariance0: float = 0.0) -> SimpleNamespace:
    x, y, z, w = q
    return SimpleNamespace(
        orientation=SimpleNamespace(x=x, y=y, z=z, w=w), orientation_covariance=[covariance0] + [0.0] * 8
    )


@pytest.mark.parametrize(("slope_pitch", "slope_roll", "yaw"), [(0.0, 0.0, 0.3), (0.1, 0.0, -2.0), (-0.08, 0.12, 1.0)])
def test_the_imu_attitude_is_the_simulators_through_a_recorded_quaternion(slope_pitch, slope_roll, yaw) -> None:
    """The bag recorder writes the body's orientation; read back it is the attitude the simulator's
    runtime got (REP 103: positive roll lifts the left side, positive pitch lowers the nose)."""
    from segmin.nav_eval.sim.bag_recorder import base_pose, quaternion
    from segmin.nav_eval.sim.robot import RobotState, imu_attitude

    state = RobotState(x=1.0, y=2.0, yaw=yaw, pitch=slope_pitch, roll=slope_roll)
    got = attitude_from_imu(_imu(quaternion(base_pose(state)[:3, :3])), topics.IMU)
    assert got == pytest.approx(imu_attitude(state), abs=1e-9)
    if slope_pitch > 0:  # nose-up ground: the nose is raised, a negative pitch
        assert got[1] < 0


@pytest.mark.parametrize(
    ("q", "covariance0", "needle"),
    [
        ((0.0, 0.0, 0.0, 0.0), 0.0, "not a unit quaternion"),
        ((0.0, 0.0, 0.0, float("nan")), 0.0, "not a unit quaternion"),
        ((0.0, 0.0, 0.0, 1.0), -1.0, "no orientation"),
    ],
)
def test_a_bad_imu_message_names_its_topic(q, covariance0, needle) -> None:
    with pytest.raises(ValueError, match=rf"^{topics.IMU}: .*{needle}"):
        attitude_from_imu(_imu(q, covariance0), topics.IMU)


def _info(width: int = 224, height: int = 224, fx: float = 160.0) -> SimpleNamespace:
    return SimpleNamespace(width=width, height=height, k=[fx, 0.0, 111.5, 0.0, fx, 111.5, 0.0, 0.0, 1.0])


def test_camera_info_gives_the_intrinsics_and_the_parameters_the_mount() -> None:
    geometry = geometry_from_camera_info(
        _info(), topics.COLOUR_INFO, mount_height=0.4, tilt_deg=15.0, mount_forward=0.2
    )
    assert (geometry.width, geometry.height, geometry.fx, geometry.cx, geometry.tilt_deg) == (
        224,
        224,
        160.0,
        111.5,
        15.0,
    )
    with pytest.raises(ValueError, match=rf"^{topics.COLOUR_INFO}: camera fx .*uncalibrated"):
        geometry_from_camera_info(_info(fx=0.0), topics.COLOUR_INFO, 0.4, 15.0, 0.2)


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({}, "parameter camera_info_topic: segcorridor needs the camera intrinsics"),
        ({"follower.camera.fx": 160.0}, "parameter follower.camera.width: width: unset beside the other intrinsics"),
        ({"depth_topic": ""}, "parameter depth_topic: segcorridor needs depth"),
        (
            {"camera_info_topic": topics.COLOUR_INFO, "follower.navigator.v_max": -1.0},
            "parameter follower.navigator.v_max: corridor.v_max must be",
        ),
        ({"camera_info_topic": topics.COLOUR_INFO, "imu_max_age_s": 0.0}, "parameter imu_max_age_s: imu_max_age_s"),
    ],
)
def test_segcorridor_refuses_to_start_without_the_camera_intrinsics(values, message) -> None:
    with pytest.raises(ValueError, match=r"^" + message):
        node_params({"follower.method": "segcorridor", **values})


def test_the_sloped_rows_settings_reach_segcorridor_and_bad_ones_are_named() -> None:
    sloped = {"controller": "centre_hold", "hold_slope_drift": 0.5, "row_start_max": 2.5, "trim": 2.0}
    sloped = {f"follower.navigator.{k}": v for k, v in sloped.items()}
    base = {"follower.method": "segcorridor", "camera_info_topic": topics.COLOUR_INFO}
    corridor = node_params({**base, **sloped}).navigator
    assert (corridor.controller, corridor.hold_slope_drift, corridor.row_start_max, corridor.trim) == (
        "centre_hold",
        0.5,
        2.5,
        2.0,
    )
    with pytest.raises(ValueError, match="^parameter follower.navigator.hold_slope_drift:"):
        node_params({**base, **sloped, "follower.navigator.hold_slope_drift": -1.0})


def test_segcorridor_takes_its_camera_from_the_parameters_or_the_camera_info_topic() -> None:
    intrinsics = {"width": 224, "height": 224, "fx": 160.0, "fy": 160.0, "cx": 111.5, "cy": 111.5}
    params = node_params(
        {"follower.method": "segcorridor", **{f"follower.camera.{k}": v for k, v in intrinsics.items()}}
    )
    assert params.camera is not None and params.camera.frame_shape == (224, 224) and params.camera.tilt_deg == 15.0
    from_topic = node_params({"follower.method": "segcorridor", "camera_info_topic": topics.COLOUR_INFO})
    assert from_topic.camera is None and from_topic.navigator.method == "segcorridor"


@pytest.fixture(scope="module")
def corridor_run(tmp_path_factory) -> tuple[list, list]:
    """(messages in bag order as (topic, t, message), the simulator's commands) of a SegCorridor run."""
    from rosbags.highlevel import AnyReader

    bag = tmp_path_factory.mktemp("corridor") / "run"
    episode, _ = _episode(GreenSegmenter(), method="segcorridor", bag=bag)
    wanted_topics = (topics.COLOUR, topics.DEPTH, topics.COLOUR_INFO, topics.IMU)
    with AnyReader([bag]) as reader:
        wanted = [c for c in reader.connections if c.topic in wanted_topics]
        messages = [
            (c.topic, t / 1e9, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages(connections=wanted)
        ]
    order = {topic: i for i, topic in enumerate((topics.COLOUR_INFO, topics.IMU, topics.DEPTH, topics.COLOUR))}
    messages.sort(key=lambda m: (m[1], order[m[0]]))  # per frame: camera info and IMU first, colour last
    return messages, episode.commands


def _feed(core: FollowerCore, messages: list) -> None:
    handlers = {
        topics.COLOUR: core.on_colour,
        topics.DEPTH: core.on_depth,
        topics.COLOUR_INFO: core.on_camera_info,
        topics.IMU: core.on_imu,
    }
    for topic, t, message in messages:
        handlers[topic](message, t)


def test_the_core_drives_segcorridor_as_the_simulator_from_camera_info_and_imu(corridor_run) -> None:
    messages, commands = corridor_run
    core, out = _core(method="segcorridor", camera_info_topic=topics.COLOUR_INFO, imu_topic=topics.IMU)
    _feed(core, messages)
    sent = [(_stamp_s(o.stamp), o.command.v, o.command.omega) for o in out.sent]
    assert len(commands) > 5
    assert [s[1:] for s in sent] == [c[1:3] for c in commands]
    recorded_fx = next(m.k[0] for topic, _, m in messages if topic == topics.COLOUR_INFO)
    assert core.follower.navigator.camera.fx == pytest.approx(recorded_fx)
    assert out.logged == [f"{topics.COLOUR_INFO}: camera 48x48, fx {recorded_fx:.1f}: runtime (re)started"]


def test_frames_before_camera_info_or_of_another_size_stop_the_robot_naming_the_topic(corridor_run) -> None:
    messages, _ = corridor_run
    core, out = _core(method="segcorridor", camera_info_topic=topics.COLOUR_INFO)
    _feed(core, [m for m in messages[:8] if m[0] != topics.COLOUR_INFO])
    assert out.sent and all(o.command.v == 0.0 for o in out.sent) and core.frames == 0
    assert len(out.logged) == 1 and out.logged[0].endswith(
        f"{topics.COLOUR_INFO}: no CameraInfo yet (SegCorridor needs the intrinsics)"
    )
    info = next(m[2] for m in messages if m[0] == topics.COLOUR_INFO)
    core, out = _core(method="segcorridor", camera_info_topic=topics.COLOUR_INFO)
    core.on_camera_info(dataclasses.replace(info, width=320, height=240), 0.0)
    _feed(core, [m for m in messages[:8] if m[0] != topics.COLOUR_INFO])
    assert core.frames == 0 and out.sent[-1].command.v == 0.0
    assert f"{topics.COLOUR_INFO}: the camera is 320x240 but {topics.COLOUR} images are 48x48" in out.logged[-1]


def test_a_stale_imu_is_ignored_with_a_log_line_and_the_robot_drives_on(corridor_run) -> None:
    messages, commands = corridor_run
    core, out = _core(method="segcorridor", camera_info_topic=topics.COLOUR_INFO, imu_topic=topics.IMU)
    first_imu = next(m for m in messages if m[0] == topics.IMU)
    _feed(core, [first_imu] + [m for m in messages if m[0] != topics.IMU])
    assert [(o.command.v, o.command.omega) for o in out.sent] == [c[1:3] for c in commands]  # level ground here
    stale = [line for line in out.logged if topics.IMU in line]
    assert stale and "stale" in stale[0] and "imu_max_age_s=0.1" in stale[0]


def test_the_imu_attitude_on_a_slope_reaches_the_navigator(corridor_run) -> None:
    """The recorded run is on level ground; here every IMU message says the robot is rolled and
    pitched, and each command of SegCorridor must be computed with that attitude."""
    from segmin.nav_eval.sim.bag_recorder import base_pose, quaternion
    from segmin.nav_eval.sim.robot import RobotState, imu_attitude

    messages, _ = corridor_run
    state = RobotState(x=0.0, y=0.0, yaw=0.0, pitch=0.1, roll=-0.08)
    x, y, z, w = quaternion(base_pose(state)[:3, :3])
    tilted = [
        (topic, t, dataclasses.replace(m, orientation=dataclasses.replace(m.orientation, x=x, y=y, z=z, w=w)))
        if topic == topics.IMU
        else (topic, t, m)
        for topic, t, m in messages
    ]
    core, out = _core(method="segcorridor", camera_info_topic=topics.COLOUR_INFO, imu_topic=topics.IMU)
    _feed(core, tilted[:1])  # the CameraInfo starts the runtime
    navigator = core.follower.navigator
    seen: list = []
    command = navigator.command

    def spy(fused, depth_m, attitude=None, rgb=None):
        seen.append(attitude)
        return command(fused, depth_m, attitude, rgb)

    navigator.command = spy
    _feed(core, tilted[1:])
    assert core.follower.navigator is navigator and len(seen) > 5 and out.logged[1:] == []
    assert all(a == pytest.approx(imu_attitude(state), abs=1e-9) for a in seen)
    assert min(abs(a) for a in imu_attitude(state)) > 0.05


def test_command_timing_reports_the_nodes_latency_and_period_jitter() -> None:
    from segmin.nav_eval.ros2.timing import CommandTiming

    timing = CommandTiming()
    timing.published(None, now_ns=0, monotonic_s=99.5, paced=True)  # a stop before the first frame: no period
    for k in range(5):
        stamp = 10**9 * k
        timing.image_received(stamp, received_ns=stamp + 1_000_000)
        late = 0.004 if k == 3 else 0.0  # one command 4 ms late
        timing.published(stamp, now_ns=stamp + 11_000_000, monotonic_s=100.0 + 0.2 * k + late, paced=True)
        timing.published(stamp, now_ns=stamp + 99_000_000, monotonic_s=100.1 + 0.2 * k, paced=False)  # again
    timing.image_received(7 * 10**9, received_ns=7 * 10**9)
    timing.published(7 * 10**9, now_ns=7 * 10**9 + 30_000_000, monotonic_s=100.95, paced=False)  # missed its tick
    timing.published(None, now_ns=0, monotonic_s=101.0, paced=True)  # the camera stalled: the chain breaks
    timing.published(8 * 10**9, now_ns=0, monotonic_s=101.5, paced=True)
    summary = timing.summary(command_hz=5)
    assert summary["latency image received to command published median ms"] == "10.00"  # first publications
    assert np.percentile([10.0] * 5 + [30.0], 95) == pytest.approx(
        float(summary["latency image received to command published p95 ms"])
    )
    assert summary["command period median ms"] == "200.00" and summary["command periods timed"] == "4"
    assert float(summary["command period jitter p99 ms"]) == pytest.approx(4.0, abs=0.1)
    assert CommandTiming().summary(5)["command period jitter p99 ms"] == "-"


# ---- sensor faults: the runtime's stops, in the log and the diagnostics ---------------------


def _feed_pairs(core: FollowerCore, frames: list, clock_offset: float = 0.0, depth_of=None) -> None:
    for t, colour, depth in frames:
        core.on_colour(colour, t + clock_offset)
        core.on_depth(depth if depth_of is None else depth_of(t, colour), t + clock_offset)


@pytest.mark.parametrize(("encoding", "blind"), [("32FC1", np.nan), ("16UC1", 0)])
def test_a_blind_depth_camera_stops_the_robot_with_one_log_line_and_names_it_in_the_diagnostics(
    run, encoding, blind
) -> None:
    frames, _ = run
    core, out = _core()
    _feed_pairs(core, frames[:13])
    assert out.sent[-1].command.valid and out.sent[-1].command.v > 0
    driving = len(out.sent)
    _feed_pairs(
        core, frames[13:25], depth_of=lambda t, c: depth_message(np.full((c.height, c.width), blind), t, encoding)
    )
    stops = out.sent[driving:]
    assert stops and all(not o.command.valid and o.reason == "depth_invalid" for o in stops)
    assert _stamp_s(stops[0].stamp) - frames[13][0] <= 0.2 + 1e-9
    assert len(out.logged) == 1 and out.logged[0].startswith("robot stopped, sensor fault depth_invalid: 0% of the")
    t = frames[24][0]
    status = core.status(t)
    assert status["sensor fault"] == "depth_invalid" and status["stopped because"].startswith("depth_invalid: 0% of")
    core.tick(t + 0.3, t + 0.3)  # the watchdog names it too
    assert not out.sent[-1].command.valid and out.sent[-1].reason.startswith("depth_invalid")
    _feed_pairs(core, frames[25:40])
    assert out.sent[-1].command.valid and out.sent[-1].command.v > 0
    assert out.logged[1:] == ["sensor fault depth_invalid cleared: the runtime drives again"]
    assert core.status(frames[39][0])["sensor fault"] == "-"


def test_a_fault_that_comes_and_goes_is_logged_once_per_reason_within_log_every_s(run) -> None:
    frames, _ = run
    core, out = _core()
    for k, (t, colour, depth) in enumerate(frames[:37]):  # ends on a command (1.2 s) after good frames
        image = colour
        if k % 8 in (5, 6):  # a black image now and then
            image = image_message(np.zeros((colour.height, colour.width, 3), np.uint8), t, "rgb8")
            image.header = colour.header
        core.on_colour(image, t)
        core.on_depth(depth, t)
        if k == 5:  # between two commands (0.167 s): the stop goes out at once
            assert not out.sent[-1].command.valid and out.sent[-1].reason == "image_black"
    assert out.sent[-1].command.valid
    assert [line.split(":")[0] for line in out.logged] == [
        "robot stopped, sensor fault image_black",
        "sensor fault image_black cleared",
    ]


def test_frames_on_another_clock_stop_the_robot_naming_how_far_and_use_sim_time(run) -> None:
    frames, _ = run
    core, out = _core()
    offset = 1796571822.0  # a bag's own stamps against the node's wall clock
    _feed_pairs(core, frames[:13], clock_offset=offset)
    assert out.sent and all(not o.command.valid and o.reason == "clock_offset" for o in out.sent)
    assert len(out.logged) == 1
    assert "1796571822.000 s behind the follower's clock" in out.logged[0] and "use_sim_time" in out.logged[0]
    now = frames[12][0] + offset
    assert core.stop_reason(now).startswith("clock_offset: frame stamps are 1796571822.000 s behind")
    core.tick(now + 0.3, now + 0.3)
    assert out.sent[-1].reason.startswith("clock_offset")


def test_a_second_kind_of_bad_input_on_a_topic_gets_its_own_log_line(run) -> None:
    frames, _ = run
    core, out = _core()
    t = frames[0][0]
    bad = image_message(np.zeros((48, 48, 3), np.uint8), t, "rgb8")
    bad.encoding = "yuv422"
    core.on_colour(bad, t)
    core.on_colour(frames[1][1], t + 0.01)
    core.on_depth(depth_message(np.zeros((24, 48), np.uint16), frames[1][0], "16UC1"), t + 0.01)
    core.on_colour(bad, t + 0.02)  # the first kind again within LOG_EVERY_S: no new line
    assert len(out.logged) == 2
    assert "'yuv422'" in out.logged[0] and "depth is 48x24" in out.logged[1]
