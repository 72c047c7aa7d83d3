"""`segmin ros2 view-bag`: the picture of a simulated bag's topics (no ROS, no viewer)."""

from __future__ import annotations

import numpy as np
import pytest
from test_replay_bags import GreenSegmenter
from test_sim_bags import _episode, _read

from segmin.app.cli import main
from segmin.data.overlay import GREEN, tint_mask
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.ros2.bag_view import plot_bag_view, read_bag_view


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    bag = tmp_path_factory.mktemp("view") / "run"
    episode, _ = _episode(GreenSegmenter(), bag=bag)
    return bag, episode


def test_the_view_holds_the_frame_nearest_the_time_and_the_whole_run(recorded) -> None:
    bag, episode = recorded
    view = read_bag_view(bag, 0.5)
    frame_period = 1 / 30
    assert abs(view.frame_t - 0.5) <= frame_period / 2 + 1e-6
    assert view.rgb.dtype == np.uint8 and view.rgb.ndim == 3
    assert view.depth is not None and view.depth.shape == view.rgb.shape[:2] and np.nanmin(view.depth) > 0
    assert view.commands[:, 1:].tolist() == [[v, omega] for _, v, omega, *_ in episode.commands]
    assert len(view.path) > 10 and view.path[-1, 1] > view.path[0, 1]  # the robot drove forward (+x)


def test_the_view_is_the_recorded_frame_its_depth_and_the_odometry(recorded) -> None:
    """Read back independently (rosbags): the colour message nearest the time, the depth message of
    its stamp (0 = no reading shown as NaN), and /odom, all on the bag's clock from its first message."""
    bag, _ = recorded
    messages = _read(bag)
    start = min(t for topic, stamped in messages.items() if topic != "types" for t, _ in stamped)
    at = 0.52
    colour_ns, colour = min(messages[topics.COLOUR], key=lambda m: abs((m[0] - start) * 1e-9 - at))
    depth = next(m for t, m in messages[topics.DEPTH] if t == colour_ns)
    view = read_bag_view(bag, at)
    assert view.frame_t == pytest.approx((colour_ns - start) * 1e-9, abs=1e-9) and view.frame_t != at
    rgb = np.frombuffer(colour.data, np.uint8).reshape(colour.height, colour.width, 3)
    assert np.array_equal(view.rgb, rgb)
    metres = np.frombuffer(depth.data, np.float32).reshape(depth.height, depth.width)
    assert view.depth is not None and np.array_equal(view.depth, np.where(metres > 0, metres, np.nan), equal_nan=True)
    odom = [((t - start) * 1e-9, m.pose.pose.position.x, m.pose.pose.position.y) for t, m in messages[topics.ODOM]]
    assert view.path == pytest.approx(np.array(odom), abs=1e-9)


def test_the_picture_draws_the_masked_frame_the_depth_the_commands_and_the_path(recorded, monkeypatch) -> None:
    """What each panel holds, read off the figure before it is closed."""
    import matplotlib.pyplot as plt

    bag, _ = recorded
    view = read_bag_view(bag, 1.0)
    mask = GreenSegmenter().segment(view.rgb)
    assert 0 < np.count_nonzero(mask) < mask.size
    close, figures = plt.close, []
    monkeypatch.setattr(plt, "close", figures.append)
    png = plot_bag_view(view, "a run", mask)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(figures) == 1
    figure = figures[0]
    try:
        colour_ax, depth_ax, command_ax, path_ax = figure.axes[:4]
        shown = np.asarray(colour_ax.images[0].get_array())
        assert np.array_equal(shown, tint_mask(view.rgb, mask, GREEN, opacity=0.45))
        assert np.array_equal(shown[~mask], view.rgb[~mask]) and np.any(shown[mask] != view.rgb[mask])
        depth = np.ma.filled(np.ma.asarray(depth_ax.images[0].get_array(), dtype=float), np.nan)
        assert np.array_equal(depth, view.depth, equal_nan=True)
        v_line, omega_line, now_line = command_ax.get_lines()
        t, v, omega = view.commands.T
        assert np.array_equal(v_line.get_xdata(), t) and np.array_equal(v_line.get_ydata(), v)
        assert np.array_equal(omega_line.get_xdata(), t) and np.array_equal(omega_line.get_ydata(), omega)
        assert list(now_line.get_xdata()) == [view.frame_t] * 2
        path_line, here = path_ax.get_lines()
        assert np.array_equal(path_line.get_xdata(), view.path[:, 1])
        assert np.array_equal(path_line.get_ydata(), view.path[:, 2])
        nearest = view.path[np.argmin(np.abs(view.path[:, 0] - view.frame_t))]
        assert (here.get_xdata()[0], here.get_ydata()[0]) == (nearest[1], nearest[2])
        assert colour_ax.get_title() == f"{topics.COLOUR} at {view.frame_t:.2f} s + mask"
        assert figure._suptitle.get_text() == "a run"
    finally:
        close(figure)


def test_view_bag_writes_a_png_and_refuses_to_overwrite_it(recorded, tmp_path, capsys) -> None:
    bag, _ = recorded
    out = tmp_path / "view.png"
    assert main(["ros2", "view-bag", "--bag", str(bag), "--out", str(out), "--at", "1"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    before = out.read_bytes()
    assert main(["ros2", "view-bag", "--bag", str(bag), "--out", str(out)]) == 2
    assert "--out" in capsys.readouterr().err and out.read_bytes() == before


def test_a_missing_colour_topic_is_one_line_listing_the_bags_topics(recorded, tmp_path, capsys) -> None:
    bag, _ = recorded
    assert main(["ros2", "view-bag", "--bag", str(bag), "--out", str(tmp_path / "v.png"), "--colour-topic", "/x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no topic '/x'" in err[0] and "/odom" in err[0]
    assert not (tmp_path / "v.png").exists()
