"""A Jackal-like robot: kinematic unicycle with realistic actuation, riding on the terrain.

Why kinematic: a skid-steer physics robot in pybullet turns badly and runs about 2x slower
(reference-facts section 5), while what the evaluation measures is the navigator. Realism comes
from the actuation: the commanded (v, omega) pass through a first-order lag and acceleration
limits before they move the robot, so a jumpy controller pays for it as it would on the Jackal.

The pose is integrated in the horizontal plane (x, y, yaw); height, pitch and roll follow the
terrain under the robot (`World.terrain_height` / `terrain_normal`). Collisions are answered in
pure numpy: the rectangular footprint against the trunk and post circles of the world.

`robot.model: skid_steer` swaps in the harder robot of `nav_eval.skid_steer` (wheel slip that
depends on the terrain, actuator noise, command latency); its numbers are `SkidSteerConfig`,
kept here with the rest of the robot's config so the nav config loads without the model code.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Literal

import numpy as np

from segmin.common.angles import wrap_angle


@dataclasses.dataclass
class SkidSteerConfig:
    """Slip, noise and latency of the skid-steer model (equations: nav_eval.skid_steer).

    Defaults: a Jackal on grass. Its drive mixes wheel speeds with the track width times the ICR
    expansion (the Jackal's own controller uses a wheel separation multiplier of 1.5), so on firm,
    flat ground it turns as commanded; rough ground widens the ICRs further and the robot
    under-turns, slopes add longitudinal slip and a sideways creep downhill.
    """

    track_width: float = 0.376  # B: distance between the left and right wheels, m
    icr_expansion: float = 1.5  # alpha_0 >= 1: track ICRs at +-alpha_0 B / 2 on firm, flat ground
    icr_expansion_per_roughness: float = 3.0  # alpha grows by this per metre of terrain roughness (height std)
    icr_x: float = 0.02  # x_ICR: longitudinal ICR offset, m (+ ahead: a left turn slides right)
    longitudinal_slip: float = 0.03  # i_0: share of the wheel speed lost on firm, flat ground
    slip_per_roughness: float = 1.0  # i grows by this per metre of terrain roughness
    slip_per_slope: float = 0.5  # ... and by this times sin(pitch) when driving uphill (less downhill)
    cross_slope_drift: float = 0.5  # sideways creep downhill: v_y = -k tan(roll) |v_x|
    latency_ticks: int = 6  # command delay in physics ticks (6 at 60 Hz = 0.1 s)
    noise_std: float = 0.03  # actuator noise: relative wheel-speed error (stationary std)
    noise_tau: float = 0.3  # its correlation time, s (Ornstein-Uhlenbeck)

    def __post_init__(self) -> None:
        if self.track_width <= 0 or self.noise_tau <= 0:
            raise ValueError("robot.skid.track_width and robot.skid.noise_tau must be > 0")
        if self.icr_expansion < 1:
            raise ValueError(
                f"robot.skid.icr_expansion must be >= 1 (slip only widens the ICRs), got {self.icr_expansion}"
            )
        if not 0 <= self.longitudinal_slip < 1:
            raise ValueError(f"robot.skid.longitudinal_slip must be within [0, 1), got {self.longitudinal_slip}")
        for name in (
            "icr_expansion_per_roughness",
            "slip_per_roughness",
            "slip_per_slope",
            "cross_slope_drift",
            "latency_ticks",
            "noise_std",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"robot.skid.{name} must be >= 0, got {getattr(self, name)}")


@dataclasses.dataclass
class RobotConfig:
    """Geometry and actuation limits (defaults: Clearpath Jackal), and which motion model."""

    length: float = 0.51  # footprint along the heading, m
    width: float = 0.43  # footprint across, m
    wheel_radius: float = 0.098  # m (for the record: the unicycle model does not use it)
    max_v: float = 2.0  # hardware speed limit, m/s
    max_omega: float = 4.0  # hardware turn-rate limit, rad/s
    max_lin_acc: float = 1.0  # m/s^2
    max_ang_acc: float = 3.0  # rad/s^2
    lag_tau: float = 0.15  # first-order lag time constant of the drive, s (0 = none)
    model: Literal["kinematic", "skid_steer"] = "kinematic"  # kinematic: the paper comparison
    skid: SkidSteerConfig = dataclasses.field(default_factory=SkidSteerConfig)  # used by skid_steer only

    def __post_init__(self) -> None:
        for name in ("length", "width", "wheel_radius", "max_v", "max_omega", "max_lin_acc", "max_ang_acc"):
            if getattr(self, name) <= 0:
                raise ValueError(f"robot.{name} must be > 0, got {getattr(self, name)}")
        if self.lag_tau < 0:
            raise ValueError(f"robot.lag_tau must be >= 0, got {self.lag_tau}")


@dataclasses.dataclass
class RobotState:
    """Pose and executed velocities. yaw is in radians, counter-clockwise from +x."""

    x: float
    y: float
    yaw: float
    v: float = 0.0
    omega: float = 0.0
    z: float = 0.0
    pitch: float = 0.0  # nose-up positive, rad
    roll: float = 0.0  # left side up positive, rad


class Robot:
    """Unicycle with a first-order lag and acceleration limits, following the terrain."""

    def __init__(
        self,
        config: RobotConfig | None = None,
        terrain_height: Callable | None = None,
        terrain_normal: Callable | None = None,
    ) -> None:
        self.config = config or RobotConfig()
        self._height = terrain_height
        self._normal = terrain_normal
        self.state = RobotState(0.0, 0.0, 0.0)
        self._cmd = (0.0, 0.0)

    def reset(self, x: float, y: float, yaw: float, rng: np.random.Generator | None = None) -> RobotState:
        """Place the robot at rest at (x, y, yaw) on the terrain.

        `rng` is the run's actuator-noise stream; the unicycle is noise-free and ignores it.
        """
        self.state = RobotState(float(x), float(y), float(yaw))
        self._cmd = (0.0, 0.0)
        self._follow_terrain()
        return self.state

    def command(self, v: float, omega: float) -> None:
        """Set the velocity command held until the next one (clipped to the hardware limits)."""
        c = self.config
        self._cmd = (float(np.clip(v, -c.max_v, c.max_v)), float(np.clip(omega, -c.max_omega, c.max_omega)))

    def step(self, dt: float) -> RobotState:
        """Advance by dt seconds: actuation (lag, then acceleration limit), then kinematics."""
        c, s = self.config, self.state
        v_new = _actuate(s.v, self._cmd[0], dt, c.lag_tau, c.max_lin_acc)
        w_new = _actuate(s.omega, self._cmd[1], dt, c.lag_tau, c.max_ang_acc)
        # Midpoint integration of the unicycle: exact enough at 60 Hz, and cheap.
        v_mid, w_mid = 0.5 * (s.v + v_new), 0.5 * (s.omega + w_new)
        yaw_mid = s.yaw + 0.5 * w_mid * dt
        # The wheels roll on the slope: the horizontal advance shrinks with the pitch.
        ground = v_mid * math.cos(s.pitch) * dt
        s.x += ground * math.cos(yaw_mid)
        s.y += ground * math.sin(yaw_mid)
        s.yaw = wrap_angle(s.yaw + w_mid * dt)
        s.v, s.omega = v_new, w_new
        self._follow_terrain()
        return s

    def _follow_terrain(self) -> None:
        s = self.state
        if self._height is not None:
            s.z = float(self._height(s.x, s.y))
        if self._normal is not None:
            nx, ny, nz = (float(v) for v in np.asarray(self._normal(s.x, s.y), dtype=float).reshape(3))
            cy, sy = math.cos(s.yaw), math.sin(s.yaw)
            nz = max(nz, 1e-6)
            # Slope of the ground along the heading and along the left axis.
            s.pitch = math.atan(-(nx * cy + ny * sy) / nz)
            s.roll = math.atan(-(-nx * sy + ny * cy) / nz)


def imu_attitude(state: RobotState) -> tuple[float, float]:
    """(roll, pitch) of the robot as its IMU reports them, in radians.

    REP 103 (ROS): positive roll lifts the left side, positive pitch lowers the nose, and the
    body-to-level rotation is R_y(pitch) R_x(roll). The state holds the ground's slope angles
    along the heading and the left axis (a = tan(state.pitch), b = tan(state.roll)); the body
    axes are those the renderer's camera rides on: up along the ground normal n ~ (-a, -b, 1),
    forward the heading projected onto the ground. On a slope crossing the heading the forward
    axis turns slightly (by about a b), so the angles are read off these axes, not the slopes.
    """
    forward, left, n = body_axes(state)
    return math.atan2(float(left[2]), float(n[2])), -math.asin(max(-1.0, min(1.0, float(forward[2]))))


def body_axes(state: RobotState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The body's forward, left and up axes in the heading frame (x along the yaw, z up): up along
    the ground normal, forward the heading projected onto the ground (see `imu_attitude`)."""
    a, b = math.tan(state.pitch), math.tan(state.roll)
    n = np.array([-a, -b, 1.0]) / math.sqrt(1.0 + a * a + b * b)
    forward = np.array([1.0, 0.0, 0.0]) - n[0] * n
    forward /= np.linalg.norm(forward)
    return forward, np.cross(n, forward), n


def _actuate(current: float, target: float, dt: float, tau: float, max_acc: float) -> float:
    """One step of a first-order lag towards `target`, with the rate limited to max_acc."""
    desired = target if tau <= 0 else current + (target - current) * (1.0 - math.exp(-dt / tau))
    step = float(np.clip(desired - current, -max_acc * dt, max_acc * dt))
    return current + step


def footprint_distances(x: float, y: float, yaw: float, circles: np.ndarray, length: float, width: float) -> np.ndarray:
    """Signed distance from the rectangular footprint to each circle's edge (< 0: overlap).

    circles: (N, 3) of x, y, radius in the world frame. Pure numpy, vectorised: the circle
    centres go into the robot frame, are clamped to the rectangle, and the gap is measured.
    A centre inside the rectangle gives minus (radius + depth inside).
    """
    circles = np.asarray(circles, dtype=float).reshape(-1, 3)
    if circles.shape[0] == 0:
        return np.zeros(0)
    dx, dy = circles[:, 0] - x, circles[:, 1] - y
    c, s = math.cos(yaw), math.sin(yaw)
    lx, ly = c * dx + s * dy, -s * dx + c * dy
    hl, hw = 0.5 * length, 0.5 * width
    ox = np.abs(lx) - hl
    oy = np.abs(ly) - hw
    outside = np.hypot(np.maximum(ox, 0.0), np.maximum(oy, 0.0))
    inside = np.minimum(np.maximum(ox, oy), 0.0)
    return outside + inside - circles[:, 2]
