"""The follower config (nav_eval.runtime.follower_config): one typed config that nav-eval, replay
and the ROS 2 node load into equal objects; bad input named by its key; old keys still read."""

from __future__ import annotations

import dataclasses
import logging

import pytest
import yaml

from segmin.common.config import ConfigError
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.corridor import CorridorConfig, CorridorNavigator
from segmin.nav_eval.runtime.follower_config import (
    CameraConfig,
    FollowerConfig,
    follower_from_dict,
    follower_to_dict,
    load_follower_config,
    make_navigator,
    navigator_fields,
)
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from segmin.nav_eval.sim.config import load_nav_config

CAMERA = CameraGeometry(
    width=224, height=224, fx=160.0, fy=160.0, cx=111.5, cy=111.5, mount_height=0.4, tilt_deg=15.0, mount_forward=0.2
)


def test_the_method_chooses_the_navigator_and_its_keys(tmp_path) -> None:
    path = tmp_path / "follower.yaml"
    path.write_text("method: segcorridor\nnavigator: {depth_threshold: 8.0, trim: 2.0}\nruntime: {command_hz: 10}\n")
    config = load_follower_config(path, ["camera.tilt_deg=12"])
    assert config.method == "segcorridor" and config.navigator == CorridorConfig(depth_threshold=8.0, trim=2.0)
    assert config.runtime.command_hz == 10 and config.camera.tilt_deg == 12.0
    paper = load_follower_config(None, ["method=segzeros", "navigator.depth_threshold=5"])
    assert paper.navigator == NavigatorConfig(method="segzeros", depth_threshold=5.0)
    # what it writes, it reads back
    assert follower_from_dict(follower_to_dict(config)) == config
    assert follower_from_dict(yaml.safe_load(yaml.safe_dump(follower_to_dict(config)))) == config
    assert set(navigator_fields("segcorridor")) == {f.name for f in dataclasses.fields(CorridorConfig) if f.init} - {
        "method"
    }


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["method=segmax", "navigator.depth_threshold=5"], "follower.method: 'segmax' is not one of"),
        ([], "follower.navigator: missing"),
        (["navigator.depth_threshold=5", "navigator.trim=2"], "follower.navigator: unknown key(s) ['trim']"),
        (
            ["method=segcorridor", "navigator.depth_threshold=5", "navigator.smooth_window=3"],
            "unknown key(s) ['smooth_",
        ),
        (["navigator.depth_threshold=5", "navigator.method=segmin"], "follower.navigator.method: the method is chosen"),
        (["navigator.depth_threshold=25"], "follower.navigator.depth_threshold: depth_threshold (25 m) is beyond"),
        (
            ["navigator.depth_threshold=5", "runtime.segment_hz=7"],
            "follower.runtime: segment_hz (7) must be a multiple",
        ),
        (["navigator.depth_threshold=5", "camera.fx=300"], "follower.camera: width: unset beside the other"),
        (["navigator.depth_threshold=5", "camera.tilt_deg=95"], "follower.camera: camera tilt_deg must be"),
        (["navigator.depth_threshold=five"], "follower.navigator.depth_threshold: expected a number"),
    ],
)
def test_bad_input_is_one_line_naming_the_key(overrides, message) -> None:
    with pytest.raises(ConfigError) as caught:
        load_follower_config(None, overrides)
    assert message in str(caught.value) and "\n" not in str(caught.value)


def test_make_navigator_builds_the_methods_navigator_on_the_frames_camera() -> None:
    segmind = load_follower_config(None, ["navigator.depth_threshold=5"])
    assert isinstance(make_navigator(segmind), Navigator)
    corridor = load_follower_config(None, ["method=segcorridor", "navigator.depth_threshold=5"])
    with pytest.raises(ValueError, match="segcorridor needs the camera intrinsics"):
        make_navigator(corridor)
    navigator = make_navigator(corridor, CAMERA)
    assert isinstance(navigator, CorridorNavigator) and navigator.camera == CAMERA
    intrinsics = {k: getattr(CAMERA, k) for k in ("width", "height", "fx", "fy", "cx", "cy")}
    fixed = dataclasses.replace(corridor, camera=CameraConfig(**intrinsics))
    assert make_navigator(fixed).camera == CAMERA  # the config's own intrinsics on its mount


def test_nav_eval_builds_each_runs_follower_from_its_section() -> None:
    config = load_nav_config(None, ["follower.corridor.trim=2.0", "follower.runtime.segment_hz=10"])
    corridor = config.follower.config("segcorridor", 8.0)
    assert corridor == FollowerConfig(
        CorridorConfig(depth_threshold=8.0, trim=2.0), dataclasses.replace(corridor.runtime, segment_hz=10)
    )
    assert config.follower.config("segmin", 5.0).navigator == NavigatorConfig(method="segmin", depth_threshold=5.0)
    with pytest.raises(ConfigError, match=r"navigator: \['depth_threshold'\] are set by each run"):
        load_nav_config(None, ["follower.navigator.depth_threshold=3"])
    with pytest.raises(ConfigError, match=r"camera.width: the simulator's camera gives the intrinsics"):
        load_nav_config(
            None,
            [f"follower.camera.{k}={v}" for k, v in (("width", 8), ("height", 8), ("fx", 9))]
            + ["follower.camera.fy=9", "follower.camera.cx=4", "follower.camera.cy=4"],
        )
    with pytest.raises(ConfigError, match=r"rates.physics_hz \(60\) must be a multiple of follower.runtime.segment_hz"):
        load_nav_config(None, ["follower.runtime.segment_hz=25", "follower.runtime.command_hz=5"])


OLD_FILE = """\
rates: {physics_hz: 60, camera_hz: 30, segment_hz: 10, command_hz: 5}
perception: {fuse_frames: 2, width: 112, height: 112}
navigator: {mask_closing: 8}
corridor: {trim: 2.0}
sensor_checks: {frozen_s: 0.5}
"""
NEW_FILE = """\
rates: {physics_hz: 60, camera_hz: 30}
perception: {width: 112, height: 112}
follower:
  runtime: {segment_hz: 10, command_hz: 5, checks: {frozen_s: 0.5}}
  navigator: {mask_closing: 8, fuse_frames: 2}
  corridor: {trim: 2.0, fuse_frames: 2}
"""


def test_old_nav_config_keys_read_as_the_new_with_one_warning_line(tmp_path, caplog) -> None:
    old, new = tmp_path / "old.yaml", tmp_path / "new.yaml"
    old.write_text(OLD_FILE)
    new.write_text(NEW_FILE)
    with caplog.at_level(logging.WARNING):
        expected = load_nav_config(new)
        assert not caplog.records  # the new keys: no note
        assert load_nav_config(old) == expected
    (record,) = caplog.records
    assert "old nav config keys rates.segment_hz" in record.getMessage() and "follower.runtime.checks" in (
        record.getMessage()
    )
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # old override keys win over the file's new ones, as they did
        overridden = load_nav_config(new, ["navigator.mask_closing=4", "perception.fuse_frames=3"])
    assert overridden.follower.navigator == {"mask_closing": 4, "fuse_frames": 3}
    assert overridden.follower.corridor == {"trim": 2.0, "fuse_frames": 3}
    assert len(caplog.records) == 1 and "perception.fuse_frames" in caplog.records[0].getMessage()
    both = tmp_path / "both.yaml"
    both.write_text(NEW_FILE + "navigator: {mask_closing: 4}\n")
    with pytest.raises(ConfigError, match=r"navigator \(old\) and follower.navigator both set \['mask_closing'\]"):
        load_nav_config(both)


def _replay_follower(*argv: str) -> FollowerConfig:
    """The follower config of a `segmin replay` command line."""
    from segmin.app.cli import build_parser
    from segmin.nav_eval.replay.cli import follower_of

    return follower_of(build_parser().parse_args(["replay", "--model", "m.onnx", "--rgb", "f", "--out", "o", *argv]))


def test_the_jackal_file_a_nav_eval_config_and_a_replay_command_line_load_equal_followers() -> None:
    from segmin.common.shipped import resolve_config
    from segmin.nav_eval.ros2.params import load_params_file, node_params

    jackal = resolve_config("ros2", "jackal_d435")
    node = node_params(load_params_file(jackal)[1], jackal.parent).follower
    nav_eval = load_nav_config(None).follower.config("segmind", 5.0)
    replay = _replay_follower("--method", "segmind", "navigator.depth_threshold=5")
    assert node == nav_eval == replay == _replay_follower("--follower", str(jackal))
    # and they stay equal when the same key changes in each
    changed = _replay_follower("--depth-threshold", "8", "--command-hz", "10", "method=segcorridor", "navigator.trim=2")
    assert changed == load_nav_config(
        None, ["follower.corridor.trim=2", "follower.runtime.command_hz=10"]
    ).follower.config("segcorridor", 8.0)


def test_replay_without_a_depth_cut_or_a_camera_for_segcorridor_is_one_line(tmp_path, capsys) -> None:
    from segmin.app.cli import main

    frames = tmp_path / "frames"
    frames.mkdir()
    base = ["replay", "--model", "m.onnx", "--rgb", str(frames), "--fps", "30", "--out", str(tmp_path / "o")]
    assert main(base) == 2
    assert capsys.readouterr().err.strip() == (
        "segmin: error: --depth-threshold: the depth cut in metres is needed (paper: 5, 8, 10), or "
        "navigator.depth_threshold=... or a --follower file"
    )
    assert main([*base, "--depth", str(frames), "--method", "segcorridor", "navigator.depth_threshold=5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "camera: segcorridor needs the camera intrinsics" in err[0]
    assert not (tmp_path / "o").exists()


def test_the_nodes_old_flat_parameter_names_read_as_the_new_with_one_warning_line(caplog) -> None:
    from segmin.nav_eval.ros2 import topics
    from segmin.nav_eval.ros2.params import node_params

    old = {"method": "segmind", "v_max": 0.8, "segment_hz": 10, "frozen_s": 0.5, "camera_tilt_deg": 12.0}
    new = {
        "follower.method": "segmind",
        "follower.navigator.v_max": 0.8,
        "follower.runtime.segment_hz": 10,
        "follower.runtime.checks.frozen_s": 0.5,
        "follower.camera.tilt_deg": 12.0,
    }
    with caplog.at_level(logging.WARNING):
        expected = node_params(new)
        assert not caplog.records
        assert node_params({**old, "controller": "centre_hold"}) == expected  # SegCorridor's, beside SegMinD: dropped
    (record,) = caplog.records
    assert "old flat parameter names method, v_max, segment_hz, frozen_s, camera_tilt_deg" in record.getMessage()
    assert "controller: not segmind's, ignored" in record.getMessage()
    corridor = node_params({"method": "segcorridor", "camera_info_topic": topics.COLOUR_INFO, "trim": 2.0})
    assert corridor.navigator == CorridorConfig(depth_threshold=5.0, trim=2.0)
    with pytest.raises(ValueError, match=r"^parameter follower.navigator.trunks was removed \(the trunk mode"):
        node_params({"method": "segcorridor", "camera_info_topic": topics.COLOUR_INFO, "trunks": True})
