"""SegCorridor's law against slip (controller centre_hold): it holds a steady sideways drift with
a smaller standing offset than pure pursuit, damps the heading, points the robot uphill on a cross
slope when told, and is off by default (the kinematic results are unchanged); the laws that lost
(the drift observer, the offset integral) are refused with one line that says so."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from segmin.common.config import ConfigError, from_dict
from segmin.nav_eval.demo.scenes import CLOSED_CANOPY_SCENE, DemoScene, render_scene
from segmin.nav_eval.runtime.corridor import CorridorConfig, CorridorNavigator
from segmin.nav_eval.sim.config import load_nav_config
from segmin.nav_eval.sim.factories import make_navigator
from tests.test_corridor import SIZE, scene_camera

DT = 0.2  # s between commands (5 Hz)
DRIFT = 0.03  # m/s to the right: a robot creeping downhill across a slope


def drive_with_drift(controller: str, seconds: float = 40.0, drift: float = DRIFT, **changes: float) -> np.ndarray:
    """A tiny closed loop: the navigator sees an analytic straight vine row from the robot's pose
    (lateral offset e, left of the centre; heading psi), and a unicycle that also slides `drift` m/s
    to the right follows its commands. Returns e after each command."""
    config = CorridorConfig(depth_threshold=5.0, controller=controller, **changes)
    nav = CorridorNavigator(config, scene_camera())
    e, psi, offsets = 0.0, 0.0, []
    for k in range(round(seconds / DT)):
        scene = DemoScene(
            "vines", 0.9, 0.4, 2.0, None, 20.0, lateral_offset=e, yaw=psi, hole_fraction=0.0, depth_threshold=5.0
        )
        mask, depth = render_scene(scene, size=SIZE)
        command = nav.step(mask, depth, stamp=k * DT)
        e += (command.v * math.sin(psi) - drift) * DT
        psi += command.omega * DT
        offsets.append(e)
    return np.asarray(offsets)


def test_centre_hold_leaves_a_smaller_standing_offset_than_pursuit():
    """The short lookahead and the heading damping balance the drift at about
    (L + k_h L² / 2 v) d / v = 0.1 m instead of pure pursuit's L d / v = 0.15 m."""
    pursuit, held = drive_with_drift("pursuit"), drive_with_drift("centre_hold")
    assert np.mean(pursuit[-25:]) == pytest.approx(-2.5 * DRIFT / 0.5, abs=0.03)
    assert np.mean(held[-25:]) == pytest.approx(-(1.0 + 0.6 / 1.0) * DRIFT / 0.5, abs=0.02)
    assert np.max(np.abs(held)) < 0.2  # on the way, no overshoot into a row


def centre_hold_command(
    offset: float,
    yaw: float,
    controller: str = "centre_hold",
    attitude: tuple[float, float] | None = None,
    **changes: float,
) -> float:
    """The first yaw rate (before the EMA: ema_lambda 1) from a straight vine row seen at `offset` m
    left of its centre with heading `yaw` (left > 0), the IMU reading `attitude` (roll, pitch)."""
    config = CorridorConfig(depth_threshold=5.0, controller=controller, ema_lambda=1.0, **changes)
    nav = CorridorNavigator(config, scene_camera())
    scene = DemoScene("vines", 0.9, 0.4, 2.0, None, 20.0, lateral_offset=offset, yaw=yaw, hole_fraction=0.0)
    mask, depth = render_scene(scene, size=SIZE)
    return nav.step(mask, depth, attitude=attitude).omega


def test_an_offset_turns_the_robot_towards_the_centre():
    assert centre_hold_command(0.2, 0.0) < -0.05  # left of the centre: turn right
    assert centre_hold_command(-0.2, 0.0) > 0.05


def test_the_heading_term_damps_a_heading_error():
    """Centred but turned left: the law turns right by pure pursuit's share on the same lookahead
    plus hold_heading_gain x the heading error."""
    pursuit = centre_hold_command(0.0, 0.1, controller="pursuit", lookahead=1.0)
    held = centre_hold_command(0.0, 0.1)
    assert pursuit < 0
    assert held - pursuit == pytest.approx(-0.6 * 0.1, abs=0.02)


@pytest.mark.parametrize("roll", [0.08, -0.05])
def test_the_slope_feedforward_points_the_robot_uphill_by_the_drift_angle(roll):
    """Across a slope (roll > 0: left side up) the robot creeps downhill (right) at the drift angle
    k_s tan(roll); hold_slope_drift k_s adds the yaw rate that holds that heading against the
    law's heading gain, (2 v / L_h + k_h) k_s tan(roll), and changes nothing else (same levelled
    points, same fit)."""
    attitude = (roll, 0.02)
    plain = centre_hold_command(0.1, 0.02, attitude=attitude)
    fed = centre_hold_command(0.1, 0.02, attitude=attitude, hold_slope_drift=0.5)
    assert fed - plain == pytest.approx((2.0 * 0.5 / 1.0 + 0.6) * 0.5 * math.tan(roll), rel=1e-6)
    assert math.copysign(1.0, fed - plain) == math.copysign(1.0, roll)  # uphill: left when the left is up


def test_without_an_imu_or_outside_centre_hold_the_slope_feedforward_does_nothing():
    assert centre_hold_command(0.1, 0.02, hold_slope_drift=0.5) == centre_hold_command(0.1, 0.02)
    plain = centre_hold_command(0.1, 0.02, controller="pursuit", attitude=(0.08, 0.0))
    fed = centre_hold_command(0.1, 0.02, controller="pursuit", attitude=(0.08, 0.0), hold_slope_drift=0.5)
    assert fed == plain


def test_in_trunk_mode_centre_hold_steers_as_pure_pursuit():
    """The trunks give no heading: without its damping the short lookahead weaved out of the high
    trees' rows, so there the law is pure pursuit on the usual lookahead."""
    mask, depth = render_scene(dataclasses.replace(CLOSED_CANOPY_SCENE, lateral_offset=0.3), size=SIZE)
    commands = []
    for controller in ("pursuit", "centre_hold"):
        nav = CorridorNavigator(CorridorConfig(10.0, controller=controller, trunk_min_points=4), scene_camera())
        commands.append([nav.step(mask, depth, stamp=0.2 * k) for k in range(3)])
    assert [c.mode for c in commands[1]] == ["trunks"] * 3
    assert [(c.v, c.omega) for c in commands[0]] == [(c.v, c.omega) for c in commands[1]]


@pytest.mark.parametrize(
    "changes,field",
    [
        ({"controller": "stanley"}, "corridor.controller"),
        ({"hold_lookahead": 0.0}, "corridor.hold_lookahead"),
        ({"hold_heading_gain": -0.6}, "corridor.hold_heading_gain"),
        ({"hold_slope_drift": -0.5}, "corridor.hold_slope_drift"),
        ({"hold_slope_drift": float("inf")}, "corridor.hold_slope_drift"),
    ],
)
def test_bad_controller_settings_name_the_field(changes, field):
    with pytest.raises(ValueError, match=field) as caught:
        CorridorConfig(depth_threshold=5.0, **changes)
    assert "\n" not in str(caught.value)


def test_a_bad_controller_in_the_nav_config_is_one_line_naming_it():
    with pytest.raises(ValueError, match=r"corridor\.controller must be one of pursuit, centre_hold, got 'lqr'$"):
        load_nav_config(overrides=["corridor.controller=lqr"])


@pytest.mark.parametrize(
    ("override", "message"),
    [
        (
            "corridor.controller=drift_observer",
            r"corridor\.controller drift_observer was removed: .*; use centre_hold$",
        ),
        (
            "corridor.drift_time=4.0",
            r"corridor\.drift_time was removed \(.*drift_observer.*\): delete it from the config$",
        ),
        ("corridor.drift_limit=0.05", r"corridor\.drift_limit was removed "),
        ("corridor.heading_gain=0.3", r"corridor\.heading_gain was removed "),
        ("corridor.hold_integral_time=30", r"corridor\.hold_integral_time was removed \(.*integral.*\)"),
        ("corridor.trunks=false", r"corridor\.trunks was removed \(the trunk mode is always on"),
    ],
)
def test_an_old_config_setting_a_removed_key_is_told_so_in_one_line(override, message):
    with pytest.raises(ValueError, match=message) as caught:
        load_nav_config(overrides=["robot.model=skid_steer", override])
    assert "\n" not in str(caught.value)


def test_a_removed_key_is_named_by_the_typed_loader_too():
    """Configs built with segmin.common.config.from_dict (a follower file's corridor section)."""
    with pytest.raises(ConfigError, match=r"^follower\.navigator\.drift_time was removed \("):
        from_dict(CorridorConfig, {"depth_threshold": 5.0, "drift_time": 4.0}, where="follower.navigator")


@pytest.mark.parametrize(
    "overrides,controller",
    [
        ([], "pursuit"),  # the kinematic robot: pure pursuit, today's trajectories
        (["robot.model=skid_steer"], "pursuit"),  # opt-in only: it measured worse than pure pursuit in bends
        (["robot.model=skid_steer", "corridor.controller=centre_hold"], "centre_hold"),
    ],
)
def test_the_evaluation_uses_a_slip_law_only_when_told(overrides, controller):
    nav = make_navigator("segcorridor", 5.0, load_nav_config(overrides=overrides))
    assert isinstance(nav, CorridorNavigator)
    assert nav.config.controller == controller


def test_pure_pursuit_ignores_the_stamps():
    """The default law's commands do not depend on time: kinematic results stay bit-identical."""
    scene = DemoScene("vines", 0.9, 0.4, 2.0, None, 20.0, lateral_offset=0.2, yaw=0.05, hole_fraction=0.25)
    mask, depth = render_scene(scene, size=SIZE)
    stamped, unstamped = (
        CorridorNavigator(CorridorConfig(5.0), scene_camera()),
        CorridorNavigator(CorridorConfig(5.0), scene_camera()),
    )
    for k in range(4):
        a, b = stamped.step(mask, depth, stamp=0.37 * k), unstamped.step(mask, depth)
        assert (a.v, a.omega, a.centre) == (b.v, b.omega, b.centre)
