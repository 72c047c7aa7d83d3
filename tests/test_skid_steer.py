"""The skid-steer robot (nav_eval.skid_steer): reduces to the unicycle without slip, and each of its
effects (slip, lateral drift, latency, noise) has the documented size and sign. Pure numpy."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from segmin.common.config import ConfigError
from segmin.nav_eval.sim.config import load_nav_config
from segmin.nav_eval.sim.robot import Robot, RobotConfig, SkidSteerConfig
from segmin.nav_eval.sim.skid_steer import SkidSteerRobot, make_robot

DT = 1.0 / 60.0
NO_SLIP = SkidSteerConfig(
    icr_expansion_per_roughness=0.0,
    icr_x=0.0,
    longitudinal_slip=0.0,
    slip_per_roughness=0.0,
    slip_per_slope=0.0,
    cross_slope_drift=0.0,
    latency_ticks=0,
    noise_std=0.0,
)


def _skid(roughness: float = 0.0, normal=(0.0, 0.0, 1.0), **changes) -> SkidSteerRobot:
    config = RobotConfig(model="skid_steer", skid=dataclasses.replace(NO_SLIP, **changes))
    n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    return SkidSteerRobot(config, None, lambda x, y: n, roughness=roughness)


def _drive(
    robot: Robot,
    commands: list[tuple[float, float]],
    ticks_per_command: int = 2,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """x, y, yaw, v, omega after every tick, holding each command for `ticks_per_command` ticks."""
    robot.reset(0.0, 0.0, 0.0, rng=rng)
    rows = []
    for v, w in commands:
        robot.command(v, w)
        for _ in range(ticks_per_command):
            s = robot.step(DT)
            rows.append((s.x, s.y, s.yaw, s.v, s.omega))
    return np.array(rows)


COMMANDS = [(0.5, 0.0)] * 60 + [(0.5, 0.4)] * 60 + [(0.3, -0.6)] * 30 + [(0.0, 0.0)] * 30


def test_without_slip_noise_or_latency_it_is_the_unicycle() -> None:
    tilted = (0.05, -0.03, 1.0)  # a slope under the robot: pitch and roll both non-zero
    for normal in ((0.0, 0.0, 1.0), tilted):
        n = np.asarray(normal) / np.linalg.norm(normal)
        unicycle = _drive(Robot(RobotConfig(), None, lambda x, y, n=n: n), COMMANDS)
        skid = _drive(_skid(normal=normal), COMMANDS)
        assert np.allclose(skid, unicycle, atol=1e-9, rtol=0)
    # ... whatever the calibrated ICR expansion: the drive's mixing and the kinematics cancel.
    assert np.allclose(_drive(_skid(icr_expansion=2.3), COMMANDS), _drive(Robot(RobotConfig()), COMMANDS), atol=1e-9)


def test_rough_ground_slips_and_under_turns_by_the_documented_factors() -> None:
    rho = 0.1
    robot = _skid(roughness=rho, longitudinal_slip=0.03, slip_per_roughness=1.0, icr_expansion_per_roughness=3.0)
    out = _drive(robot, [(0.5, 0.4)] * 300)
    i = 0.03 + 1.0 * rho  # longitudinal slip
    alpha = 1.5 + 3.0 * rho  # ICR expansion on this ground (the drive assumes 1.5)
    assert out[-1, 3] == pytest.approx(0.5 * (1 - i), rel=1e-6)
    assert out[-1, 4] == pytest.approx(0.4 * (1 - i) * 1.5 / alpha, rel=1e-6)
    unicycle = _drive(Robot(RobotConfig()), [(0.5, 0.4)] * 300)
    assert out[-1, 4] < 0.8 * unicycle[-1, 4] and np.unwrap(out[:, 2])[-1] < np.unwrap(unicycle[:, 2])[-1]


def test_uphill_slips_more_than_downhill() -> None:
    uphill = (-0.1, 0.0, 1.0)  # ground rising along +x: nose up
    up = _drive(_skid(normal=uphill, slip_per_slope=0.5), [(0.5, 0.0)] * 200)
    down = _drive(_skid(normal=uphill, slip_per_slope=0.5), [(-0.5, 0.0)] * 200)
    pitch = math.atan(0.1)
    assert up[-1, 3] == pytest.approx(0.5 * (1 - 0.5 * math.sin(pitch)), rel=1e-6)
    assert down[-1, 3] == pytest.approx(-0.5, rel=1e-6)  # backing down the slope: slip clipped at 0


def test_cross_slope_creeps_downhill_and_the_icr_offset_slides_a_turn_outward() -> None:
    left_up = (0.0, -0.1, 1.0)  # ground rising to the left of a robot heading +x: roll > 0
    out = _drive(_skid(normal=left_up, cross_slope_drift=0.5), [(0.5, 0.0)] * 300)
    assert out[-1, 1] < -0.02  # drifted to the right, downhill
    assert abs(out[-1, 2]) < 1e-9  # without turning
    flat = _drive(_skid(), [(0.5, 0.0)] * 300)
    assert abs(flat[-1, 1]) < 1e-12
    robot = _skid(icr_x=0.05)
    robot.reset(0.0, 0.0, 0.0)
    _vx, vy, w = robot.body_velocity(0.5, 0.4)
    assert w > 0 and vy == pytest.approx(-0.05 * w)  # turning left, the centre slides right


def test_latency_delays_the_response_by_exactly_n_ticks() -> None:
    steps = [(0.5, 0.3)] * 40 + [(0.0, -0.2)] * 40
    base = _drive(_skid(), steps, ticks_per_command=1)
    for n in (1, 6):
        late = _drive(_skid(latency_ticks=n), steps, ticks_per_command=1)
        assert np.all(late[:n, 3:] == 0)
        assert np.allclose(late[n:, 3:], base[:-n, 3:], atol=1e-12)


def test_actuator_noise_is_reproducible_from_the_seed() -> None:
    def run(seed: int) -> np.ndarray:
        return _drive(_skid(noise_std=0.05), COMMANDS, rng=np.random.default_rng(seed))

    assert np.array_equal(run(3), run(3))
    assert not np.allclose(run(3), run(4))
    still = _drive(_skid(noise_std=0.05), [(0.0, 0.0)] * 60, rng=np.random.default_rng(0))
    assert np.all(still == 0)  # relative noise: at rest it stays at rest


# Clearpath's Jackal controller mixes wheel speeds for a track of wheel_separation 0.37559 m times
# wheel_separation_multiplier 1.5, its calibration on firm ground (docs/reference/robot-model.md).
JACKAL_WHEEL_SEPARATION = 0.37559
JACKAL_SEPARATION_MULTIPLIER = 1.5


@pytest.mark.parametrize("v, omega", [(0.5, 0.0), (0.5, 0.4), (0.3, -1.0), (0.0, 1.0)])
def test_the_default_drive_mixes_wheel_speeds_as_the_jackal_controller_does(v: float, omega: float) -> None:
    """On firm, flat ground the shipped robot turns as commanded, and its drive mixes wheel speeds
    over the same effective track as the Jackal's controller (so a recorded Jackal's wheel speeds
    mean the same yaw rate here)."""
    config = load_nav_config(overrides=["robot.model=skid_steer"]).robot
    skid = dataclasses.replace(config.skid, noise_std=0.0, longitudinal_slip=0.0)
    robot = SkidSteerRobot(dataclasses.replace(config, skid=skid), None, None, roughness=0.0)
    robot.reset(0.0, 0.0, 0.0)
    vx, _, w = robot.body_velocity(v, omega)
    assert (vx, w) == (pytest.approx(v), pytest.approx(omega))
    jackal_track = JACKAL_WHEEL_SEPARATION * JACKAL_SEPARATION_MULTIPLIER
    assert skid.icr_expansion * skid.track_width == pytest.approx(jackal_track, rel=2e-3)


def test_the_model_is_chosen_and_checked_by_the_nav_config() -> None:
    world = type(
        "W",
        (),
        {
            "terrain_height": None,
            "terrain_normal": None,
            "spec": type("S", (), {"terrain": type("T", (), {"roughness": 0.07})()})(),
        },
    )()
    assert type(make_robot(load_nav_config().robot, world)) is Robot  # the default: kinematic
    skid = make_robot(load_nav_config(overrides=["robot.model=skid_steer"]).robot, world)
    assert isinstance(skid, SkidSteerRobot) and skid.roughness == 0.07
    for bad, word in [
        ("robot.model=tank", "robot.model"),
        ("robot.skid.latency=3", "latency"),
        ("robot.skid.icr_expansion=0.8", "icr_expansion"),
        ("robot.skid.latency_ticks=-1", "latency_ticks"),
        ("robot.skid.longitudinal_slip=1.0", "longitudinal_slip"),
    ]:
        with pytest.raises(ConfigError, match=word):
            load_nav_config(overrides=[bad])


def test_the_closed_loop_drives_a_row_with_the_skid_steer_robot_reproducibly() -> None:
    from test_nav_eval_sim import FakeRenderer, FakeWorld

    from segmin.nav_eval.evaluation.rollout import run_episode
    from segmin.nav_eval.sim.config import NavEvalConfig, Perception, RunSettings
    from segmin.nav_eval.sim.factories import make_follower
    from segmin.nav_eval.sim.oracle import OracleSegmenter
    from segmin.nav_eval.sim.row_env import RowEnv

    def run(model: str, seed: int):
        config = NavEvalConfig(
            robot=RobotConfig(model=model),
            perception=Perception(width=48, height=48),
            run=RunSettings(length_m=6.0, time_limit_s=30.0),
        )
        world = FakeWorld()
        simulator = RowEnv(world, FakeRenderer(world), config)
        return run_episode(simulator, make_follower("segmin", 5.0, config), OracleSegmenter(), seed)

    a, b, kinematic = run("skid_steer", 1), run("skid_steer", 1), run("kinematic", 1)
    assert a.reason == "success", a.reason
    assert np.array_equal(a.trajectory.y, b.trajectory.y)  # seeded noise
    assert not np.allclose(a.trajectory.y[:200], kinematic.trajectory.y[:200])  # ... and a different robot
    assert np.mean(a.trajectory.v[60:]) < np.mean(kinematic.trajectory.v[60:])  # slip costs speed
