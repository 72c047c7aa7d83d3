"""SegCorridor's laws against slip (controllers drift_observer and centre_hold): they cancel a
steady sideways drift that pure pursuit can only balance with a standing offset, stay bounded,
restart with the run, and are off by default (the kinematic results are unchanged)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from segmin.nav_eval.demo.scenes import CLOSED_CANOPY_SCENE, DemoScene, render_scene
from segmin.nav_eval.runtime.control import ClampedIntegral, DriftObserver
from segmin.nav_eval.runtime.corridor import CorridorConfig, CorridorNavigator
from segmin.nav_eval.sim.config import load_nav_config
from segmin.nav_eval.sim.factories import make_navigator
from tests.test_corridor import SIZE, scene_camera

DT = 0.2  # s between commands (5 Hz)
DRIFT = 0.03  # m/s to the right: a robot creeping downhill across a slope


# centre_hold with its (opt-in) integral: 10 s
LAWS = {"pursuit": {}, "drift_observer": {}, "centre_hold": {"hold_integral_time": 10.0}}


def drive_with_drift(controller: str, seconds: float = 40.0, drift: float = DRIFT, **changes: float) -> np.ndarray:
    """A tiny closed loop: the navigator sees an analytic straight vine row from the robot's pose
    (lateral offset e, left of the centre; heading psi), and a unicycle that also slides `drift` m/s
    to the right follows its commands. Returns e after each command."""
    config = CorridorConfig(depth_threshold=5.0, controller=controller, **{**LAWS[controller], **changes})
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


@pytest.mark.parametrize("controller", ["drift_observer", "centre_hold"])
def test_both_laws_cancel_a_constant_drift_that_pursuit_leaves_standing(controller):
    pursuit = drive_with_drift("pursuit")
    held = drive_with_drift(controller)
    last = slice(-25, None)  # the last 5 s
    # Pure pursuit turns against the drift only as far as a standing offset makes it (about
    # lookahead x drift / v = 0.15 m); the observer points it against the drift, the integral
    # of the robot's offset turns it further until the offset is gone.
    assert np.mean(pursuit[last]) < -0.08
    assert abs(np.mean(held[last])) < 0.02
    assert np.max(np.abs(held)) < 0.2  # on the way, no overshoot into a row


def test_without_its_integral_centre_hold_leaves_a_smaller_standing_offset():
    """By default (no integral) the short lookahead and the heading damping balance the drift at
    about (L + k_h L² / 2 v) d / v = 0.1 m instead of pure pursuit's L d / v = 0.15 m."""
    held = drive_with_drift("centre_hold", hold_integral_time=0.0)
    assert np.mean(held[-25:]) == pytest.approx(-(1.0 + 0.6 / 1.0) * DRIFT / 0.5, abs=0.02)


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
    for controller in ("pursuit", "drift_observer"):
        plain = centre_hold_command(0.1, 0.02, controller=controller, attitude=(0.08, 0.0))
        fed = centre_hold_command(0.1, 0.02, controller=controller, attitude=(0.08, 0.0), hold_slope_drift=0.5)
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


def test_the_integral_turns_by_2v_over_the_lookahead_squared():
    """centre_hold's integral term is (2 v / L_h²) S / T_i with S = ∫c_0 dt (L_h = 1.5 m here: at
    the default 1 m, 2 v / L_h and 2 v / L_h² are the same number)."""
    scene = DemoScene("vines", 0.9, 0.4, 2.0, None, 20.0, lateral_offset=0.15, yaw=0.0, hole_fraction=0.0)
    mask, depth = render_scene(scene, size=SIZE)
    commands = {}
    for integral_time in (0.0, 2.0):
        config = CorridorConfig(
            depth_threshold=5.0,
            controller="centre_hold",
            ema_lambda=1.0,
            hold_lookahead=1.5,
            hold_integral_time=integral_time,
        )
        nav = CorridorNavigator(config, scene_camera())
        commands[integral_time] = [nav.step(mask, depth, stamp=stamp) for stamp in (0.0, 0.2)]
    plain, held = commands[0.0][-1], commands[2.0][-1]
    offset = held.centre[0]  # c_0, integrated over the 0.2 s between the two frames
    assert offset == pytest.approx(-0.15, abs=0.02) and abs(held.omega) < 0.9  # not clipped
    assert held.omega - plain.omega == pytest.approx(2.0 * 0.5 / 1.5**2 * (offset * 0.2) / 2.0, rel=1e-6)


def test_the_integral_is_clamped_and_restarts_with_the_run():
    integral = ClampedIntegral(limit=0.5)
    assert integral.update(1.0, stamp=0.0) == 0.0  # the first measurement has no time step
    assert integral.update(1.0, stamp=0.2) == pytest.approx(0.2)  # dt from the stamps
    assert integral.update(1.0, stamp=0.2) == pytest.approx(0.2)  # no time passed: nothing added
    for k in range(2, 40):  # a long start transient or bend: wound up only to the clamp
        value = integral.update(1.0, stamp=0.2 * k)
    assert value == 0.5
    assert integral.update(-1.0, stamp=0.2 * 40) == pytest.approx(0.3)  # and unwinds from there at once
    integral.forget_track()  # a frame without a path: the sum stays, the next starts afresh
    assert integral.update(-1.0, stamp=20.0) == pytest.approx(0.3)
    assert integral.update(-1.0, stamp=22.0) == pytest.approx(0.3)  # 2 s later: not integrated
    integral.reset()
    assert integral.value == 0.0


def test_the_clamp_cancels_a_drift_up_to_drift_limit_and_no_more():
    """The clamped integral removes the offset of a drift below `drift_limit`; of a larger one it
    removes only `drift_limit`'s share, and the rest stands as without the integral."""
    limit = CorridorConfig(depth_threshold=5.0).drift_limit
    within = drive_with_drift("centre_hold", seconds=60.0, drift=0.8 * limit)
    beyond = drive_with_drift("centre_hold", seconds=60.0, drift=2.0 * limit)
    excess_only = drive_with_drift("centre_hold", seconds=60.0, drift=limit, hold_integral_time=0.0)
    last = slice(-25, None)
    assert abs(np.mean(within[last])) < 0.02
    assert np.mean(beyond[last]) < -0.05  # a standing offset: the clamp held
    assert np.mean(beyond[last]) == pytest.approx(np.mean(excess_only[last]), abs=0.03)


@pytest.mark.parametrize("controller", ["drift_observer", "centre_hold"])
def test_stop_and_reset_forget_the_drift(controller):
    nav = CorridorNavigator(
        CorridorConfig(depth_threshold=5.0, controller=controller, **LAWS[controller]), scene_camera()
    )
    scenes = [
        DemoScene("vines", 0.9, 0.4, 2.0, None, 20.0, lateral_offset=0.03 * k, hole_fraction=0.0) for k in range(6)
    ]
    frames = [render_scene(scene, size=SIZE) for scene in scenes]

    def slide() -> None:  # sliding left along the row, heading straight: a drift to the left
        for k, (mask, depth) in enumerate(frames):
            nav.step(mask, depth, stamp=k * DT)

    def estimate() -> float:  # the observer's drift (> 0: left), or the integral of the offset
        return nav._observer.drift if controller == "drift_observer" else -nav._offset_integral.value

    slide()
    assert estimate() > 0
    nav.stop()
    assert estimate() == 0.0
    slide()
    nav.reset()
    assert estimate() == 0.0


def test_the_estimate_is_clamped_and_fit_jumps_are_not_used():
    observer = DriftObserver(time_constant=1.0, limit=0.05, max_lateral_speed=0.25)
    for k in range(50):  # the robot slides left at 0.2 m/s with its heading along the path
        drift = observer.update(0.2 * k * DT, 0.0, 0.5, stamp=k * DT)
    assert drift == pytest.approx(0.05)  # clamped, however fast it slides
    before = observer.drift
    observer.update(0.2 * 49 * DT + 0.3, 0.0, 0.5, stamp=50 * DT)  # 0.3 m in 0.2 s: the fit jumped
    assert observer.drift == before


def test_motion_the_heading_explains_is_no_drift():
    """A start or a bend taken late: the offset changes exactly as the heading says, so (unlike an
    integral of the offset) nothing winds up."""
    observer = DriftObserver(time_constant=1.0, limit=0.05, max_lateral_speed=0.25)
    offset, heading = 0.15, -0.1
    for k in range(30):
        observer.update(offset, heading, 0.5, stamp=k * DT)
        offset += 0.5 * math.sin(heading) * DT
        heading *= 0.9
    assert abs(observer.drift) < 1e-3  # the heading is sampled at the step's end: a discretisation error only


def test_the_time_step_is_the_stamps_difference():
    observer = DriftObserver(time_constant=0.5, limit=1.0, max_lateral_speed=1.0)
    assert observer.update(0.0, 0.0, 0.0, stamp=5.0) == 0.0  # the first measurement has no difference
    assert observer.update(0.1, 0.0, 0.0, stamp=5.0) == 0.0  # nor one at the same stamp
    # 0.02 m in 0.1 s is 0.2 m/s; a step of 0.1 s moves the estimate 0.1 / 0.5 of the way.
    assert observer.update(0.02, 0.0, 0.0, stamp=5.1) == pytest.approx(0.2 * 0.1 / 0.5)
    observer.forget_track()  # a frame without a path: the estimate stays, the next starts a track
    assert observer.update(5.0, 0.0, 0.0, stamp=7.0) == pytest.approx(0.04)
    assert observer.update(5.0, 0.0, 0.0, stamp=8.5) == pytest.approx(0.04)  # 1.5 s later: not used


@pytest.mark.parametrize(
    "changes,field",
    [
        ({"controller": "stanley"}, "corridor.controller"),
        ({"hold_lookahead": 0.0}, "corridor.hold_lookahead"),
        ({"hold_heading_gain": -0.6}, "corridor.hold_heading_gain"),
        ({"hold_integral_time": float("nan")}, "corridor.hold_integral_time"),
        ({"hold_integral_time": -1.0}, "corridor.hold_integral_time"),
        ({"hold_slope_drift": -0.5}, "corridor.hold_slope_drift"),
        ({"hold_slope_drift": float("inf")}, "corridor.hold_slope_drift"),
        ({"heading_gain": -0.1}, "corridor.heading_gain"),
        ({"heading_gain": float("nan")}, "corridor.heading_gain"),
        ({"drift_limit": 0.0}, "corridor.drift_limit"),
        ({"drift_time": float("inf")}, "corridor.drift_time"),
    ],
)
def test_bad_controller_settings_name_the_field(changes, field):
    with pytest.raises(ValueError, match=field) as caught:
        CorridorConfig(depth_threshold=5.0, **changes)
    assert "\n" not in str(caught.value)


def test_a_bad_controller_in_the_nav_config_is_one_line_naming_it():
    with pytest.raises(ValueError, match=r"corridor\.controller must be one of pursuit, drift_observer, centre_hold"):
        load_nav_config(overrides=["corridor.controller=lqr"])


@pytest.mark.parametrize(
    "overrides,controller",
    [
        ([], "pursuit"),  # the kinematic robot: pure pursuit, today's trajectories
        (["robot.model=skid_steer"], "pursuit"),  # opt-in only: it measured worse than pure pursuit in bends
        (["robot.model=skid_steer", "corridor.controller=drift_observer"], "drift_observer"),
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
