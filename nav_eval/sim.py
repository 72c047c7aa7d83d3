"""The closed loop in simulated time: robot + camera in a synth world, segmenter, navigator.

Two layers, Gymnasium-style:
- `RowEnv` is the world side. `reset(seed)` places the robot at the row entrance with a seeded
  lateral offset and heading error; `step((v, omega))` holds that command for one command
  period (1 / command_hz), integrating the robot at physics_hz and checking the end conditions
  at every tick. Both return an `Observation`: the camera frames the perception pipeline
  consumes before the next command.
- `run_episode(env, segmenter, navigator)` is the robot's software: it segments those frames,
  ORs the last `fuse_frames` masks, and asks the navigator for the next command.

Frames are rendered on demand (`RowEnv.frame(tick)`), in tick order on the calling thread, and
each is segmented on a helper thread while the next one renders: onnxruntime releases the GIL,
so segmentation and pybullet's software rasteriser share the two cores instead of taking turns.
The results do not depend on it: render order, noise draws and masks are the same either way.

Timing (deterministic, all on integer physics ticks): camera frames exist at camera_hz, the
segmenter runs at segment_hz on the latest camera frame, the navigator runs at command_hz on
the OR of the last `fuse_frames` masks (and the depth of the newest frame). Only the camera
frames that feed a used mask are rendered: with the paper's rates (30/20/5 Hz, N = 3) that is
15 of 30 frames per second. The robot pose of a frame is the pose at that camera tick.

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

from segmin.data.overlay import GREEN, tint_mask
from segmin.nav_eval.eval_config import NavEvalConfig
from segmin.nav_eval.metrics import Trajectory, polyline_length, project_onto_polyline
from segmin.nav_eval.oracle import segment_frame
from segmin.nav_eval.robot import Robot, footprint_distances


@dataclasses.dataclass
class Observation:
    """Camera ticks whose frames feed the next command, oldest first (empty once the run has ended).

    Only the ticks: `RowEnv.frame(tick)` renders a frame when the caller asks for it, so the
    caller decides what to overlap with rendering.
    """

    t: float
    ticks: list[int]


def point_on_polyline(polyline: np.ndarray, s: float) -> tuple[float, float, float]:
    """(x, y, tangent angle) at arc length s along the polyline (extrapolated past the ends)."""
    line = np.asarray(polyline, dtype=float)
    seg = np.diff(line, axis=0)
    lens = np.hypot(seg[:, 0], seg[:, 1])
    keep = lens > 1e-12
    a, seg, lens = line[:-1][keep], seg[keep], lens[keep]
    cum = np.concatenate([[0.0], np.cumsum(lens)])
    k = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(lens) - 1))
    u = (s - cum[k]) / lens[k]
    p = a[k] + u * seg[k]
    return float(p[0]), float(p[1]), float(math.atan2(seg[k, 1], seg[k, 0]))


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
        self.robot = Robot(config.robot, world.terrain_height, world.terrain_normal)
        r = config.rates
        self.dt = 1.0 / r.physics_hz
        self._cam_every = r.physics_hz // r.camera_hz
        self._seg_every = r.physics_hz // r.segment_hz
        self._cmd_every = r.physics_hz // r.command_hz
        self.goal_s = 0.0
        self.start_s = 0.0
        self.reason: str | None = None
        self.clearance_time: float | None = None
        self.start_pose = (0.0, 0.0, 0.0)
        self._rows: list[tuple[float, ...]] = []
        self._tick = 0
        self._frames: dict[int, Any] = {}

    # ---- Gymnasium-like API -------------------------------------------------------------
    def reset(self, seed: int, pose: tuple[float, float, float] | None = None) -> tuple[Observation, dict[str, Any]]:
        """Start a run: seeded start noise and depth-noise stream; returns the first frames.

        `pose` (x, y, yaw) replaces the seeded start pose (tests, scripted scenarios).
        """
        run = self.config.run
        seeds = np.random.SeedSequence(int(seed)).spawn(2)
        start_rng = np.random.default_rng(seeds[0])
        self._noise_rng = np.random.default_rng(seeds[1])
        self.start_s = float(run.start_s)
        self.goal_s = min(self.start_s + run.length_m, self.row_length - 0.05)
        if self.goal_s <= self.start_s:
            raise ValueError(f"row gap {self.gap} is {self.row_length:.2f} m long; start_s={self.start_s} leaves nothing to drive")
        x0, y0, tangent = point_on_polyline(self.centreline, self.start_s)
        offset = float(start_rng.uniform(-run.start_lateral_max, run.start_lateral_max))
        heading = math.radians(float(start_rng.uniform(-run.start_heading_max_deg, run.start_heading_max_deg)))
        x = x0 - math.sin(tangent) * offset
        y = y0 + math.cos(tangent) * offset
        yaw = tangent + heading
        if pose is not None:
            x, y, yaw = (float(v) for v in pose)
        self.start_pose = (x, y, yaw)
        self.robot.reset(x, y, yaw)
        self.reason, self.clearance_time = None, None
        self._rows, self._tick, self._frames = [], 0, {}
        self._progress: list[tuple[float, float]] = []
        self._record()
        self._check_end()
        return self._observation(), self._info()

    def step(self, action: tuple[float, float]) -> tuple[Observation, bool, dict[str, Any]]:
        """Hold (v, omega) for one command period; returns (observation, ended, info)."""
        if self.reason is not None:
            raise RuntimeError("step() after the run ended; call reset()")
        self.robot.command(float(action[0]), float(action[1]))
        for _ in range(self._cmd_every):
            self.robot.step(self.dt)
            self._tick += 1
            self._record()
            if self._check_end():
                break
        return self._observation(), self.reason is not None, self._info()

    # ---- state ------------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return self._tick * self.dt

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
    def _observation(self) -> Observation:
        """Camera ticks of the segmentation ticks in the fusion window of the command at this tick."""
        if self.reason is not None:
            return Observation(self.t, [])
        fuse = self.config.perception.fuse_frames
        last_seg = self._tick // self._seg_every
        seg_ticks = [j * self._seg_every for j in range(max(0, last_seg - fuse + 1), last_seg + 1)]
        cam_ticks: list[int] = []
        for tick in seg_ticks:
            cam = (tick // self._cam_every) * self._cam_every
            if cam not in cam_ticks:
                cam_ticks.append(cam)
        self._frames = {k: v for k, v in self._frames.items() if k in cam_ticks}
        return Observation(self.t, cam_ticks)

    def frame(self, tick: int) -> Any:
        """The camera frame at the pose of camera tick `tick`, rendered on first use (fixed light
        and sky: no flicker). Frames of the current observation stay cached until the next one.

        Depth noise is applied here with the run's own generator, not inside the renderer, so a
        run's noise depends on its seed only (not on the runs a worker did before it); ask for
        the frames of an observation in tick order (as `run_episode` does) to keep it so.
        """
        if not 0 <= tick <= self._tick:
            raise ValueError(f"camera tick {tick} is in the future (the run is at tick {self._tick})")
        if tick not in self._frames:
            _, x, y, yaw = self._rows[tick][:4]
            frame = self.renderer.render(x, y, yaw, rng=None, noisy_depth=False)
            camera = getattr(self.renderer, "camera", None)
            if self.config.perception.depth_noise and camera is not None and hasattr(camera, "apply_depth_noise"):
                frame = dataclasses.replace(frame, depth=camera.apply_depth_noise(frame.depth, self._noise_rng))
            self._frames[tick] = frame
        return self._frames[tick]


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

    def __enter__(self) -> "BackgroundSegmenter":
        return self

    def __exit__(self, *exc: object) -> None:
        self._pool.shutdown(wait=True)


@dataclasses.dataclass
class Episode:
    """One finished run: the trajectory and how it ended (metrics come from nav_eval.metrics)."""

    trajectory: Trajectory
    reason: str
    success: bool
    clearance_time: float | None
    collisions: int
    start_pose: tuple[float, float, float]
    goal_m: float
    commands: list[tuple[float, float, float, float | None]]   # t, v, omega, target column
    video: list[np.ndarray]


def run_episode(env: RowEnv, segmenter: Any, navigator: Any, seed: int, *, video: bool = False,
                pose: tuple[float, float, float] | None = None) -> Episode:
    """Drive one run to its end. The navigator must not fuse again (its fuse_frames = 1)."""
    navigator.reset()
    obs, info = env.reset(seed, pose)
    masks: dict[int, Future] = {}   # camera tick -> its mask, segmented on the helper thread
    commands: list[tuple[float, float, float, float | None]] = []
    frames_out: list[np.ndarray] = []
    ended = info["reason"] is not None
    with BackgroundSegmenter(segmenter) as background:
        while not ended:
            for key in obs.ticks:   # render in tick order; segment each while the next renders
                if key not in masks:
                    masks[key] = background.submit(env.frame(key))
            masks = {k: v for k, v in masks.items() if k in obs.ticks}
            fused = np.logical_or.reduce([masks[key].result() for key in obs.ticks])
            newest = env.frame(obs.ticks[-1])
            cmd = navigator.step(fused, newest.depth)
            column = getattr(cmd, "target_column", None)
            commands.append((obs.t, float(cmd.v), float(cmd.omega), None if column is None else float(column)))
            if video:
                frames_out.append(overlay(newest.rgb, fused, column))
            obs, ended, info = env.step((cmd.v, cmd.omega))
    reason = env.reason or "error"
    return Episode(
        trajectory=env.trajectory, reason=reason, success=reason == "success",
        clearance_time=env.clearance_time, collisions=int(reason == "collision"),
        start_pose=env.start_pose, goal_m=env.goal_s - env.start_s, commands=commands, video=frames_out)


def overlay(rgb: np.ndarray, mask: np.ndarray | None, column: float | None) -> np.ndarray:
    """Camera view with the mask tinted green and the chosen column drawn in red."""
    img = np.asarray(rgb, dtype=np.uint8).copy() if mask is None else tint_mask(rgb, mask, GREEN, opacity=0.45)
    if column is not None and np.isfinite(column):
        c = int(round(float(column)))
        c = min(max(c, 0), img.shape[1] - 1)
        img[:, max(c - 1, 0):c + 1] = (255, 0, 0)
    else:
        img[:4, :] = (255, 0, 0)   # no valid command: red bar at the top
    return img
