"""SegCorridor's drift observer (controller drift_observer): it cancels a steady sideways drift
that pure pursuit can only balance with a standing offset, stays bounded, restarts with the run,
and is off by default (the kinematic results are unchanged)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from segmin.nav_eval.demo.scenes import DemoScene, render_scene
from segmin.nav_eval.runtime.control import DriftObserver
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


def test_the_observer_cancels_a_constant_drift_that_pursuit_leaves_standing():
    pursuit = drive_with_drift("pursuit")
    held = drive_with_drift("drift_observer")
    last = slice(-25, None)  # the last 5 s
    # Pure pursuit turns against the drift only as far as a standing offset makes it (about
    # lookahead x drift / v = 0.15 m), the observer points it against the drift.
    assert np.mean(pursuit[last]) < -0.08
    assert abs(np.mean(held[last])) < 0.02
    assert np.max(np.abs(held)) < 0.2  # on the way, no overshoot into a row


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


def test_stop_and_reset_forget_the_drift():
    nav = CorridorNavigator(CorridorConfig(depth_threshold=5.0, controller="drift_observer"), scene_camera())
    scenes = [
        DemoScene("vines", 0.9, 0.4, 2.0, None, 20.0, lateral_offset=0.03 * k, hole_fraction=0.0) for k in range(6)
    ]
    frames = [render_scene(scene, size=SIZE) for scene in scenes]

    def slide() -> None:  # sliding left along the row, heading straight: a drift to the left
        for k, (mask, depth) in enumerate(frames):
            nav.step(mask, depth, stamp=k * DT)

    slide()
    assert nav._observer.drift > 0
    nav.stop()
    assert nav._observer.drift == 0.0
    slide()
    nav.reset()
    assert nav._observer.drift == 0.0


@pytest.mark.parametrize(
    "changes,field",
    [
        ({"controller": "stanley"}, "corridor.controller"),
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
    with pytest.raises(ValueError, match=r"corridor\.controller must be one of pursuit, drift_observer"):
        load_nav_config(overrides=["corridor.controller=lqr"])


@pytest.mark.parametrize(
    "overrides,controller",
    [
        ([], "pursuit"),  # the kinematic robot: pure pursuit, today's trajectories
        (["robot.model=skid_steer"], "pursuit"),  # opt-in only: it measured worse than pure pursuit in bends
        (["robot.model=skid_steer", "corridor.controller=drift_observer"], "drift_observer"),
    ],
)
def test_the_evaluation_uses_the_drift_observer_only_when_told(overrides, controller):
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
