"""nav-eval's episode: a plain rollout of the robot runtime (`RowFollower`) in `RowFollowEnv`.

Nothing here fuses masks or keeps time: the runtime does, exactly as on the robot. The rollout
only adds the simulator's two economies, which change no command:

- it asks the runtime whether the next frame will be segmented (`needs_frame`) and lets the env
  skip rendering it otherwise (with the paper's rates, 15 of the 30 frames per second render);
- each rendered frame is segmented on a helper thread (`sim.BackgroundSegmenter`) while the next
  one renders; the runtime waits for that mask only when a deadline needs it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from segmin.nav_eval.replay.video import overlay
from segmin.nav_eval.runtime.follower import RowFollower
from segmin.nav_eval.sim.gym_env import RowFollowEnv
from segmin.nav_eval.sim.row_env import BackgroundSegmenter
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


@dataclasses.dataclass
class _Frame:
    """What a segmenter may read of a rendered frame (the oracle reads the exact mask)."""

    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray


def run_episode(
    env: RowFollowEnv,
    follower: RowFollower,
    seed: int,
    *,
    video: bool = False,
    pose: tuple[float, float, float] | None = None,
    recorder: Any = None,
) -> Episode:
    """Drive one run to its end with `follower` (its segmenter may be the oracle).

    `recorder` (a `sim.bag_recorder.RunRecorder`) is given every camera frame and every command."""
    follower.reset()
    obs, info = env.reset(seed=seed, options=None if pose is None else {"pose": pose})
    period = env.camera_period
    imu = env.config.perception.imu
    commands: list[tuple[float, float, float, float | None]] = []
    frames_out: list[np.ndarray] = []
    ended = info["reason"] is not None
    with BackgroundSegmenter(follower.segmenter) as background:
        while not ended:
            t = float(obs["t"])
            rendered = info["rendered"]
            mask = background.submit(_Frame(obs["rgb"], obs["depth"], info["mask"])) if rendered else None
            if recorder is not None:
                recorder.frame(env, obs, info)
            out = follower.step(
                obs["rgb"] if rendered else None, obs["depth"], t, mask=mask, attitude=obs["attitude"] if imu else None
            )
            if out.fresh:
                cmd = out.command
                column = cmd.target_column
                commands.append((t, float(cmd.v), float(cmd.omega), None if column is None else float(column)))
                if recorder is not None:
                    recorder.command(t, float(cmd.v), float(cmd.omega))
                if video:
                    frames_out.append(overlay(obs["rgb"], out.fused, column))
            env.skip_next_render = not follower.needs_frame(t + period, t + 2 * period)
            obs, _, terminated, truncated, info = env.step((out.command.v, out.command.omega))
            ended = terminated or truncated
    row = env.row
    reason = row.reason or "error"
    return Episode(
        trajectory=row.trajectory,
        reason=reason,
        success=reason == "success",
        clearance_time=row.clearance_time,
        collisions=int(reason == "collision"),
        start_pose=row.start_pose,
        goal_m=row.goal_s - row.start_s,
        commands=commands,
        video=frames_out,
    )


def make_env(ctx: Any, config: Any) -> RowFollowEnv:
    """An env on an already built field (a worker builds each field once, for many runs)."""
    return RowFollowEnv(ctx.spec.name, config=config, world=ctx.world, renderer=ctx.renderer, gap=ctx.gap)
