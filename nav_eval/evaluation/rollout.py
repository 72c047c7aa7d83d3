"""nav-eval's episode: a plain rollout of the robot runtime (`RowFollower`) in the simulator.

Nothing here fuses masks or keeps time: the runtime does, exactly as on the robot. The rollout
drives the simulator (`nav_eval.sim.row_env.RowEnv`) through its public interface, the one the
Gymnasium env adapts, and adds only the simulator's three economies, which change no command:

- it asks the runtime whether the next frame will be segmented (`needs_frame`) and asks the
  simulator for that frame only then (with the paper's rates, 15 of the 30 frames per second
  render); a frame that is not rendered reaches the runtime as its timestamp, without image or
  mask, and blank depth;
- it asks for a frame's colour only when something reads it (a segmenter on images, a
  navigator that declares `rgb`, the video, a recorder): the oracle's runs of SegMin, SegMinD
  and SegZeros render depth and mask alone (`RowEnv.frame(colour=False)`);
- each rendered frame is segmented on a helper thread (`BackgroundSegmenter`) while the next
  ones render; the runtime waits for that mask only when a command needs it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from segmin.nav_eval.replay.video import overlay
from segmin.nav_eval.runtime.follower import RowFollower
from segmin.nav_eval.sim.faults import FaultInjector, faults_read_colour
from segmin.nav_eval.sim.protocols import FrameSegmenter
from segmin.nav_eval.sim.row_env import RowEnv
from segmin.nav_eval.sim.segmentation import BackgroundSegmenter
from segmin.nav_eval.sim.track import Trajectory


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
    commands: list[tuple[float, float, float, float | None]]  # t, v, omega, target column
    video: list[np.ndarray]
    # (t, the command in force drives) at every runtime step: the fault metrics read it
    driving: list[tuple[float, bool]] = dataclasses.field(default_factory=list)


def run_episode(
    simulator: RowEnv,
    follower: RowFollower,
    segmenter: FrameSegmenter,
    seed: int,
    *,
    video: bool = False,
    pose: tuple[float, float, float] | None = None,
    recorder: Any = None,
) -> Episode:
    """Drive one run to its end with `follower`, its masks from `segmenter` (the oracle, or a
    model on the rendered images); `pose` replaces the seeded start. `recorder` (a
    `sim.bag_recorder.RunRecorder`) is given every camera frame, every runtime step and every command.

    The loop stays whole: rendering, background segmentation, the runtime step and the simulator
    step interleave per frame, and splitting it would pass that per-frame state around."""
    follower.reset()
    info = simulator.reset(seed, pose)
    period = simulator.camera_period
    imu = simulator.config.perception.imu
    # What the runtime gets of a frame that is not rendered (no command reads it: it serves no
    # segmentation deadline) and what the video shows when a command falls on one.
    blank_rgb = np.zeros((*simulator.camera_size, 3), dtype=np.uint8)
    blank_depth = np.zeros(simulator.camera_size, dtype=np.float32)
    commands: list[tuple[float, float, float, float | None]] = []
    frames_out: list[np.ndarray] = []
    ended = info["reason"] is not None
    faults = simulator.config.faults
    spoil = FaultInjector(faults, seed) if faults else None  # the configured sensor faults (sim.faults)
    driving: list[tuple[float, bool]] = []
    colour = (
        video
        or recorder is not None
        or segmenter.reads_colour
        or follower.navigator.inputs.rgb
        or faults_read_colour(faults)
    )
    render = True  # the first frame always serves deadline 0
    with BackgroundSegmenter(segmenter) as background:
        while not ended:
            t = simulator.t
            if render:
                frame = simulator.frame(colour)
                if spoil is not None:
                    frame = spoil(frame, t)
            if recorder is not None:  # the frames as the robot got them, faults included
                recorder.frame(simulator, t, frame if render else None)
            if render:
                out = follower.step(
                    frame.rgb,
                    frame.depth,
                    t,
                    mask=background.submit(frame),
                    attitude=simulator.attitude if imu else None,
                )
            else:
                out = follower.step(None, blank_depth, t, attitude=simulator.attitude if imu else None)
            driving.append((t, out.command.valid))
            if recorder is not None:
                recorder.step(t, out, follower.navigator)
            if out.fresh:
                cmd = out.command
                column = cmd.target_column
                commands.append((t, float(cmd.v), float(cmd.omega), None if column is None else float(column)))
                if recorder is not None:
                    recorder.command(t, float(cmd.v), float(cmd.omega))
                if video:
                    frames_out.append(overlay(frame.rgb if render else blank_rgb, out.fused, column))
            render = follower.needs_frame(t + period, t + 2 * period)
            ended, _ = simulator.step((out.command.v, out.command.omega))
    reason = simulator.reason or "error"
    return Episode(
        trajectory=simulator.trajectory,
        reason=reason,
        success=reason == "success",
        clearance_time=simulator.clearance_time,
        collisions=int(reason == "collision"),
        start_pose=simulator.start_pose,
        goal_m=simulator.goal_distance,
        commands=commands,
        video=frames_out,
        driving=driving,
    )
