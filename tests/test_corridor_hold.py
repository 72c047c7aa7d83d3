"""SegCorridor's offset integral (controller pursuit_integral): it cancels a steady sideways drift
that pure pursuit can only balance with a standing offset, stays bounded, restarts with the run,
and is off by default (the kinematic results are unchanged)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from segmin.nav_eval.demo.scenes import DemoScene, render_scene
from segmin.nav_eval.runtime.control import OffsetIntegrator
from segmin.nav_eval.runtime.corridor import CorridorConfig, CorridorNavigator
from segmin.nav_eval.sim.config import load_nav_config
from segmin.nav_eval.sim.factories import make_navigator
from tests.test_corridor import SIZE, scene_camera

DT = 0.2  # s between commands (5 Hz)
DRIFT = 0.03  # m/s to the right: a robot creeping downhill across a slope


def drive_with_drift(controller: str, seconds: float = 40.0) -> np.ndarray:
    """A tiny closed loop: the navigator sees an analytic straight vine row from the robot's pose
    (lateral offset e, left of the centre; heading psi), and a unicycle that also slides DRIFT m/s
    to the right follows its commands. Returns e after each command."""
    nav = CorridorNavigator(CorridorConfig(depth_threshold=5.0, controller=controller), scene_camera())
    e, psi, offsets = 0.0, 0.0, []
    for k in range(round(seconds / DT)):
        scene = DemoScene(
            "vines", 0.9, 0.4, 2.0, None, 20.0, lateral_offset=e, yaw=psi, hole_fraction=0.0, depth_threshold=5.0
        )
        mask, depth = render_scene(scene, size=SIZE)
        command = nav.step(mask, depth, stamp=k * DT)
        e += (command.v * math.sin(psi) - DRIFT) * DT
        psi += command.omega * DT
        offsets.append(e)
    return np.asarray(offsets)


def test_the_integral_cancels_a_constant_drift_that_pursuit_leaves_standing():
    pursuit = drive_with_drift("pursuit")
    held = drive_with_drift("pursuit_integral")
    last = slice(-25, None)  # the last 5 s
    # Pure pursuit turns against the drift only as far as a standing offset makes it (about
    # lookahead x drift / v = 0.15 m), the integral removes it.
    assert np.mean(pursuit[last]) < -0.08
    assert abs(np.mean(held[last])) < 0.02
    assert np.max(np.abs(held)) < 0.2  # on the way, no overshoot into a row


def test_the_term_is_clamped_and_large_offsets_are_not_integrated():
    integrator = OffsetIntegrator(gain=0.1, limit=0.15, band=0.3)
    for k in range(200):
        term = integrator.update(0.25, stamp=k * DT)
    assert term == pytest.approx(0.15)  # clamped, however long the offset stands
    # Wound up to the clamp only: a change of side unwinds it in the time it took to reach it.
    for k in range(200, 200 + 31):
        term = integrator.update(-0.25, stamp=k * DT)
    assert term < 0
    before = integrator.integral
    integrator.update(0.31, stamp=300 * DT)  # beyond the band: a transient
    integrator.update(0.1, stamp=301 * DT, saturated=True)  # the command is at its limit
    assert integrator.integral == before


def test_the_time_step_is_the_stamps_difference():
    integrator = OffsetIntegrator(gain=1.0, limit=10.0, band=1.0)
    assert integrator.update(0.1, stamp=5.0) == 0.0  # the first update has no time step
    assert integrator.update(0.1, stamp=5.0) == 0.0  # nor one at the same stamp
    assert integrator.update(0.1, stamp=5.5) == pytest.approx(0.05)
    assert integrator.update(None, stamp=9.5) == pytest.approx(0.05)  # no path seen: nothing integrated
    assert integrator.update(0.1, stamp=9.7) == pytest.approx(0.07)  # and the 4 s without one are not either


def test_stop_and_reset_forget_the_integral():
    nav = CorridorNavigator(CorridorConfig(depth_threshold=5.0, controller="pursuit_integral"), scene_camera())
    scene = DemoScene("vines", 0.9, 0.4, 2.0, None, 20.0, lateral_offset=-0.2, hole_fraction=0.0)
    mask, depth = render_scene(scene, size=SIZE)
    for k in range(5):
        nav.step(mask, depth, stamp=k * DT)
    assert nav._integrator.integral > 0  # the centre is to the left
    nav.stop()
    assert nav._integrator.integral == 0.0
    for k in range(5):
        nav.step(mask, depth, stamp=k * DT)
    nav.reset()
    assert nav._integrator.integral == 0.0


@pytest.mark.parametrize(
    "changes,field",
    [
        ({"controller": "stanley"}, "corridor.controller"),
        ({"integral_gain": -0.1}, "corridor.integral_gain"),
        ({"integral_gain": float("nan")}, "corridor.integral_gain"),
        ({"integral_limit": 0.0}, "corridor.integral_limit"),
        ({"integral_band": float("inf")}, "corridor.integral_band"),
    ],
)
def test_bad_controller_settings_name_the_field(changes, field):
    with pytest.raises(ValueError, match=field) as caught:
        CorridorConfig(depth_threshold=5.0, **changes)
    assert "\n" not in str(caught.value)


def test_a_bad_controller_in_the_nav_config_is_one_line_naming_it():
    with pytest.raises(ValueError, match=r"corridor\.controller must be one of pursuit, pursuit_integral"):
        load_nav_config(overrides=["corridor.controller=lqr"])


@pytest.mark.parametrize(
    "overrides,controller",
    [
        ([], "pursuit"),  # the kinematic robot: pure pursuit, today's trajectories
        (["robot.model=skid_steer"], "pursuit_integral"),
        (["robot.model=skid_steer", "corridor.controller=pursuit"], "pursuit"),  # named: kept
        (["corridor.controller=pursuit_integral"], "pursuit_integral"),
    ],
)
def test_the_evaluation_holds_the_centre_on_the_skid_steer_robot_unless_told(overrides, controller):
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
