"""The simulator: the world side of the closed loop in simulated time, robot + camera in a field.

`RowEnv` places the robot at the row entrance with a seeded lateral offset and heading error
(`reset(seed)`), and `step((v, omega))` holds that command for one camera period
(1 / camera_hz), integrating the robot at physics_hz and checking the end conditions at every
tick. `frame()` renders the camera frame at the current tick on demand: a frame nobody asks for
is never rendered, which is how nav-eval renders only the frames the runtime will segment. The
robot's software (segmenter, mask fusion, navigator, all timing) is
`nav_eval.runtime.RowFollower`, the same one a robot runs.

Its public interface is all that its two drivers use: `nav_eval.sim.gym_env.RowFollowEnv`, a
thin Gymnasium adapter, and nav-eval's rollout (`nav_eval.evaluation.rollout.run_episode`):
`reset`, `step`, `frame`, the state (`t`, `pose`, `attitude`, `trajectory`, `reason`,
`clearance_time`, `start_pose`, `goal_distance`) and the row driven (`gap`, `centreline`,
`half_width`), and the camera (`camera_period`, `camera_size`).

End conditions (first one wins): "success" (covered run.length_m along the centreline),
"collision" (footprint touches a trunk or post), "left_row" (|lateral| beyond the gap's free
half-width, or run.back_margin_m behind the start), "stalled" (less than stall_distance_m of
progress over stall_time_s), "timeout" (time_limit_s).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from segmin.nav_eval.sim.config import NavEvalConfig
from segmin.nav_eval.sim.protocols import SimFrame, SimRenderer, SimWorld
from segmin.nav_eval.sim.robot import footprint_distances, imu_attitude
from segmin.nav_eval.sim.skid_steer import make_robot
from segmin.nav_eval.sim.track import PolylineProjection, Trajectory, point_on_polyline, polyline_length

if TYPE_CHECKING:
    from segmin.data.synth.camera import CameraModel


@dataclasses.dataclass(frozen=True)
class CameraFrame:
    """A camera frame as the simulated robot receives it: the render, with the sensor's depth noise."""

    rgb: np.ndarray | None  # uint8 H x W x 3; None for a frame asked without colour (`RowEnv.frame`)
    depth: np.ndarray  # float32 H x W metres, 0 = no reading
    mask: np.ndarray  # bool H x W exact vegetation (for the oracle only)


def depth_noise_camera(renderer: SimRenderer, scale: float) -> CameraModel | None:
    """The renderer's camera with its depth-noise model scaled by `scale` (sigma coefficient and
    dropout share); None when the camera's depth noise is switched off (`depth_noise_enabled`)."""
    camera = renderer.camera
    if not camera.depth_noise_enabled:
        return None
    if scale == 1.0:
        return camera
    return dataclasses.replace(
        camera,
        depth_noise_k=camera.depth_noise_k * scale,
        depth_invalid_fraction=min(1.0, camera.depth_invalid_fraction * scale),
    )


class RowEnv:
    """The simulator: one row gap of a world, a robot in it, and its camera (module docstring)."""

    def __init__(
        self, world: SimWorld, renderer: SimRenderer, config: NavEvalConfig, *, gap: int | None = None
    ) -> None:
        self.world = world
        self.renderer = renderer
        self.config = config
        n_gaps = len(world.centrelines)
        if n_gaps == 0:
            raise ValueError(f"world {world.spec.name!r} has no row gap (centrelines is empty)")
        g = config.run.gap if gap is None else gap
        self.gap = n_gaps // 2 if g is None else int(g)
        if not 0 <= self.gap < n_gaps:
            raise ValueError(f"run.gap={self.gap} but the world has {n_gaps} gap(s)")
        self.centreline = np.asarray(world.centrelines[self.gap], dtype=float)
        self._projection = PolylineProjection(self.centreline)  # the robot is projected at every tick
        self.half_width = float(world.gap_half_widths[self.gap])
        self.row_length = polyline_length(self.centreline)
        plants = np.asarray(world.plant_circles, dtype=float).reshape(-1, 3)
        obstacles = np.asarray(world.obstacle_circles, dtype=float).reshape(-1, 3)
        self.plants, self.obstacles = plants, obstacles
        self._solid = np.concatenate([plants, obstacles], axis=0)
        self.robot = make_robot(config.robot, world)
        self._depth_camera = depth_noise_camera(renderer, config.perception.depth_noise_scale)
        r = config.rates
        self.dt = 1.0 / r.physics_hz
        self.cam_every = r.physics_hz // r.camera_hz
        self.goal_s = 0.0
        self.start_s = 0.0
        self.reason: str | None = None
        self.clearance_time: float | None = None
        self.start_pose = (0.0, 0.0, 0.0)
        self._rows: list[tuple[float, ...]] = []
        self._tick = 0
        self._frame: tuple[int, CameraFrame] | None = None

    def reset(self, seed: int, pose: tuple[float, float, float] | None = None) -> dict[str, Any]:
        """Start a run: seeded start noise, depth-noise and actuator-noise streams; returns the info.

        `pose` (x, y, yaw) replaces the seeded start pose (tests, scripted scenarios); it must
        pass `check_pose`.
        """
        run = self.config.run
        if pose is not None:
            pose = self.check_pose(pose)  # before anything changes: a refused pose leaves the run as it was
        seeds = np.random.SeedSequence(int(seed)).spawn(3)
        start_rng = np.random.default_rng(seeds[0])
        self._noise_rng = np.random.default_rng(seeds[1])
        self.start_s, self.goal_s = self._run_span()
        x0, y0, tangent = point_on_polyline(self.centreline, self.start_s)
        offset = float(start_rng.uniform(-run.start_lateral_max, run.start_lateral_max))
        heading = math.radians(float(start_rng.uniform(-run.start_heading_max_deg, run.start_heading_max_deg)))
        x = x0 - math.sin(tangent) * offset
        y = y0 + math.cos(tangent) * offset
        yaw = tangent + heading
        if pose is not None:
            x, y, yaw = pose
        self.start_pose = (x, y, yaw)
        self.robot.reset(x, y, yaw, rng=np.random.default_rng(seeds[2]))
        self.reason, self.clearance_time = None, None
        self._rows, self._tick, self._frame = [], 0, None
        self._progress: list[tuple[float, float]] = []
        self._record()
        self._check_end()
        return self._info()

    def check_pose(self, pose: object, name: str = "pose") -> tuple[float, float, float]:
        """`pose` as (x, y, yaw) floats if a run can start there, else ValueError naming `name`.

        A start must be finite and inside the row gap driven, where the run has not already
        ended: within the gap's free half-width of the centreline and, along it, between
        run.back_margin_m behind the start and the goal (a pose outside would end the run as
        "left_row" or "success" before its first step).
        """
        values: tuple[float, ...] = ()
        if not isinstance(pose, (str, bytes)):
            try:
                values = tuple(float(v) for v in np.asarray(pose, dtype=float).reshape(-1))
            except (TypeError, ValueError):
                values = ()
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise ValueError(f"{name} must be (x, y, yaw): three finite numbers (metres, radians), got {pose!r}")
        x, y, yaw = values
        start_s, goal_s = self._run_span()
        earliest = start_s - self.config.run.back_margin_m
        along, lateral, _ = self._projection.project(np.array([[x, y]]))
        s, offset = float(along[0]), float(lateral[0])
        if not (earliest <= s < goal_s and abs(offset) <= self.half_width):
            raise ValueError(
                f"{name} = ({x:g}, {y:g}, {yaw:g}) is outside row gap {self.gap} of the field: it lies "
                f"{s:.2f} m along the gap's centreline and {offset:+.2f} m beside it; a run starts within "
                f"{self.half_width:.2f} m of the centreline, from {earliest:.2f} m up to the goal at {goal_s:.2f} m"
            )
        return x, y, yaw

    def _run_span(self) -> tuple[float, float]:
        """(start, goal) of a run along the centreline, in metres from the row entrance."""
        run = self.config.run
        start_s = float(run.start_s)
        goal_s = min(start_s + run.length_m, self.row_length - 0.05)
        if goal_s <= start_s:
            raise ValueError(
                f"row gap {self.gap} is {self.row_length:.2f} m long; start_s={start_s} leaves nothing to drive"
            )
        return start_s, goal_s

    def step(self, action: tuple[float, float]) -> tuple[bool, dict[str, Any]]:
        """Hold (v, omega) for one camera period; returns (ended, info)."""
        if not self._rows:
            raise RuntimeError("step() before the first reset(): call reset(seed) to start a run")
        if self.reason is not None:
            raise RuntimeError("step() after the run ended; call reset()")
        self.robot.command(float(action[0]), float(action[1]))
        for _ in range(self.cam_every):
            self.robot.step(self.dt)
            self._tick += 1
            self._record()
            if self._check_end():
                break
        return self.reason is not None, self._info()

    # ---- state ------------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return self._tick * self.dt

    @property
    def tick(self) -> int:
        return self._tick

    @property
    def pose(self) -> tuple[float, float, float]:
        s = self.robot.state
        return (s.x, s.y, s.yaw)

    @property
    def attitude(self) -> tuple[float, float]:
        """The robot's (roll, pitch) as its IMU reports them (`nav_eval.robot.imu_attitude`)."""
        return imu_attitude(self.robot.state)

    @property
    def trajectory(self) -> Trajectory:
        """Every tick of the run so far (time, pose, velocities, distance to the nearest plant)."""
        return Trajectory.from_rows(self._rows)

    @property
    def goal_distance(self) -> float:
        """Metres along the centreline from the start to the goal (the run's length)."""
        return self.goal_s - self.start_s

    @property
    def camera_period(self) -> float:
        """Seconds of simulated time between two camera frames (one `step`)."""
        return 1.0 / self.config.rates.camera_hz

    @property
    def camera_size(self) -> tuple[int, int]:
        """(height, width) of the camera frames."""
        camera = self.renderer.camera
        return int(camera.height), int(camera.width)

    def _record(self) -> None:
        s = self.robot.state
        gaps = footprint_distances(s.x, s.y, s.yaw, self.plants, self.config.robot.length, self.config.robot.width)
        plant_gap = float(gaps.min()) if gaps.size else math.inf
        self._rows.append((self.t, s.x, s.y, s.yaw, s.v, s.omega, plant_gap))

    def _check_end(self) -> bool:
        s = self.robot.state
        run = self.config.run
        cfg = self.config.robot
        along, lateral, _ = self._projection.project(np.array([[s.x, s.y]]))
        self._s, self._lateral = float(along[0]), float(lateral[0])
        solid = footprint_distances(s.x, s.y, s.yaw, self._solid, cfg.length, cfg.width)
        if solid.size and solid.min() < 0.0:
            self.reason = "collision"
        elif self._s >= self.goal_s:
            self.reason, self.clearance_time = "success", self.t
        elif abs(self._lateral) > self.half_width or self._s < self.start_s - run.back_margin_m:
            self.reason = "left_row"
        elif self.t >= run.time_limit_s:
            self.reason = "timeout"
        else:
            self._progress.append((self.t, self._s))
            cut = self.t - run.stall_time_s
            while len(self._progress) > 1 and self._progress[1][0] <= cut:
                self._progress.pop(0)
            if self._progress[0][0] <= cut and self._s - self._progress[0][1] < run.stall_distance_m:
                self.reason = "stalled"
        return self.reason is not None

    def _info(self) -> dict[str, Any]:
        return {"t": self.t, "s": self._s - self.start_s, "lateral": self._lateral, "reason": self.reason}

    # ---- camera -----------------------------------------------------------------------------
    def frame(self, colour: bool = True) -> CameraFrame:
        """The camera frame at the current tick's pose, rendered on first use (fixed light and
        sky: no flicker) and cached until the robot moves. Not asking for a frame skips its
        render; `colour=False` skips its image (`rgb` is None: a consumer of mask and depth
        only), and a later colour request at the same tick adds the image to the same depth.

        Depth noise is applied here with the run's own generator, not inside the renderer, so a
        run's noise depends on its seed and on which frames were rendered, in tick order (not on
        the runs a worker did before it, nor on whether the frames had colour).
        """
        if self._frame is None or self._frame[0] != self._tick:
            self._frame = (self._tick, self.render(self._noise_rng, colour))
        elif colour and self._frame[1].rgb is None:
            self._frame = (self._tick, dataclasses.replace(self._frame[1], rgb=self._render_pose(colour=True).rgb))
        return self._frame[1]

    def render(self, noise_rng: np.random.Generator, colour: bool = True) -> CameraFrame:
        """The camera frame at the current tick's pose, uncached, its depth noise drawn from
        `noise_rng`. A recorder that wants the frames the run skips renders them here with a
        generator of its own, leaving the run's frames and noise as they are."""
        rendered = self._render_pose(colour)
        depth = rendered.depth
        if self.config.perception.depth_noise and self._depth_camera is not None:
            depth = self._depth_camera.apply_depth_noise(depth, noise_rng)
        return CameraFrame(rendered.rgb, depth, rendered.mask)

    def _render_pose(self, colour: bool) -> SimFrame:
        """The renderer's noise-free frame at the current tick's pose (fixed light and sky)."""
        _, x, y, yaw = self._rows[self._tick][:4]
        return self.renderer.render(x, y, yaw, rng=None, noisy_depth=False, colour=colour)
