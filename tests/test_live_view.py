"""The live view in Foxglove (`--live`), checked by a protocol client on loopback (`live_client`):

- a replay streams every channel within 1 s of the client's connection and at least 95 % of
  the frames of a 30 Hz sequence, each payload a ROS 2 message of its advertised schema;
- a nav-eval run streams exactly the topics, schemas (byte for byte) and messages its bag holds,
  so one layout opens both, and the bag holds the view topics;
- the rows drawn for SegCorridor lie half the corridor width to each side of its centreline;
- the shipped layout names only topics the live view publishes;
- a port in use and a missing foxglove-sdk are one line each, exit 2.
"""

from __future__ import annotations

import json
import socket
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from test_nav_eval_sim import FakeRenderer, FakeWorld, _config
from test_replay_bags import GreenSegmenter
from test_sim_bags import LENGTH_M, _ImageFrames

from benchmarks.live_client import LiveClient, free_port
from segmin.app.cli import main
from segmin.nav_eval.evaluation.rollout import run_episode
from segmin.nav_eval.live.publisher import LiveView
from segmin.nav_eval.live.server import LIVE_TYPES, LiveServer
from segmin.nav_eval.live.view import MARKER_ADD, ViewMessages
from segmin.nav_eval.replay.run import FrameSource, replay
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.sim.bag_recorder import TOPIC_TYPES, RunRecorder
from segmin.nav_eval.sim.factories import make_follower, nav_camera
from segmin.nav_eval.sim.row_env import RowEnv

STORE = get_typestore(Stores.ROS2_HUMBLE)
LAYOUT = Path(__file__).resolve().parent.parent / "configs" / "foxglove" / "segmin_live.json"
HZ, FRAMES = 30.0, 45  # 1.5 s of camera at 30 Hz


class _Rows:
    """A segmenter of two walls of vegetation at the image's sides."""

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        mask = np.zeros(rgb.shape[:2], dtype=bool)
        mask[:, :12] = mask[:, -12:] = True
        return mask


def _paced(count: int, hz: float) -> Iterator[tuple[str, float, np.ndarray, np.ndarray, bool]]:
    """`count` tiny frames, each handed out when due at `hz` (a camera's pace)."""
    start = time.perf_counter()
    for i in range(count):
        wait = start + i / hz - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        rgb = np.full((36, 48, 3), 90, dtype=np.uint8)
        yield f"f{i}", i / hz, rgb, np.full((36, 48), 3.0, dtype=np.float32), False


def _client(port: int) -> LiveClient:
    """A client subscribed to every channel of the server on `port`."""
    client = LiveClient(port)
    assert client.connected.wait(5), "the client did not connect"
    deadline = time.monotonic() + 5
    while not client.received.channels and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.1)  # the subscription reaches the server
    return client


def test_replay_streams_every_channel_within_a_second_and_the_frames_at_30_hz(tmp_path) -> None:
    port = free_port()
    with LiveServer(LIVE_TYPES, port) as server:
        client = _client(port)
        source = FrameSource(count=FRAMES, frames=_paced(FRAMES, HZ), has_depth=True)
        result = replay(
            "unused.onnx", None, tmp_path, method="segmind", depth_threshold=5.0, force=True,
            segmenter=_Rows(), source=source, live=LiveView(server),
        )  # fmt: skip
        time.sleep(0.2)
        got = client.stop()
    assert got.topics() == set(LIVE_TYPES)
    assert max(got.subscribed_at.values()) < 1.0
    first = {topic: min(arrival for name, _, _, arrival in got.messages if name == topic) for topic in LIVE_TYPES}
    assert max(first.values()) < 1.0, first
    counts = Counter(name for name, *_ in got.messages)
    assert counts[topics.OVERLAY] >= 0.95 * FRAMES, counts
    assert counts[topics.CMD_VEL] == len(result.commands) == counts[topics.HISTOGRAM] == counts[topics.ROWS]
    for channel in got.channels.values():
        assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg")
        assert channel["schemaName"] == LIVE_TYPES[channel["topic"]]
        assert channel["schema"] == STORE.generate_msgdef(channel["schemaName"], ros_version=2)[0]
        for payload in got.of(channel["topic"]):
            STORE.deserialize_cdr(payload, channel["schemaName"])
    image = STORE.deserialize_cdr(got.of(topics.OVERLAY)[-1], "sensor_msgs/msg/Image")
    pixels = image.data.reshape(image.height, image.width, 3)
    assert (image.encoding, image.width) == ("rgb8", 48)
    assert (pixels[:, 0] != 90).any()  # the mask is drawn
    twist = STORE.deserialize_cdr(got.of(topics.CMD_VEL)[-1], "geometry_msgs/msg/Twist")
    assert (twist.linear.x, twist.angular.z) == pytest.approx(result.commands[-1][1:3])


def _episode(method: str, bag: Path | None, live_port: int = 0):
    config = _config(length_m=LENGTH_M)
    world = FakeWorld()
    simulator = RowEnv(world, FakeRenderer(world), config)
    follower = make_follower(method, 5.0, config)
    with RunRecorder(bag, nav_camera(config), seed=3, live_port=live_port) as recorder:
        client = _client(live_port) if live_port else None
        episode = run_episode(simulator, follower, _ImageFrames(GreenSegmenter()), seed=3, recorder=recorder)
        time.sleep(0.3)
        got = client.stop() if client is not None else None
    return episode, got


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, object]:
    """A SegCorridor run in the stand-in world, written as a bag."""
    bag = tmp_path_factory.mktemp("live") / "run"
    episode, _ = _episode("segcorridor", bag)
    return bag, episode


def test_nav_eval_streams_the_topics_schemas_and_messages_of_its_bag(recorded) -> None:
    from rosbags.highlevel import AnyReader

    bag, episode = recorded
    with AnyReader([bag]) as reader:
        schemas = {c.topic: (c.msgtype, c.msgdef.data) for c in reader.connections}
        counts = Counter(c.topic for c, _, _ in reader.messages())
        rows = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages() if c.topic == topics.ROWS]
    assert set(schemas) == set(TOPIC_TYPES) and {topics.OVERLAY, topics.PATH} <= set(counts)
    assert counts[topics.OVERLAY] == counts[topics.COLOUR] and counts[topics.PATH] == len(episode.commands)
    assert any(m.action == MARKER_ADD and len(m.points) > 1 for array in rows for m in array.markers)

    live_episode, got = _episode("segcorridor", None, live_port=free_port())
    assert live_episode.commands == episode.commands  # streaming changes nothing of the run
    assert {c["topic"]: (c["schemaName"], c["schema"]) for c in got.channels.values()} == schemas
    assert Counter(name for name, *_ in got.messages) == counts


def test_replaying_a_bag_live_streams_its_odometry_as_the_path_and_tf(recorded, tmp_path, capsys) -> None:
    from segmin.nav_eval.replay.bags import bag_poses

    bag, _ = recorded
    port = free_port()
    client = LiveClient(port)  # connects once the replay's server is up
    argv = ["replay", "--model", "unused.onnx", "--bag", str(bag), "--rgb-topic", topics.COLOUR, "--depth-topic"]
    argv += [topics.DEPTH, "--method", "segmind", "--depth-threshold", "5", "--out", str(tmp_path / "out")]
    with pytest.MonkeyPatch.context() as patch:  # the stand-in world's segmenter instead of a model file
        patch.setattr("segmin.nav_eval.runtime.segmenter.OnnxSegmenter", lambda *a, **k: GreenSegmenter())
        patch.setattr("segmin.nav_eval.runtime.segmenter.resolve_model", lambda model, **_: Path(model))
        assert main([*argv, "--live", "--live-port", str(port), "--live-rate", "2"]) == 0
    got = client.stop()
    assert f"live view: ws://127.0.0.1:{port};" in capsys.readouterr().out
    assert got.topics() == set(LIVE_TYPES) | {topics.PATH, topics.TF}
    path = STORE.deserialize_cdr(got.of(topics.PATH)[-1], "nav_msgs/msg/Path")
    last = path.poses[-1]
    t = last.header.stamp.sec + last.header.stamp.nanosec * 1e-9
    pose = [p for s, p in bag_poses(bag, topics.ODOM) if s <= t + 1e-9][-1]
    assert (last.pose.position.x, last.pose.position.y, last.pose.orientation.w) == (pose[0], pose[1], pose[6])
    tf = STORE.deserialize_cdr(got.of(topics.TF)[-1], "tf2_msgs/msg/TFMessage").transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id, tf.transform.translation.x) == ("odom", "base_link", pose[0])


def test_rows_lie_half_the_corridor_width_beside_the_centreline() -> None:
    navigator = SimpleNamespace(config=SimpleNamespace(x_min=1.0, x_max=5.0), corridor_width=2.0)
    markers = ViewMessages(STORE.types).rows(0.5, (0.3, 0.1), navigator).markers
    centre, left, right = ([(p.x, p.y) for p in m.points] for m in markers)
    assert centre[0] == pytest.approx((1.0, 0.4)) and centre[-1] == pytest.approx((5.0, 0.8))
    assert [y for _, y in left] == pytest.approx([y + 1.0 for _, y in centre])
    assert [y for _, y in right] == pytest.approx([y - 1.0 for _, y in centre])
    assert {m.header.frame_id for m in markers} == {topics.BASE_FRAME}


def _layout_topics(node: object) -> set[str]:
    """Every topic a layout's panels name: keys and values starting with '/', cut at a message path."""
    if isinstance(node, dict):
        return set().union(*(_layout_topics(k) | _layout_topics(v) for k, v in node.items()))
    if isinstance(node, list):
        return set().union(*(_layout_topics(v) for v in node)) if node else set()
    if isinstance(node, str) and node.startswith("/"):
        return {node.split(".", 1)[0]}
    return set()


def test_the_layout_shows_only_topics_the_live_view_publishes() -> None:
    named = _layout_topics(json.loads(LAYOUT.read_text()))
    assert {topics.OVERLAY, topics.HISTOGRAM, topics.ROWS, topics.PATH, topics.CMD_VEL} <= named
    assert named <= set(TOPIC_TYPES)  # what nav-eval's live view and its bags carry


def _replay_argv(tmp_path: Path, port: int) -> list[str]:
    return ["replay", "--model", "x.onnx", "--rgb", str(tmp_path), "--out", str(tmp_path / "out")] + [
        "--depth-threshold", "5", "--live", "--live-port", str(port),
    ]  # fmt: skip


def test_a_port_in_use_is_one_line_naming_it(tmp_path, capsys) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(_replay_argv(tmp_path, port)) == 2
        nav_eval = ["nav-eval", "--model", "oracle", "--out", str(tmp_path / "n"), "--live", "--live-port", str(port)]
        assert main(nav_eval) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2 and all(f"--live-port {port}: 127.0.0.1:{port} is in use" in line for line in lines)


def test_a_missing_foxglove_sdk_names_the_extra(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setitem(__import__("sys").modules, "foxglove", None)  # `import foxglove` fails as if not installed
    assert main(_replay_argv(tmp_path, free_port())) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "[live] extra" in err and "pip install 'segmin[live]'" in err


def test_nav_eval_live_takes_one_run(tmp_path, capsys) -> None:
    argv = ["nav-eval", "--model", "oracle", "--fields", "curved_vineyard", "--methods", "segmin", "--runs", "2"]
    assert main([*argv, "--out", str(tmp_path), "--live", "--live-port", str(free_port())]) == 2
    assert "--live streams one run" in capsys.readouterr().err
    assert main([*argv, "--out", str(tmp_path), "--live", "--executor", "ray"]) == 2
    assert "--live streams a run from this computer" in capsys.readouterr().err


def test_the_looked_up_tint_is_the_per_pixel_blend_to_the_bit() -> None:
    from segmin.data.overlay import GREEN, MAGENTA, tint_mask

    rng = np.random.default_rng(0)
    for opacity in (0.4, 0.45, 0.5, 0.55):
        for colour in (GREEN, MAGENTA, (12, 200, 77)):
            rgb = rng.integers(0, 256, (17, 23, 3), dtype=np.uint8)
            mask = rng.random((17, 23)) > 0.5
            keep = round(1.0 - opacity, 6)
            expected = rgb.copy()
            expected[mask] = (keep * rgb[mask] + opacity * np.asarray(colour)).astype(np.uint8)
            assert np.array_equal(tint_mask(rgb, mask, colour, opacity), expected)


def test_a_wide_frame_is_drawn_at_the_overlay_width_with_its_mask_and_column() -> None:
    from segmin.nav_eval.runtime.control import Command

    mask = np.zeros((480, 640), dtype=bool)
    mask[:, :160] = True
    output = SimpleNamespace(fresh=True, fused=mask, command=Command(0.5, 0.0, 400.0, np.zeros(640), True))
    view = ViewMessages(STORE.types)
    (topic, image), *_ = view.step(0.0, np.zeros((480, 640, 3), dtype=np.uint8), output, None)
    pixels = image.data.reshape(image.height, image.width, 3)
    assert (topic, image.width, image.height) == (topics.OVERLAY, 224, 168)
    assert (pixels[:, :55, 1] > 0).all() and (pixels[:, 57:130, 1] == 0).all()  # the mask, a quarter of the width
    assert (pixels[:, 139:141] == (255, 0, 0)).all()  # column 400 of 640 at 140 of 224


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (70000, r"parameter live_port: live_port must be 0 \(off\) or a TCP port"),
        ("8765", "parameter live_port: expected int"),
    ],
)
def test_the_nodes_live_port_parameter_is_checked(value, message) -> None:
    from segmin.nav_eval.ros2.params import STARTUP_ONLY, as_values, node_params

    params = node_params({"live_port": 8765})
    assert params.node.live_port == 8765 and as_values(params)["live_port"] == 8765
    assert node_params({}).node.live_port == 0 and "live_port" in STARTUP_ONLY  # off unless asked; fixed at start-up
    with pytest.raises(ValueError, match=message):
        node_params({"live_port": value})


def test_nav_eval_live_streams_its_one_run(tmp_path, capsys) -> None:
    port = free_port()
    client = LiveClient(port, timeout=60)  # connects once the run's server is up
    argv = ["nav-eval", "--model", "oracle", "--fields", "straight_vineyard", "--methods", "segmin", "--runs", "1"]
    argv += ["--no-plots", "--no-progress", "--out", str(tmp_path), "--set", "perception.width=64"]
    argv += ["perception.height=48", "run.length_m=1.0", "run.time_limit_s=8", "--live", "--live-port", str(port)]
    assert main(argv) == 0, capsys.readouterr().err
    got = client.stop()
    assert got.topics() == set(TOPIC_TYPES)
    counts = Counter(name for name, *_ in got.messages)
    assert counts[topics.OVERLAY] == counts[topics.COLOUR] > 0 and counts[topics.CMD_VEL] > 0


def test_the_path_keeps_the_newest_poses_only(monkeypatch) -> None:
    """A long run's path message stays bounded: the newest PATH_POSES poses, in order."""
    from segmin.nav_eval.live import view

    monkeypatch.setattr(view, "PATH_POSES", 3)
    messages = view.ViewMessages(STORE.types)
    types = STORE.types
    for k in range(5):
        pose = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=float(k), y=0.0, z=0.0),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        path = messages.path(0.2 * k, pose)
    assert [p.pose.position.x for p in path.poses] == [2.0, 3.0, 4.0]
