"""Simulated runs written as rosbag2 (MCAP), and the loop closed through the bag.

- recording changes nothing of the run (same commands, same trajectory) although the recorder
  renders the frames the run skips;
- the bag holds every camera frame with standard types, frame ids and consistent TF;
- replaying the bag (`segmin replay --bag`) gives the commands the simulator's runtime issued:
  v, omega and the target column bit-identical, times within a nanosecond (stamps are ns);
- `segmin nav-eval --bag` writes one bag per field and method in a real pybullet field.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_nav_eval_sim import FakeRenderer, FakeWorld, _config
from test_replay_bags import GreenSegmenter

from benchmarks.cli import main as benchmarks_main
from segmin.app.cli import main
from segmin.nav_eval.evaluation.rollout import run_episode
from segmin.nav_eval.replay.bags import bag_camera, bag_frames
from segmin.nav_eval.replay.run import read_commands_csv, replay
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.runtime.segmenter import OnnxSegmenter
from segmin.nav_eval.sim.bag_recorder import RunRecorder, quaternion
from segmin.nav_eval.sim.factories import follower_config, make_follower, nav_camera
from segmin.nav_eval.sim.protocols import FrameSegmenter
from segmin.nav_eval.sim.row_env import RowEnv

LENGTH_M = 1.5


class _ImageFrames(FrameSegmenter):
    """An image segmenter (`segment(rgb)`, as the robot's) on the simulator's frames."""

    name = "image"

    def __init__(self, segmenter) -> None:
        self.segmenter = segmenter

    def segment_frame(self, frame) -> np.ndarray:
        return np.asarray(self.segmenter.segment(frame.rgb), dtype=bool)


class SlopedWorld(FakeWorld):
    """FakeWorld's rows on the constant slope of a shipped sloped world (its terrain.slope, without
    the roughness): the robot drives rolled across it, and its IMU says so. The stand-in renderer
    still draws level frames: the runtime's attitude is what differs."""

    def __init__(self, name: str = "slope_vineyard_s8") -> None:
        from segmin.data.synth.spec import load_world_spec

        super().__init__()
        self.slope = np.asarray(load_world_spec(name).terrain.slope, dtype=float)

    def terrain_height(self, x, y):
        return self.slope[0] * np.asarray(x, dtype=float) + self.slope[1] * np.asarray(y, dtype=float)

    def terrain_normal(self, x, y):
        normal = np.array([-self.slope[0], -self.slope[1], 1.0])
        return normal / np.linalg.norm(normal)


def _episode(segmenter, method: str = "segmind", bag: Path | None = None, world: FakeWorld | None = None):
    world = world or FakeWorld()
    config = _config(length_m=LENGTH_M)
    renderer = FakeRenderer(world)
    simulator = RowEnv(world, renderer, config)
    follower = make_follower(method, 5.0, config)
    frames = _ImageFrames(segmenter)
    if bag is None:
        return run_episode(simulator, follower, frames, seed=3), renderer
    with RunRecorder(bag, nav_camera(config), seed=3, metadata={"method": method}) as recorder:
        episode = run_episode(simulator, follower, frames, seed=3, recorder=recorder)
    return episode, renderer


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    bag = tmp_path_factory.mktemp("sim") / "run"
    plain, plain_renderer = _episode(GreenSegmenter())
    episode, renderer = _episode(GreenSegmenter(), bag=bag)
    return bag, plain, plain_renderer, episode, renderer


def _read(bag: Path) -> dict[str, list]:
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([bag]) as reader:
        for connection, t, raw in reader.messages():
            out.setdefault(connection.topic, []).append((t, reader.deserialize(raw, connection.msgtype)))
        types = {name: info.msgtype for name, info in reader.topics.items()}
    out["types"] = [types]
    return out


def test_recording_changes_nothing_of_the_run(recorded) -> None:
    _, plain, plain_renderer, episode, renderer = recorded
    assert episode.reason == "success", episode.reason
    assert episode.commands == plain.commands
    assert np.array_equal(episode.trajectory.x, plain.trajectory.x)
    assert np.array_equal(episode.trajectory.yaw, plain.trajectory.yaw)
    assert renderer.calls > plain_renderer.calls  # the skipped frames were rendered for the bag


def test_the_bag_holds_every_frame_in_standard_messages(recorded) -> None:
    bag, _, _, episode, _ = recorded
    messages = _read(bag)
    types = messages["types"][0]
    assert types[topics.COLOUR] == "sensor_msgs/msg/Image" and types[topics.ODOM] == "nav_msgs/msg/Odometry"
    frames = messages[topics.COLOUR]
    assert len(frames) == len(messages[topics.DEPTH]) == len(messages[topics.IMU]) == len(messages[topics.TF])
    period = np.diff([t for t, _ in frames])
    assert np.allclose(period, 1e9 / 30, atol=1)  # every camera frame, 30 Hz
    assert len(messages[topics.CMD_VEL]) == len(episode.commands)
    assert [m.linear.x for _, m in messages[topics.CMD_VEL]] == [c[1] for c in episode.commands]
    t0, colour = frames[0]
    assert colour.encoding == "rgb8" and colour.header.frame_id == topics.OPTICAL_FRAME
    assert colour.header.stamp.sec * 10**9 + colour.header.stamp.nanosec == t0
    depth = messages[topics.DEPTH][0][1]
    assert depth.encoding == "32FC1" and depth.step == 4 * depth.width
    info = messages[topics.COLOUR_INFO][0][1]
    k = nav_camera(_config()).intrinsics()
    assert list(info.k) == [k["fx"], 0.0, k["cx"], 0.0, k["fy"], k["cy"], 0.0, 0.0, 1.0]
    static = messages[topics.TF_STATIC][0][1].transforms
    assert [(s.header.frame_id, s.child_frame_id) for s in static] == [
        (topics.MAP_FRAME, topics.ODOM_FRAME),
        (topics.BASE_FRAME, topics.CAMERA_FRAME),
        (topics.CAMERA_FRAME, topics.OPTICAL_FRAME),
        (topics.BASE_FRAME, topics.IMU_FRAME),
    ]
    # REP 105: map -> odom (static) composed with odom -> base_link is the ground truth.
    start = static[0].transform
    odom = messages[topics.ODOM][-1][1].pose.pose.position
    truth = messages[topics.GROUND_TRUTH][-1][1].pose.pose.position
    yaw = 2 * math.atan2(start.rotation.z, start.rotation.w)
    x = start.translation.x + math.cos(yaw) * odom.x - math.sin(yaw) * odom.y
    y = start.translation.y + math.sin(yaw) * odom.x + math.cos(yaw) * odom.y
    assert (x, y) == pytest.approx((truth.x, truth.y), abs=1e-9)
    first = messages[topics.GROUND_TRUTH][0][1].pose.pose.position
    assert (first.x, first.y) == pytest.approx(episode.start_pose[:2], abs=1e-12)


def test_replaying_the_bag_gives_the_commands_of_the_simulator(recorded, tmp_path) -> None:
    bag, _, _, episode, _ = recorded
    result = replay(
        "model.onnx",
        None,
        tmp_path / "out",
        method="segmind",
        depth_threshold=5.0,
        source=bag_frames(bag, topics.COLOUR, topics.DEPTH),
        segmenter=GreenSegmenter(),
    )
    assert len(result.commands) == len(episode.commands) > 5
    assert [(v, w, c) for _, v, w, c, _ in result.commands] == [(v, w, c) for _, v, w, c in episode.commands]
    assert [r[0] for r in result.commands] == pytest.approx([c[0] for c in episode.commands], abs=1e-9)


def test_segcorridor_replays_the_bag_with_the_camera_of_its_camera_info(tmp_path) -> None:
    """SegCorridor, which `segmin replay` could not run before the follower config: its camera
    from the bag's CameraInfo on the config's mount, its commands the simulator's (flat ground:
    the IMU's level attitude changes nothing)."""
    episode, _ = _episode(GreenSegmenter(), method="segcorridor", bag=tmp_path / "run")
    follower = follower_config("segcorridor", 5.0, _config(length_m=LENGTH_M))
    camera = bag_camera(tmp_path / "run", topics.COLOUR_INFO, follower.camera)
    assert camera == make_follower("segcorridor", 5.0, _config()).navigator.camera
    result = replay(
        "model.onnx",
        None,
        tmp_path / "out",
        follower=follower,
        camera=camera,
        source=bag_frames(tmp_path / "run", topics.COLOUR, topics.DEPTH),
        segmenter=GreenSegmenter(),
    )
    assert len(result.commands) == len(episode.commands) > 5
    assert [(v, w, c) for _, v, w, c, _ in result.commands] == [(v, w, c) for _, v, w, c in episode.commands]
    assert any("no IMU: segcorridor assumed level ground" in note for note in result.notes)
    with pytest.raises(ValueError, match=r"Imu, not sensor_msgs/msg/CameraInfo, on '/imu/data' \(--camera-info-topic"):
        bag_camera(tmp_path / "run", topics.IMU, follower.camera)
    with pytest.raises(ValueError, match=r"no topic '/nope' \(--camera-info-topic.*the bag has: /camera"):
        bag_camera(tmp_path / "run", "/nope", follower.camera)


def test_segcorridor_replays_a_sloped_run_with_the_bags_imu(tmp_path, capsys) -> None:
    """On a sloped row (slope_vineyard_s8's cross slope) SegCorridor levels its points with the
    IMU's roll and pitch: replayed with the bag's /imu/data, each frame with the newest sample at
    or before it, its commands are the simulator's, bit for bit; on level ground they are not."""
    from segmin.nav_eval.replay.bags import bag_imu

    bag = tmp_path / "run"
    episode, _ = _episode(GreenSegmenter(), method="segcorridor", bag=bag, world=SlopedWorld())
    follower = follower_config("segcorridor", 5.0, _config(length_m=LENGTH_M))
    camera = bag_camera(bag, topics.COLOUR_INFO, follower.camera)
    imu = bag_imu(bag, topics.IMU, named=False)
    assert imu is not None and min(abs(roll) for roll, _ in imu.attitudes) > 0.05

    def commands(imu, out: str):
        source = bag_frames(bag, topics.COLOUR, topics.DEPTH)
        result = replay(
            "m.onnx",
            None,
            tmp_path / out,
            follower=follower,
            camera=camera,
            source=source,
            imu=imu,
            segmenter=GreenSegmenter(),
        )
        return [(v, w, c) for _, v, w, c, _ in result.commands], result.notes

    expected = [(v, w, c) for _, v, w, c in episode.commands]
    levelled, notes = commands(imu, "imu")
    assert len(expected) > 5 and levelled == expected
    assert not any("IMU" in note or topics.IMU in note for note in notes) and imu.stale == 0
    level, notes = commands(None, "level")
    assert level != expected and any("no IMU: segcorridor assumed level ground" in note for note in notes)
    assert bag_imu(bag, "/nope", named=False) is None  # a bag without the default topic: level ground
    argv = ["replay", "--model", "m.onnx", "--bag", str(bag), "--rgb-topic", topics.COLOUR, "--depth-topic"]
    argv += [topics.DEPTH, "--method", "segcorridor", "--depth-threshold", "5", "--out", str(tmp_path / "cli")]
    for topic, problem in (("/nope", "is not in the bag"), (topics.ODOM, "holds nav_msgs/msg/Odometry, not")):
        assert main([*argv, "--imu-topic", topic]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"--imu-topic {topic} {problem}" in err[0]


def test_the_round_trip_holds_with_the_onnx_model(exported, tmp_path) -> None:
    model = exported[0]
    episode, _ = _episode(OnnxSegmenter(model, threads=1), bag=tmp_path / "run")
    argv = ["replay", "--model", str(model), "--bag", str(tmp_path / "run"), "--rgb-topic", topics.COLOUR]
    argv += ["--depth-topic", topics.DEPTH, "--depth-threshold", "5", "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    rows = read_commands_csv(tmp_path / "out" / "commands.csv")
    assert [(v, w, c) for _, v, w, c, _ in rows] == [(v, w, c) for _, v, w, c in episode.commands]


def test_quaternions_of_rotations() -> None:
    for yaw in (0.0, 1.0, math.pi - 1e-3, -2.5):
        c, s = math.cos(yaw), math.sin(yaw)
        q = quaternion(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]))
        assert q == pytest.approx((0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)), abs=1e-12) or q == pytest.approx(
            (0.0, 0.0, -math.sin(yaw / 2), -math.cos(yaw / 2)), abs=1e-12
        )
    flip = quaternion(np.diag([1.0, -1.0, -1.0]))  # half a turn about x
    assert abs(flip[0]) == pytest.approx(1.0)


def _rotation(q) -> np.ndarray:
    """3 x 3 rotation of a geometry_msgs Quaternion (the textbook formula, independent of the recorder's)."""
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@pytest.fixture(scope="module")
def sloped_bag(tmp_path_factory):
    """(bag messages, robot state, camera) of one frame recorded on ground pitched and rolled."""
    from types import SimpleNamespace

    from segmin.nav_eval.sim.robot import RobotState

    camera = nav_camera(_config())
    state = RobotState(x=1.0, y=-0.5, yaw=0.7, pitch=0.12, roll=-0.09)
    simulator = SimpleNamespace(robot=SimpleNamespace(state=state))
    frame = SimpleNamespace(rgb=np.zeros((48, 48, 3), np.uint8), depth=np.ones((48, 48), np.float32))
    bag = tmp_path_factory.mktemp("sloped") / "run"
    with RunRecorder(bag, camera, seed=0) as recorder:
        recorder.frame(simulator, 0.0, frame)
    return _read(bag), state, camera


def test_the_recorded_camera_transform_projects_pixels_as_the_runtime_does(sloped_bag) -> None:
    """base_link -> camera_link -> optical frame from /tf_static, applied to pixels with planar
    depth, lands where the runtime's camera model puts them (tilted up by tilt_deg)."""
    from segmin.nav_eval.runtime.camera import CameraGeometry

    messages, _, camera = sloped_bag
    static = {s.child_frame_id: s.transform for s in messages[topics.TF_STATIC][0][1].transforms}
    mount, optical = static[topics.CAMERA_FRAME], static[topics.OPTICAL_FRAME]
    geometry = CameraGeometry.from_camera(camera)
    rows, cols, z = np.array([0.0, 23.0, 47.0, 10.0]), np.array([0.0, 24.0, 47.0, 40.0]), np.array([1.0, 2.0, 3.0, 5.0])
    in_optical = np.stack([z * (cols - geometry.cx) / geometry.fx, z * (rows - geometry.cy) / geometry.fy, z])
    offset = np.array([[mount.translation.x], [mount.translation.y], [mount.translation.z]])
    in_base = _rotation(mount.rotation) @ _rotation(optical.rotation) @ in_optical + offset
    assert in_base == pytest.approx(np.stack(geometry.robot_frame(rows, cols, z)), abs=1e-9)
    forward = _rotation(mount.rotation) @ _rotation(optical.rotation) @ np.array([0.0, 0.0, 1.0])
    assert math.degrees(math.asin(forward[2])) == pytest.approx(camera.tilt_deg)  # looks up, as rendered


def test_the_recorded_imu_reads_gravity_in_the_body_frame(sloped_bag) -> None:
    """At rest an accelerometer reads +g along the level frame's up axis, expressed in its body axes:
    g (-sin pitch, sin roll cos pitch, cos roll cos pitch) for the recorded (REP 103) attitude."""
    from segmin.nav_eval.ros2.sensors import attitude_from_imu
    from segmin.nav_eval.sim.robot import imu_attitude

    messages, state, _ = sloped_bag
    imu = messages[topics.IMU][0][1]
    roll, pitch = attitude_from_imu(imu, topics.IMU)
    assert (roll, pitch) == pytest.approx(imu_attitude(state), abs=1e-12) and min(abs(roll), abs(pitch)) > 0.05
    g = 9.80665
    expected = (-g * math.sin(pitch), g * math.sin(roll) * math.cos(pitch), g * math.cos(roll) * math.cos(pitch))
    acceleration = imu.linear_acceleration
    assert (acceleration.x, acceleration.y, acceleration.z) == pytest.approx(expected, abs=1e-9)
    assert acceleration.x > 0.5 and acceleration.y < -0.5  # nose up the slope, left side low


def test_nav_eval_writes_a_bag_per_field_and_method(tmp_path, capsys) -> None:
    out = tmp_path / "eval"
    argv = ["nav-eval", "--model", "oracle", "--fields", "straight_vineyard", "--methods", "segmin", "--runs", "2"]
    argv += ["--no-plots", "--no-progress", "--bag", "--out", str(out), "--set", "perception.width=64"]
    argv += ["perception.height=48", "run.length_m=1.0", "run.time_limit_s=8"]
    assert main(argv) == 0, capsys.readouterr().err
    bags = sorted((out / "bags").iterdir())
    assert [b.name for b in bags] == ["straight_vineyard_segmin"]  # run 0 only, like --video
    messages = _read(bags[0])
    colour = messages[topics.COLOUR][0][1]
    assert (colour.width, colour.height) == (64, 48)
    imu = messages[topics.IMU][0][1]
    assert math.hypot(imu.linear_acceleration.x, imu.linear_acceleration.y) < 9.80665 * 0.2  # gentle slopes
    assert imu.linear_acceleration.z > 9.0
    assert len(messages[topics.CMD_VEL]) >= 3
    assert not list(out.rglob("*.partial"))


def test_a_run_that_raises_leaves_no_bag(tmp_path) -> None:
    class Broken(GreenSegmenter):
        def segment(self, rgb: np.ndarray) -> np.ndarray:
            raise RuntimeError("inference failed")

    with pytest.raises(RuntimeError, match="inference failed"):
        _episode(Broken(), bag=tmp_path / "run")
    assert list(tmp_path.iterdir()) == []


def test_the_replay_bench_compares_bag_and_folders(exported, tmp_path, capsys) -> None:
    episode, _ = _episode(OnnxSegmenter(exported[0], threads=1), bag=tmp_path / "run")
    argv = ["replay-bag", "--model", str(exported[0]), "--bag", str(tmp_path / "run"), "--threads", "1"]
    assert benchmarks_main(argv) == 0
    out = capsys.readouterr().out
    assert "replay --bag:" in out and "frames/s" in out
    assert f"same commands: True ({len(episode.commands)} commands)" in out
