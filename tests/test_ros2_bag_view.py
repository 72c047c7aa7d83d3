"""`segmin ros2 view-bag`: the picture of a simulated bag's topics (no ROS, no viewer)."""

from __future__ import annotations

import numpy as np
import pytest
from test_replay_bags import GreenSegmenter
from test_sim_bags import _episode

from segmin.app.cli import main
from segmin.nav_eval.ros2.bag_view import read_bag_view


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
