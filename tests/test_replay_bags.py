"""`segmin replay --bag`: ROS 1 bags and rosbag2 (sqlite3, MCAP) give the commands of the same
frames replayed from folders; image messages decode as an independent decoder does; colour and
depth pair by stamp; bad bags and bad messages stop with one line.

The fixture is the short RowEnv sequence of test_replay (stand-in world, 48 px, 30 Hz), written
both as PNG folders and as bags in several encodings.
"""

from __future__ import annotations

import struct
import sys

import cv2
import numpy as np
import pytest
from bag_helpers import ROS1, depth_message, image_message, write_bag
from test_nav_eval_sim import FakeRenderer, FakeWorld, _config

from segmin.app.cli import main
from segmin.nav_eval.replay.bags import bag_frames
from segmin.nav_eval.replay.ros_images import ImageMessageError, decode_colour, decode_depth
from segmin.nav_eval.replay.run import FrameSource, read_commands_csv, replay
from segmin.nav_eval.replay.stamp_pairing import StampOrderError, StampPairer
from segmin.nav_eval.sim.row_env import RowEnv

FRAMES = 24
RGB, DEPTH = "/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw"


class GreenSegmenter:
    """Deterministic stand-in for the ONNX model: vegetation is where green beats red."""

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        rgb = np.asarray(rgb, dtype=np.int16)
        return rgb[..., 1] > rgb[..., 0] + 20


@pytest.fixture(scope="module")
def frames() -> list[tuple[np.ndarray, np.ndarray]]:
    """(rgb uint8, depth uint16 mm) of 24 frames at 30 Hz."""
    world = FakeWorld()
    env = RowEnv(world, FakeRenderer(world, size=48), _config())
    env.reset(seed=0)
    out = []
    for _ in range(FRAMES):
        frame = env.frame()
        out.append((frame.rgb.copy(), np.clip(np.round(frame.depth * 1000), 0, 65535).astype(np.uint16)))
        env.step((0.4, 0.0))
    return out


@pytest.fixture(scope="module")
def folder_commands(frames, tmp_path_factory) -> list:
    """The commands of the folder replay (PNG frames, uint16 mm depth PNGs, 30 fps)."""
    folder = tmp_path_factory.mktemp("folders")
    (folder / "rgb").mkdir()
    (folder / "depth").mkdir()
    for i, (rgb, depth) in enumerate(frames):
        cv2.imwrite(str(folder / "rgb" / f"{i:04d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / "depth" / f"{i:04d}.png"), depth)
    result = replay(
        "model.onnx",
        folder / "rgb",
        folder / "out",
        method="segmind",
        depth_threshold=5.0,
        depth=folder / "depth",
        fps=30,
        segmenter=GreenSegmenter(),
    )
    assert len(result.commands) == 4 and any(row[4] for row in result.commands)
    return result.commands


def _messages(frames, colour: str, depth: str | None, store=None, depth_offset: float = 0.0) -> list:
    kwargs = {} if store is None else {"store": store}
    out = []
    for i, (rgb, depth_mm) in enumerate(frames):
        t = i / 30
        out.append((RGB, t, image_message(rgb, t, colour, **kwargs)))
        if depth is not None:
            out.append((DEPTH, t + depth_offset, depth_message(depth_mm, t + depth_offset, depth, **kwargs)))
    return out


def _same_commands(rows: list, expected: list) -> None:
    assert [r[1:] for r in rows] == [e[1:] for e in expected]  # v, omega, column, valid: bit-identical
    assert [r[0] for r in rows] == pytest.approx([e[0] for e in expected], abs=1e-9)  # ns stamps


@pytest.mark.parametrize(
    ("storage", "colour", "depth"),
    [
        ("mcap", "rgb8", "16UC1"),
        ("sqlite3", "bgr8", "32FC1"),
        ("ros1", "png", "compressedDepth"),
        ("mcap", "bgra8", "png"),
    ],
)
def test_a_bag_replays_to_the_commands_of_the_same_frames_in_folders(
    frames, folder_commands, tmp_path, storage, colour, depth
) -> None:
    store = ROS1 if storage == "ros1" else None
    bag = write_bag(tmp_path / "bag", _messages(frames, colour, depth, store), storage)
    result = replay(
        "model.onnx",
        None,
        tmp_path / "out",
        method="segmind",
        depth_threshold=5.0,
        source=bag_frames(bag, RGB, DEPTH),
        segmenter=GreenSegmenter(),
    )
    assert result.frames == FRAMES
    _same_commands(result.commands, folder_commands)
    assert (tmp_path / "out" / "commands.csv").is_file()


def test_depth_is_paired_by_stamp_within_the_slop_and_strays_are_counted(frames, folder_commands, tmp_path) -> None:
    messages = _messages(frames, "rgb8", "16UC1", depth_offset=0.003)
    stray = depth_message(frames[0][1], 5.0, "16UC1")  # long after the last colour frame
    bag = write_bag(tmp_path / "bag", [*messages, (DEPTH, 5.0, stray)], "mcap")
    result = replay(
        "model.onnx",
        None,
        tmp_path / "out",
        method="segmind",
        depth_threshold=5.0,
        source=bag_frames(bag, RGB, DEPTH, slop=0.005),
        segmenter=GreenSegmenter(),
    )
    _same_commands(result.commands, folder_commands)
    assert any("1 depth frame(s)" in note for note in result.notes), result.notes
    # With a slop below the offset nothing pairs: the replay stops naming --slop and the gap (below).
    with pytest.raises(ValueError, match=r"within --slop 0.001 s: their nearest stamps are 0.003 s apart"):
        list(bag_frames(bag, RGB, DEPTH, slop=0.001).frames)


def test_the_command_line_replays_a_bag_with_the_onnx_model(frames, exported, tmp_path, capsys) -> None:
    bag = write_bag(tmp_path / "bag", _messages(frames, "rgb8", "32FC1"), "mcap")
    args = ["replay", "--model", str(exported[0]), "--depth-threshold", "5", "--method", "segmind"]
    assert (
        main([*args, "--bag", str(bag), "--rgb-topic", RGB, "--depth-topic", DEPTH, "--out", str(tmp_path / "a")]) == 0
    )
    folder = tmp_path / "frames"
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    for i, (rgb, depth) in enumerate(frames):
        cv2.imwrite(str(folder / "rgb" / f"{i:04d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        np.save(folder / "depth" / f"{i:04d}.npy", depth.astype(np.float32) * np.float32(0.001))
    argv = [*args, "--rgb", str(folder / "rgb"), "--depth", str(folder / "depth"), "--fps", "30"]
    assert main([*argv, "--out", str(tmp_path / "b")]) == 0
    _same_commands(
        read_commands_csv(tmp_path / "a" / "commands.csv"), read_commands_csv(tmp_path / "b" / "commands.csv")
    )
    assert "replay: 24 frames, 4 commands" in capsys.readouterr().out


def _error(argv: list[str], capsys) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("segmin: error:"), err
    return err[0]


def test_bad_bags_and_options_stop_with_one_line(frames, tmp_path, capsys) -> None:
    bag = write_bag(tmp_path / "bag", _messages(frames[:3], "rgb8", "16UC1"), "mcap")
    base = ["replay", "--model", "m.onnx", "--depth-threshold", "5", "--out", str(tmp_path / "o"), "--bag", str(bag)]
    line = _error([*base, "--rgb-topic", "/camera/rgb", "--depth-topic", DEPTH], capsys)
    assert "no topic '/camera/rgb'" in line and f"{RGB} (sensor_msgs/msg/Image, 3)" in line
    assert "holds sensor_msgs/msg/Image" not in line
    assert "--rgb-topic" in _error([*base, "--depth-topic", DEPTH], capsys)
    assert "--depth-topic" in _error([*base, "--rgb-topic", RGB], capsys)  # segmind without depth
    assert "does not go with --bag" in _error([*base, "--rgb-topic", RGB, "--fps", "30"], capsys)
    assert "goes with --bag" in _error(["replay", "--model", "m", "--depth-threshold", "5", "--out", "o",
                                        "--rgb", str(tmp_path), "--rgb-topic", RGB], capsys)  # fmt: skip
    (tmp_path / "junk").mkdir()
    assert "not a ROS 1 .bag file or a rosbag2 folder" in _error(
        [*base[:-1], str(tmp_path / "junk"), "--rgb-topic", RGB, "--method", "segmin"], capsys
    )


def test_bad_messages_in_a_bag_stop_with_one_line_naming_the_topic(frames, exported, tmp_path, capsys) -> None:
    rgb, depth = frames[0]
    odd = image_message(rgb, 0.0, "rgb8")
    odd.encoding = "yuv422"
    bag = write_bag(tmp_path / "enc", [(RGB, 0.0, odd)], "mcap")
    base = ["replay", "--model", str(exported[0]), "--depth-threshold", "5", "--method", "segmin", "--rgb-topic", RGB]
    line = _error([*base, "--bag", str(bag), "--out", str(tmp_path / "o1")], capsys)
    assert f"{RGB}: colour encoding 'yuv422'" in line
    backwards = [(RGB, 0.1, image_message(rgb, 0.1, "rgb8")), (RGB, 0.2, image_message(rgb, 0.05, "rgb8"))]
    bag = write_bag(tmp_path / "back", backwards, "mcap")
    line = _error([*base, "--bag", str(bag), "--out", str(tmp_path / "o2")], capsys)
    assert "is not after the previous frame" in line
    small = depth_message(depth[:24], 0.0, "16UC1")
    bag = write_bag(tmp_path / "size", [(RGB, 0.0, image_message(rgb, 0.0, "rgb8")), (DEPTH, 0.0, small)], "mcap")
    line = _error([*base, "--bag", str(bag), "--depth-topic", DEPTH, "--out", str(tmp_path / "o3")], capsys)
    assert "depth is 48x24, rgb is 48x48" in line


def _bag_argv(model: str, bag, out) -> list[str]:
    """`segmin replay` of `bag` into `out` (SegMinD unless --method follows)."""
    return ["replay", "--model", model, "--depth-threshold", "5", "--out", str(out), "--bag", str(bag)]


def test_a_bag_that_pairs_nothing_stops_naming_slop_and_writes_nothing(frames, exported, tmp_path, capsys) -> None:
    """It exited 0, saying it wrote an overlay video that did not exist."""
    bag = write_bag(tmp_path / "bag", _messages(frames[:8], "rgb8", "16UC1", depth_offset=0.05), "mcap")
    base = _bag_argv(str(exported[0]), bag, tmp_path / "o")
    line = _error([*base, "--rgb-topic", RGB, "--depth-topic", DEPTH, "--slop", "0.01"], capsys)
    assert f"no colour frame of {RGB} has a depth frame of {DEPTH} within --slop 0.01 s" in line
    assert "their nearest stamps are 0.0166667 s apart" in line  # 0.05 s late: nearest the next colour frame
    line = _error([*base, "--rgb-topic", RGB, "--depth-topic", RGB, "--method", "segmin"], capsys)
    assert f"--rgb-topic and --depth-topic are both {RGB}" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_a_topic_without_messages_is_refused_before_any_output(frames, tmp_path, capsys, storage) -> None:
    store = ROS1 if storage == "ros1" else None
    bag = write_bag(tmp_path / "bag", _messages(frames[:3], "rgb8", None, store), storage, empty=(DEPTH,))
    base = _bag_argv("m.onnx", bag, tmp_path / "o")
    line = _error([*base, "--rgb-topic", RGB, "--depth-topic", DEPTH], capsys)
    assert f"--depth-topic {DEPTH} has no messages; the bag has: " in line and f"{DEPTH} (" in line
    bag = write_bag(tmp_path / "colourless", [], storage, empty=(RGB,))
    line = _error([*base[:-1], str(bag), "--rgb-topic", RGB, "--method", "segmin"], capsys)
    assert f"--rgb-topic {RGB} has no messages" in line
    assert not (tmp_path / "o").exists()


def test_millimetres_in_32fc1_are_refused_at_the_message_as_from_folders(frames, exported, tmp_path, capsys) -> None:
    messages = _messages(frames[:4], "rgb8", "32FC1")
    _, t, late = messages[5]  # frame 2's depth, sent in millimetres
    late.data = frames[2][1].astype(np.float32).view(np.uint8).reshape(-1).copy()
    bag = write_bag(tmp_path / "bag", messages, "mcap")
    base = _bag_argv(str(exported[0]), bag, tmp_path / "o")
    line = _error([*base, "--rgb-topic", RGB, "--depth-topic", DEPTH], capsys)
    assert f"{DEPTH}: 32FC1: float depth must be metres, but its values range from" in line
    assert f"({DEPTH} message 2 (stamp {t:.9f} s))" in line
    assert not (tmp_path / "o").exists()


class CountingSegmenter(GreenSegmenter):
    def __init__(self) -> None:
        self.calls = 0

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        self.calls += 1
        return super().segment(rgb)


def test_a_colour_frame_of_another_size_stops_at_that_frame(frames, tmp_path) -> None:
    """Frame 6 is a command tick (5 Hz of 30 Hz frames): its panel went into the video, and the run
    failed only at its end, naming video panel sizes."""
    messages = _messages(frames, "rgb8", None)
    odd = cv2.resize(frames[6][0], (40, 40))
    messages[6] = (RGB, messages[6][1], image_message(odd, messages[6][1], "rgb8"))
    bag = write_bag(tmp_path / "bag", messages, "mcap")
    segmenter = CountingSegmenter()
    match = rf"^--bag .*: {RGB} message 6 \(stamp 0.200000000 s\) is 40x40, the colour frames before it are 48x48$"
    with pytest.raises(ValueError, match=match):
        replay(
            "model.onnx", None, tmp_path / "out", method="segmin", depth_threshold=5.0,
            source=bag_frames(bag, RGB), segmenter=segmenter,
        )  # fmt: skip
    assert 0 < segmenter.calls < 6 and not (tmp_path / "out").exists()


def test_a_source_that_yields_no_frame_writes_nothing(tmp_path) -> None:
    empty = FrameSource(count=0, frames=iter([]), has_depth=False)
    with pytest.raises(ValueError, match=r"^no frame of the 0 reached the runtime: nothing written$"):
        replay("model.onnx", None, tmp_path / "out", method="segmin", depth_threshold=5.0, source=empty,
               segmenter=GreenSegmenter())  # fmt: skip
    assert not (tmp_path / "out").exists()


def test_without_rosbags_the_extra_is_named(frames, tmp_path, capsys, monkeypatch) -> None:
    bag = write_bag(tmp_path / "bag", _messages(frames[:2], "rgb8", None), "mcap")
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    line = _error(["replay", "--model", "m.onnx", "--depth-threshold", "5", "--method", "segmin", "--out",
                   str(tmp_path / "o"), "--bag", str(bag), "--rgb-topic", RGB], capsys)  # fmt: skip
    assert "[ros] extra" in line and "pip install 'segmin[ros]'" in line


# ---- the decoder, against rosbags-image (an independent implementation) --------------------


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "rgba8", "bgra8"])
def test_raw_colour_honours_a_padded_row_stride(frames, encoding) -> None:
    rgb = frames[5][0]
    message = image_message(rgb, 0.2, encoding, pad=4)
    assert message.step > rgb.shape[1] * len(encoding.rstrip("8"))
    decoded = decode_colour(message, RGB)
    assert decoded.dtype == np.uint8 and np.array_equal(decoded, rgb)


@pytest.mark.parametrize("encoding", ["bgr8", "bgra8"])
def test_blue_first_colour_is_swapped_to_rgb(encoding) -> None:
    """The scene's pixels have red == blue, which a missing swap would pass; these do not."""
    channels = len(encoding) - 1
    blue_first = np.array([[[200, 100, 10, 255][:channels], [1, 2, 3, 4][:channels]]], np.uint8)  # B, G, R(, A)
    message = image_message(np.zeros((1, 2, 3), np.uint8), 0.0, encoding)
    message.data, message.step = blue_first.reshape(-1).copy(), 2 * channels
    assert decode_colour(message, RGB).tolist() == [[[10, 100, 200], [3, 2, 1]]]


def test_unpadded_raw_and_jpeg_messages_decode_as_rosbags_image_does(frames) -> None:
    from rosbags.image import message_to_cvimage

    rgb = frames[5][0]
    for encoding in ("rgb8", "bgr8", "bgra8", "png", "jpeg"):
        message = image_message(rgb, 0.2, encoding)
        assert np.array_equal(decode_colour(message, RGB), message_to_cvimage(message, "rgb8")), encoding


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1", "png"])
def test_depth_messages_decode_to_metres_as_rosbags_image_does(frames, encoding) -> None:
    from rosbags.image import message_to_cvimage

    depth_mm = frames[5][1]
    message = depth_message(depth_mm, 0.2, encoding)
    metres, bad = decode_depth(message, DEPTH)
    assert not bad and metres.dtype == np.float32
    assert np.array_equal(metres, depth_mm.astype(np.float32) * np.float32(0.001))
    if encoding != "png":  # rosbags-image reads a compressed image as 8 bits (IMREAD_ANYCOLOR)
        reference = message_to_cvimage(message)
        scale = np.float32(1.0) if encoding == "32FC1" else np.float32(0.001)
        assert np.array_equal(metres, reference.astype(np.float32) * scale)


def test_depth_details_big_endian_non_finite_and_quantised_compressed_depth(frames) -> None:
    depth_mm = frames[5][1]
    message = depth_message(depth_mm, 0.2, "16UC1")
    message.data = depth_mm.astype(">u2").view(np.uint8).reshape(-1).copy()
    message.is_bigendian = 1
    assert np.array_equal(decode_depth(message, DEPTH)[0], depth_mm.astype(np.float32) * np.float32(0.001))
    holes = depth_mm.astype(np.float32) * np.float32(0.001)
    holes[0, :3] = (np.nan, np.inf, -np.inf)
    message = depth_message(depth_mm, 0.2, "32FC1")
    message.data = holes.view(np.uint8).reshape(-1).copy()
    metres, bad = decode_depth(message, DEPTH)
    assert bad and np.all(metres[0, :3] == 0) and np.array_equal(metres[1:], holes[1:])
    # image_transport's 32FC1 compressedDepth: q = a / z + b, 0 = no reading.
    a, b = 100.0, -10.0
    z = np.array([[2.0, 4.0], [5.0, 0.0]], np.float32)
    q = np.where(z > 0, np.round(a / np.where(z > 0, z, 1) + b), 0).astype(np.uint16)
    png = cv2.imencode(".png", q)[1]
    message.format, message.data = (
        "32FC1; compressedDepth png",
        np.frombuffer(struct.pack("<iff", 0, a, b) + png.tobytes(), np.uint8),
    )
    assert np.allclose(decode_depth(message, DEPTH)[0], a / (q.astype(np.float32) - b) * (q > 0))


def test_messages_that_are_not_usable_images_name_the_topic(frames) -> None:
    rgb, depth_mm = frames[0]
    message = image_message(rgb, 0.0, "rgb8")
    message.step = 10
    with pytest.raises(ImageMessageError, match=r"^/cam: step 10 is shorter than a row"):
        decode_colour(message, "/cam")
    message = image_message(rgb, 0.0, "rgb8")
    message.data = message.data[:100]
    with pytest.raises(ImageMessageError, match=r"^/cam: 100 bytes of data for 48 rows"):
        decode_colour(message, "/cam")
    with pytest.raises(ImageMessageError, match=r"^/d: depth encoding 'rgb8'"):
        decode_depth(image_message(rgb, 0.0, "rgb8"), "/d")
    with pytest.raises(ImageMessageError, match=r"^/cam: a compressedDepth image on the colour topic"):
        decode_colour(depth_message(depth_mm, 0.0, "compressedDepth"), "/cam")
    with pytest.raises(ImageMessageError, match=r"^/d: compressed depth .* must be a 16-bit one-channel PNG"):
        decode_depth(image_message(rgb, 0.0, "png"), "/d")


# ---- pairing ---------------------------------------------------------------------------------


def test_the_pairer_takes_the_nearest_partner_and_drops_the_rest() -> None:
    pairer = StampPairer(0.01)
    assert pairer.add_depth(0.000, "d0") == []
    assert pairer.add_depth(0.004, "d1") == []
    pairs = pairer.add_colour(0.005, "c0")  # d1 is nearer than d0
    assert [(c.item, d.item) for c, d in pairs] == [("c0", "d1")]
    assert pairer.dropped_depth == 1
    assert pairer.add_colour(0.100, "c1") == []  # waits for its depth
    assert pairer.add_depth(0.200, "d2") == []  # c1 can have no partner now
    assert pairer.dropped_colour == 1
    with pytest.raises(StampOrderError, match="is not after the previous depth frame"):
        pairer.add_depth(0.150, "d3")
    pairer.finish()
    assert pairer.dropped_depth == 2


@pytest.mark.parametrize(("slop", "gap"), [(0.0, 0.0), (0.25, 0.25)])
def test_a_gap_of_exactly_the_slop_pairs(slop, gap) -> None:
    """The tolerance is inclusive: slop 0 pairs equal stamps (segmin's own bags), and a gap of exactly slop pairs."""
    pairer = StampPairer(slop)
    assert pairer.add_colour(1.0, "c") == []
    assert [(c.item, d.item) for c, d in pairer.add_depth(1.0 + gap, "d")] == [("c", "d")]
    assert pairer.dropped_colour == pairer.dropped_depth == 0


def test_a_live_pairer_bounds_what_waits() -> None:
    pairer = StampPairer(0.01, max_pending=2)
    for i in range(5):
        pairer.add_colour(i / 30, i)
    assert pairer.dropped_colour == 3


def _imu_message(roll: float, covariance0: float = 0.0):
    from types import SimpleNamespace

    half = roll / 2
    orientation = SimpleNamespace(x=np.sin(half), y=0.0, z=0.0, w=np.cos(half))
    return SimpleNamespace(orientation=orientation, orientation_covariance=[covariance0] + [0.0] * 8)


def test_each_frame_takes_the_newest_imu_sample_at_or_before_it_and_a_stale_one_is_level_ground() -> None:
    """As the node: a sample after the frame is not used, one older than imu_max_age_s is stale
    (level ground, counted), a message without orientation is skipped (counted), stamps in any order."""
    from segmin.nav_eval.replay.imu import DEFAULT_IMU_TOPIC, IMU_MAX_AGE_S, ImuTrack
    from segmin.nav_eval.ros2 import topics
    from segmin.nav_eval.ros2.params import NodeSettings

    assert (topics.IMU, NodeSettings().imu_max_age_s) == (DEFAULT_IMU_TOPIC, IMU_MAX_AGE_S)
    track = ImuTrack("/imu")
    for t, roll in ((1.0, 0.1), (0.5, 0.05), (1.2, 0.2)):
        track.add(t, _imu_message(roll))
    track.add(1.1, _imu_message(0.3, covariance0=-1.0))
    assert track.at(1.0)[0] == pytest.approx(0.1) and track.at(1.09)[0] == pytest.approx(0.1)
    assert track.at(0.55)[0] == pytest.approx(0.05)
    assert track.at(0.4) is None and track.at(1.2 + IMU_MAX_AGE_S + 1e-6) is None and track.stale == 2
    notes = track.notes()
    assert "1 message(s) of /imu ignored (first: /imu: the IMU gives no orientation" in notes[0]
    assert notes[1].startswith("2 frame(s) had no /imu sample within 0.1 s")
