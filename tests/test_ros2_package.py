"""The ROS 2 package ros/segmin_ros, built as a robot team builds it (marker `ros2`: `make test-ros2`).

colcon, from the ROS environment of `.ci/ros_env.sh`, builds the package into a temporary
workspace. Its launch file is read from the install space with stand-ins for the launch system,
which has no wheel in the package registry (`tests/ros2_launch_reader.py` says what they do), and
ament_index_python, which has. The node is then started by the command the launch file describes
(the installed `follow` executable, the install space sourced) inside the loopback-only
namespace and fed a simulated bag frame by frame (`tests/ros2_driver.py`): its commands equal
`segmin replay --bag` on the same bag.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest
from test_ros2_node import ROOT, confined, episode_bag, frame_by_frame_params, moving_commands, ros_env

from segmin.app.cli import build_parser, main
from segmin.common.shipped import resolve_config
from segmin.nav_eval.replay.run import read_commands_csv
from segmin.nav_eval.ros2 import topics
from segmin.nav_eval.ros2.params import load_params_file

pytestmark = pytest.mark.ros2
__all__ = ["episode_bag"]  # the simulated run's bag, a fixture shared with the node's tests
PACKAGE = "segmin_ros"
SOURCE = ROOT / "ros" / PACKAGE
# launch argument -> the node's parameter naming the topic it remaps
REMAP_ARGUMENTS = {
    "rgb_topic": "colour_topic",
    "depth_topic": "depth_topic",
    "camera_info_topic": "camera_info_topic",
    "cmd_vel_topic": "cmd_vel_topic",
}


def clean_env() -> dict[str, str]:
    """This environment without ROS's variables, as a shell that sourced no ROS 2 has it."""
    prefixes = ("ROS_", "RMW_", "FASTRTPS", "FASTDDS", "AMENT_", "COLCON_")
    return {k: v for k, v in os.environ.items() if not k.startswith(prefixes)}


@pytest.fixture(scope="module")
def install(tmp_path_factory) -> Path:
    """The install space of `colcon build --base-paths ros` in a temporary workspace."""
    workspace = tmp_path_factory.mktemp("colcon")
    colcon = ros_env() / "bin" / "colcon"
    argv = [str(colcon), "--log-base", str(workspace / "log"), "build", "--base-paths", "ros"]
    argv += ["--build-base", str(workspace / "build"), "--install-base", str(workspace / "install")]
    result = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=300, env=clean_env(), check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"Finished <<< {PACKAGE}" in result.stdout, result.stdout
    return workspace / "install"


def sourced(install: Path, argv: list[str]) -> list[str]:
    """argv run after sourcing the install space's setup.bash, as a user's shell does before `ros2 launch`."""
    return ["bash", "-c", 'source "$0" && exec "$@"', str(install / "setup.bash"), *argv]


def read_launch(install: Path, out: Path, *given: str) -> dict:
    """The installed launch file's arguments and node, with the launch arguments `given` (NAME:=VALUE)."""
    launch_file = install / PACKAGE / "share" / PACKAGE / "launch" / "follow.launch.py"
    reader = [str(ros_env() / "bin" / "python"), str(ROOT / "tests" / "ros2_launch_reader.py")]
    argv = sourced(install, [*reader, str(launch_file), str(out), *given])
    result = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=clean_env(), check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    return json.loads(out.read_text())


def test_colcon_installs_the_executable_the_launch_file_and_the_one_parameter_file(install) -> None:
    share = install / PACKAGE / "share"
    assert os.access(install / PACKAGE / "lib" / PACKAGE / "follow", os.X_OK)
    assert (share / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    assert (share / PACKAGE / "package.xml").read_bytes() == (SOURCE / "package.xml").read_bytes()
    installed = (share / PACKAGE / "config" / "jackal_d435.yaml").read_bytes()
    assert installed == (SOURCE / "config" / "jackal_d435.yaml").read_bytes()
    assert resolve_config("ros2", "jackal_d435").read_bytes() == installed  # segmin's shipped name: the same file
    assert not list(SOURCE.glob("*.egg-info")) and not (SOURCE / "build").exists()  # the checkout stays clean


def test_the_launch_file_takes_the_parameter_file_and_remaps_the_camera_topics(install, tmp_path) -> None:
    described = read_launch(install, tmp_path / "defaults.json")
    jackal = install / PACKAGE / "share" / PACKAGE / "config" / "jackal_d435.yaml"
    defaults = {a["name"]: a["default"] for a in described["arguments"]}
    assert defaults["params_file"] == str(jackal)
    (node,) = described["nodes"]
    assert (node["package"], node["executable"]) == (PACKAGE, "follow")
    assert node["command"][0] == str(install / PACKAGE / "lib" / PACKAGE / "follow")
    assert node["arguments"] == ["--params", str(jackal)]
    # Each remapping starts from the topic the node subscribes to with the shipped file, and by
    # default leads to it: the defaults change nothing.
    _, shipped = load_params_file(jackal)
    named = {argument: shipped[parameter] for argument, parameter in REMAP_ARGUMENTS.items()}
    assert set(defaults) == {"params_file", *REMAP_ARGUMENTS}
    assert node["remappings"] == [[named[a], named[a]] for a in REMAP_ARGUMENTS]
    assert [defaults[a] for a in REMAP_ARGUMENTS] == list(named.values())

    mine = tmp_path / "robot.yaml"
    given = [f"params_file:={mine}", "rgb_topic:=/front/color/image_raw", "cmd_vel_topic:=/cmd_vel_nav"]
    node = read_launch(install, tmp_path / "given.json", *given)["nodes"][0]
    assert node["arguments"] == ["--params", str(mine)]
    assert [topics.COLOUR, "/front/color/image_raw"] in node["remappings"]
    assert [topics.CMD_VEL, "/cmd_vel_nav"] in node["remappings"]
    assert [topics.DEPTH, topics.DEPTH] in node["remappings"]
    # segmin's command line reads the command as laid out: the file, then ROS's remappings.
    args = build_parser().parse_args(["ros2", "follow", *node["command"][1:]])
    assert args.params == mine
    assert args.ros_args[:2] == ["-r", f"{topics.COLOUR}:=/front/color/image_raw"]


def test_the_installed_node_started_as_launched_gives_the_commands_of_segmin_replay(
    install, exported, episode_bag, tmp_path
) -> None:
    """The bag fed frame by frame to the node started by the launch file's command (the node's
    tests check the same against the simulator's own commands)."""
    model = exported[0]
    params = frame_by_frame_params(tmp_path, model)
    command = read_launch(install, tmp_path / "launch.json", f"params_file:={params}")["nodes"][0]["command"]
    (tmp_path / "command.json").write_text(json.dumps(command))
    driver = [str(ros_env() / "bin" / "python"), str(ROOT / "tests" / "ros2_driver.py")]
    argv = [*driver, str(episode_bag), str(params), str(tmp_path / "out.json"), str(tmp_path / "command.json")]
    result = confined(sourced(install, argv), timeout=240)
    assert result.returncode == 0, result.stdout + result.stderr
    drive = json.loads((tmp_path / "out.json").read_text())
    assert drive["phases"]["enable_response"] == [True, "driving enabled"], drive["node_log"]
    assert drive["alive"] and drive["node_exit"] == 0, drive["node_log"]

    replayed = tmp_path / "replay"
    argv = ["replay", "--model", str(model), "--bag", str(episode_bag), "--rgb-topic", topics.COLOUR]
    argv += ["--depth-topic", topics.DEPTH, "--depth-threshold", "5", "--threads", "1", "--out", str(replayed)]
    assert main(argv) == 0
    rows = read_commands_csv(replayed / "commands.csv")
    expected = [(t, (v, omega)) for t, v, omega, _, _ in rows if (v, omega) != (0.0, 0.0)]
    received = moving_commands(drive)
    assert len(expected) > 10
    assert [command for _, command in received] == [command for _, command in expected]
    assert [stamp / 1e9 for stamp, _ in received] == pytest.approx([t for t, _ in expected], abs=1e-6)
