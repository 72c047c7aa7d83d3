"""The world side of the closed loop in simulated time: robot + camera in a synth world.

`RowEnv` places the robot at the row entrance with a seeded lateral offset and heading error
(`reset(seed)`), and `step((v, omega))` holds that command for one camera period
(1 / camera_hz), integrating the robot at physics_hz and checking the end conditions at every
tick. `frame()` renders the camera frame at the current tick on demand. The robot's software
(segmenter, mask fusion, navigator, all timing) is `nav_eval.runtime.RowFollower`, the same one
a robot runs; `nav_eval.gym_env.RowFollowEnv` wraps this class as a Gymnasium env and
`nav_eval.rollout.run_episode` drives the runtime in it.

End conditions (first one wins): "success" (covered run.length_m along the centreline),
"collision" (footprint touches a trunk or post), "left_row" (|lateral| beyond the gap's free
half-width, or run.back_margin_m behind the start), "stalled" (less than stall_distance_m of
progress over stall_time_s), "timeout" (time_limit_s).
"""

from __future__ import annotations

import dataclasses
import math
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from segmin.nav_eval.sim.config import NavEvalConfig
from segmin.nav_eval.sim.oracle import segment_frame
from segmin.nav_eval.sim.robot import footprint_distances, imu_attitude
from segmin.nav_eval.sim.skid_steer import make_robot
from segmin.nav_eval.sim.track import Trajectory, point_on_polyline, polyline_length, project_onto_polyline


def depth_noise_camera(renderer: Any, scale: float) -> Any:
    """The renderer's camera with its depth-noise model scaled by `scale` (sigma coefficient and
    dropout share); None when the renderer has no noise model (the tests' stand-in)."""
    camera = getattr(renderer, "camera", None)
    if camera is None or not hasattr(camera, "apply_depth_noise"):
        return None
    if scale == 1.0:
        return camera
    return dataclasses.replace(
        camera,
        depth_noise_k=camera.depth_noise_k * scale,
        depth_invalid_fraction=min(1.0, camera.depth_invalid_fraction * scale),
    )


class RowEnv:
    """One row gap of a world, a robot in it, and the rendering schedule."""

    def __init__(self, world: Any, renderer: Any, config: NavEvalConfig, *, gap: int | None = None) -> None:
        self.world = world
        self.renderer = renderer
        self.config = config
        n_gaps = len(world.centrelines)
        if n_gaps == 0:
            raise ValueError(f"world {getattr(world.spec, 'name', '?')!r} has no row gap (centrelines is empty)")
        g = config.run.gap if gap is None else gap
        self.gap = n_gaps // 2 if g is None else int(g)
        if not 0 <= self.gap < n_gaps:
            raise ValueError(f"run.gap={self.gap} but the world has {n_gaps} gap(s)")
        self.centreline = np.asarray(world.centrelines[self.gap], dtype=float)
        self.half_width = float(world.gap_half_widths[self.gap])
        self.row_length = polyline_length(self.centreline)
        plants = np.asarray(world.plant_circles, dtype=float).reshape(-1, 3)
        obstacles = np.asarray(getattr(world, "obstacle_circles", np.zeros((0, 3))), dtype=float).reshape(-1, 3)
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
        self._frame: tuple[int, Any] | None = None

    def reset(self, seed: int, pose: tuple[float, float, float] | None = None) -> dict[str, Any]:
        """Start a run: seeded start noise, depth-noise and actuator-noise streams; returns the info.

        `pose` (x, y, yaw) replaces the seeded start pose (tests, scripted scenarios).
        """
        run = self.config.run
        seeds = np.random.SeedSequence(int(seed)).spawn(3)
        start_rng = np.random.default_rng(seeds[0])
        self._noise_rng = np.random.default_rng(seeds[1])
        self.start_s = float(run.start_s)
        self.goal_s = min(self.start_s + run.length_m, self.row_length - 0.05)
        if self.goal_s <= self.start_s:
            raise ValueError(
                f"row gap {self.gap} is {self.row_length:.2f} m long; start_s={self.start_s} leaves nothing to drive"
            )
        x0, y0, tangent = point_on_polyline(self.centreline, self.start_s)
        offset = float(start_rng.uniform(-run.start_lateral_max, run.start_lateral_max))
        heading = math.radians(float(start_rng.uniform(-run.start_heading_max_deg, run.start_heading_max_deg)))
        x = x0 - math.sin(tangent) * offset
        y = y0 + math.cos(tangent) * offset
        yaw = tangent + heading
        if pose is not None:
            x, y, yaw = (float(v) for v in pose)
        self.start_pose = (x, y, yaw)
        self.robot.reset(x, y, yaw, rng=np.random.default_rng(seeds[2]))
        self.reason, self.clearance_time = None, None
        self._rows, self._tick, self._frame = [], 0, None
        self._progress: list[tuple[float, float]] = []
        self._record()
        self._check_end()
        return self._info()

    def step(self, action: tuple[float, float]) -> tuple[bool, dict[str, Any]]:
        """Hold (v, omega) for one camera period; returns (ended, info)."""
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
        return Trajectory.from_rows(self._rows)

    def _record(self) -> None:
        s = self.robot.state
        gaps = footprint_distances(s.x, s.y, s.yaw, self.plants, self.config.robot.length, self.config.robot.width)
        plant_gap = float(gaps.min()) if gaps.size else math.inf
        self._rows.append((self.t, s.x, s.y, s.yaw, s.v, s.omega, plant_gap))

    def _check_end(self) -> bool:
        s = self.robot.state
        run = self.config.run
        cfg = self.config.robot
        along, lateral, _ = project_onto_polyline(np.array([[s.x, s.y]]), self.centreline)
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
    def frame(self) -> Any:
        """The camera frame at the current tick's pose, rendered on first use (fixed light and
        sky: no flicker) and cached until the robot moves.

        Depth noise is applied here with the run's own generator, not inside the renderer, so a
        run's noise depends on its seed and on which frames were rendered, in tick order (not on
        the runs a worker did before it).
        """
        if self._frame is None or self._frame[0] != self._tick:
            self._frame = (self._tick, self.render(self._noise_rng))
        return self._frame[1]

    def render(self, noise_rng: np.random.Generator) -> Any:
        """The camera frame at the current tick's pose, uncached, its depth noise drawn from
        `noise_rng`. A recorder that wants the frames the run skips renders them here with a
        generator of its own, leaving the run's frames and noise as they are."""
        _, x, y, yaw = self._rows[self._tick][:4]
        frame = self.renderer.render(x, y, yaw, rng=None, noisy_depth=False)
        if self.config.perception.depth_noise and self._depth_camera is not None:
            frame = dataclasses.replace(frame, depth=self._depth_camera.apply_depth_noise(frame.depth, noise_rng))
        return frame


class BackgroundSegmenter:
    """Segments frames on one helper thread while the caller renders the next one.

    `submit` returns only once the helper has started the job. A thread waiting for the GIL
    gets it at the holder's next switch point, and pybullet holds the GIL for the whole of
    `getCameraImage`: without the handshake the helper would start after the next render, and
    nothing would overlap. Once started, the helper releases the GIL inside onnxruntime.
    """

    def __init__(self, segmenter: Any) -> None:
        self.segmenter = segmenter
        # OnnxSegmenter splits `segment` into prepare (check, resize) and segment_prepared.
        self._two_phase = hasattr(segmenter, "prepare") and hasattr(segmenter, "segment_prepared")
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="segmin-segment")

    def submit(self, frame: Any) -> Future:
        """Start segmenting `frame`; the future holds its bool mask."""
        # Resize on this thread: OpenCV releases the GIL, which would hand it to this thread's
        # next render and stall the helper before it reached onnxruntime.
        prepared = self.segmenter.prepare(frame.rgb) if self._two_phase else None
        started = threading.Event()

        def job() -> np.ndarray:
            started.set()
            if prepared is None:
                return segment_frame(self.segmenter, frame)
            return np.asarray(self.segmenter.segment_prepared(prepared), dtype=bool)

        future = self._pool.submit(job)
        started.wait()
        return future

    def __enter__(self) -> BackgroundSegmenter:
        return self

    def __exit__(self, *exc: object) -> None:
        self._pool.shutdown(wait=True)
