"""A harder robot: skid steering with terrain-dependent slip, actuator noise and command latency.

The kinematic unicycle (`nav_eval.robot.Robot`) turns and rolls exactly as commanded, so it
flatters any controller. A real Jackal is skid-steered: its wheels slide sideways whenever it
turns, how much depends on the ground, and commands reach the motors late and imperfectly. This
model keeps the unicycle's actuation (first-order lag and acceleration limits on the commanded
v, omega) and replaces what happens between the drive and the ground. Per physics tick of dt:

1. Latency: a command takes effect `latency_ticks` ticks after it was given (a FIFO queue).
2. Drive: lag and acceleration limits give the drive's (v_d, w_d), as for the unicycle. Its
   controller mixes them into wheel speeds with the ICR expansion it was calibrated for (firm,
   flat ground), alpha_0:  v_l,r = v_d -+ w_d alpha_0 B / 2  (B: track width).
3. Actuator noise: each wheel speed is multiplied by (1 + n), n an Ornstein-Uhlenbeck process of
   stationary std `noise_std` and correlation time `noise_tau`, from the run's seeded stream. It
   is relative, so a robot at rest stays at rest.
4. Longitudinal slip: the wheels' ground speed is (1 - i) times their speed, with
   i = clip(i_0 + k_rho rho + k_theta sin(pitch) sign(v_d), 0, 0.9), rho the field's terrain
   roughness (height std, m) and pitch the local slope along the heading (nose up > 0).
5. Kinematics, after Mandow et al. 2007 ("Experimental kinematics for wheeled skid-steer mobile
   robots", IROS): the left and right tracks turn about instantaneous centres of rotation
   (ICRs) at lateral offsets y_l = -y_r = alpha B / 2 and the body about an ICR at longitudinal
   offset x_ICR, which gives
       v_x = (v_l' + v_r') / 2,   omega = (v_r' - v_l') / (alpha B),   v_y = -x_ICR omega.
   The terrain widens the ICRs: alpha = alpha_0 + k_alpha rho, so on rough ground the robot
   turns less than commanded (omega = w_d alpha_0 / alpha before slip).
6. Cross slope: the wheels' lateral grip drops while they roll, so the robot creeps downhill at
   a drift angle proportional to the cross slope: v_y -= k_phi tan(roll) |v_x| (roll: left side
   up > 0, so the creep is to the right, -y in the robot frame).
7. Integration: midpoint in yaw, like the unicycle; v_x advances along the heading (times
   cos(pitch)), v_y across it (times cos(roll)); the pose then follows the terrain.

With zero slip (i_0 = k_rho = k_theta = k_alpha = x_ICR = k_phi = 0), no noise and no latency
the model reduces to the unicycle (a test checks it). `RobotState.v` / `omega` are the achieved
forward speed and yaw rate, so the metrics (v_avg, omega std) see the slip.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from segmin.common.angles import wrap_angle
from segmin.nav_eval.sim.robot import Robot, RobotConfig, RobotState, _actuate

if TYPE_CHECKING:
    from segmin.nav_eval.sim.protocols import SimWorld

MAX_SLIP = 0.9  # beyond this the wheels spin in place: the model no longer describes the robot


class SkidSteerRobot(Robot):
    """Skid-steer drive on the terrain (see the module docstring for the equations)."""

    def __init__(
        self,
        config: RobotConfig | None = None,
        terrain_height: Callable | None = None,
        terrain_normal: Callable | None = None,
        roughness: float = 0.0,
    ) -> None:
        super().__init__(config, terrain_height, terrain_normal)
        if roughness < 0:
            raise ValueError(f"terrain roughness must be >= 0, got {roughness}")
        self.roughness = float(roughness)
        self._queue: deque[tuple[int, tuple[float, float]]] = deque()
        self._reset_drive(None)

    def _reset_drive(self, rng: np.random.Generator | None) -> None:
        self._queue.clear()
        self._active = (0.0, 0.0)  # the command the drive is following now (after the latency)
        self._drive = (0.0, 0.0)  # v_d, w_d after lag and acceleration limits
        self._noise = np.zeros(2)  # relative wheel-speed errors, left and right
        self._tick = 0
        self._rng = rng if rng is not None else np.random.default_rng(0)

    def reset(self, x: float, y: float, yaw: float, rng: np.random.Generator | None = None) -> RobotState:
        """Place the robot at rest; `rng` is the run's actuator-noise stream (seeded by the run)."""
        self._reset_drive(rng)
        return super().reset(x, y, yaw)

    def command(self, v: float, omega: float) -> None:
        """Queue the command: the drive follows it `latency_ticks` physics ticks from now."""
        super().command(v, omega)
        self._queue.append((self._tick + self.config.skid.latency_ticks, self._cmd))

    def step(self, dt: float) -> RobotState:
        """Advance by dt seconds: latency, actuation, wheel noise, slip, skid-steer kinematics."""
        c, s = self.config, self.state
        while self._queue and self._queue[0][0] <= self._tick:
            self._active = self._queue.popleft()[1]
        v_old, w_old = self._drive
        v_new = _actuate(v_old, self._active[0], dt, c.lag_tau, c.max_lin_acc)
        w_new = _actuate(w_old, self._active[1], dt, c.lag_tau, c.max_ang_acc)
        self._drive = (v_new, w_new)
        self._advance_noise(dt)
        vx, vy, w = self.body_velocity(0.5 * (v_old + v_new), 0.5 * (w_old + w_new))
        yaw_mid = s.yaw + 0.5 * w * dt
        forward = vx * math.cos(s.pitch) * dt
        side = vy * math.cos(s.roll) * dt
        cy, sy = math.cos(yaw_mid), math.sin(yaw_mid)
        s.x += forward * cy - side * sy
        s.y += forward * sy + side * cy
        s.yaw = wrap_angle(s.yaw + w * dt)
        s.v, _, s.omega = self.body_velocity(v_new, w_new)
        self._tick += 1
        self._follow_terrain()
        return s

    def slip_ratio(self, v_drive: float) -> float:
        """Longitudinal slip i at the current pose (step 4)."""
        k = self.config.skid
        uphill = math.sin(self.state.pitch) * (1.0 if v_drive >= 0 else -1.0)
        i = k.longitudinal_slip + k.slip_per_roughness * self.roughness + k.slip_per_slope * uphill
        return min(max(i, 0.0), MAX_SLIP)

    def body_velocity(self, v_drive: float, w_drive: float) -> tuple[float, float, float]:
        """(v_x, v_y, omega) in the robot frame for the drive's (v_d, w_d) here (steps 2-6)."""
        k = self.config.skid
        half = 0.5 * k.icr_expansion * k.track_width
        keep = 1.0 - self.slip_ratio(v_drive)
        left = (v_drive - w_drive * half) * (1.0 + self._noise[0]) * keep
        right = (v_drive + w_drive * half) * (1.0 + self._noise[1]) * keep
        alpha = k.icr_expansion + k.icr_expansion_per_roughness * self.roughness
        vx = 0.5 * (left + right)
        w = (right - left) / (alpha * k.track_width)
        vy = -k.icr_x * w - k.cross_slope_drift * math.tan(self.state.roll) * abs(vx)
        return vx, vy, w

    def _advance_noise(self, dt: float) -> None:
        """One exact Ornstein-Uhlenbeck step of both wheels' relative errors (step 3)."""
        k = self.config.skid
        if k.noise_std == 0:
            return
        a = math.exp(-dt / k.noise_tau)
        self._noise = self._noise * a + k.noise_std * math.sqrt(1.0 - a * a) * self._rng.standard_normal(2)


def make_robot(config: RobotConfig, world: SimWorld) -> Robot:
    """The robot `config.model` names, on `world`'s terrain (its spec's roughness sets the slip)."""
    if config.model == "kinematic":
        return Robot(config, world.terrain_height, world.terrain_normal)
    roughness = float(world.spec.terrain.roughness)
    return SkidSteerRobot(config, world.terrain_height, world.terrain_normal, roughness=roughness)
