"""From SegCorridor's centreline to (v, omega) before the EMA: pure pursuit (the default,
`controller: pursuit`) and `centre_hold`, the law for a skid-steer robot (steps 6 and the slip
section of the algorithm in docs/reference/equations.md, where the gains are derived)."""

from __future__ import annotations

import math

from ..camera import CameraGeometry
from ..control import clip
from .config import CorridorConfig


def pursuit(y_goal: float, lookahead: float, config: CorridorConfig, camera: CameraGeometry) -> tuple[float, float]:
    """Unsmoothed (v, omega) of pure pursuit to the goal (lookahead, y_goal): the arc's curvature
    2 y / (L² + y²) at the top speed, and the paper's speed law on the goal's bearing, with the
    camera's half field of view as the largest bearing."""
    kappa = 2.0 * y_goal / (lookahead * lookahead + y_goal * y_goal)
    alpha = math.atan2(y_goal, lookahead)
    alpha_max = math.atan2(camera.width / 2.0, camera.fx)
    v = config.v_max * max(0.0, 1.0 - (alpha / alpha_max) ** 2)
    # The nominal speed, not the slowed one: a robot that slows for a large bearing still turns.
    omega = clip(config.v_max * kappa, -config.omega_max, config.omega_max)
    return v, omega


def centre_hold(
    centre: tuple[float, ...], omega: float, attitude: tuple[float, float] | None, config: CorridorConfig
) -> float:
    """Pure pursuit's yaw rate `omega` (on the short lookahead) plus heading damping and the
    slope feedforward, on a fitted centreline (modes "both", "one_side").

    The goal's offset c(L) is the best-measured number of the fit (the points lie around it);
    c_0 alone, the offset at the robot, is an extrapolation whose error is the heading's times
    3-4 m, so the law steers on c(L) and adds a small heading term. Across a slope the robot
    creeps downhill at a drift angle k_s tan(roll); the law alone balances that only with a
    standing offset 1.6 k_s tan(roll) m downhill, so `hold_slope_drift` k_s points the robot
    uphill by that angle from the IMU's roll (`slope_feedforward`)."""
    omega += config.hold_heading_gain * math.atan(centre[1]) + slope_feedforward(attitude, config)
    return clip(omega, -config.omega_max, config.omega_max)


def slope_feedforward(attitude: tuple[float, float] | None, config: CorridorConfig) -> float:
    """centre_hold's yaw rate that points the robot uphill against its creep down a cross slope
    (0 without `hold_slope_drift` or without the IMU).

    A skid-steer robot whose wheels roll across a slope slides downhill at about
    d = -k_s tan(roll) v (roll > 0: left side up, creep to the right). To hold the centre it must
    point by -d / v = k_s tan(roll) against it; the law's heading gain, (2 v / L_h + k_h), would
    turn that heading out again, so the feedforward is that gain times the angle. Unlike an
    integral it reads no fit, so it adds none of the fit's bias, and it follows the roll at
    once where the ground's roughness changes it from metre to metre."""
    if config.hold_slope_drift == 0.0 or attitude is None:
        return 0.0
    heading_gain = 2.0 * config.v_max / config.hold_lookahead + config.hold_heading_gain
    return heading_gain * config.hold_slope_drift * math.tan(attitude[0])
