"""`segmin/RowFollow-v0`: a real Gymnasium env, and nav-eval as a rollout of the runtime in it."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from test_nav_eval_sim import FakeRenderer, FakeWorld, _config

import segmin.nav_eval.sim.gym_env  # noqa: F401  (registers segmin/RowFollow-v0)
from segmin.nav_eval.evaluation.rollout import run_episode
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from segmin.nav_eval.runtime.protocols import NavigatorInputs
from segmin.nav_eval.sim.factories import make_follower
from segmin.nav_eval.sim.gym_env import RowFollowEnv
from segmin.nav_eval.sim.oracle import OracleSegmenter
from segmin.nav_eval.sim.robot import imu_attitude
from segmin.nav_eval.sim.row_env import RowEnv

TINY = ["perception.width=32", "perception.height=32", "run.length_m=1.0", "run.time_limit_s=4"]


def _fake_env(**run) -> RowFollowEnv:
    world = FakeWorld()
    return RowFollowEnv(None, config=_config(**run), world=world, renderer=FakeRenderer(world, size=32))


def test_check_env_passes() -> None:
    env = _fake_env(time_limit_s=2.0)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=1)
    assert obs["rgb"].shape == (32, 32, 3) and obs["depth"].dtype == np.float32 and float(obs["t"]) == 0.0
    assert info["mask"].shape == (32, 32) and len(info["pose"]) == 3 and math.isfinite(info["lateral"])


def test_reward_is_progress_and_the_end_flags() -> None:
    env = _fake_env(time_limit_s=1.0, start_lateral_max=0.0, start_heading_max_deg=0.0)
    env.reset(seed=0, options={"pose": (0.5, 0.0, 0.0)})
    total, truncated, terminated = 0.0, False, False
    while not (terminated or truncated):
        _, reward, terminated, truncated, info = env.step(np.array([0.5, 0.0]))
        total += reward
    assert truncated and not terminated and info["reason"] == "timeout"  # timeout = truncation
    assert total == pytest.approx(info["s"] - 0.5) and total > 0.2  # started 0.5 m in
    env = _fake_env(time_limit_s=10.0)
    env.reset(seed=0, options={"pose": (0.5, 0.0, 0.8)})
    while True:  # into the vine row
        _, _, terminated, truncated, info = env.step(np.array([0.5, 0.0]))
        if terminated or truncated:
            break
    assert terminated and info["reason"] in ("collision", "left_row")
    with pytest.raises(ValueError, match="unknown"):
        env.reset(options={"speed": 1})


def _old_loop(world: FakeWorld, config, method: str, seed: int):
    """The pre-runtime nav-eval loop, by its tick arithmetic: at each command tick, OR the masks
    of the camera frames under the last `fuse_frames` segmentation ticks, depth of the newest."""
    renderer = FakeRenderer(world)
    row = RowEnv(world, renderer, config)
    navigator = Navigator(NavigatorConfig(method=method, depth_threshold=5.0, fuse_frames=1))
    r = config.rates
    cam, seg, cmd = r.physics_hz // r.camera_hz, r.physics_hz // r.segment_hz, r.physics_hz // r.command_hz
    fuse = config.perception.fuse_frames
    frames: dict[int, object] = {}
    info = row.reset(seed)
    ended = info["reason"] is not None
    action = (0.0, 0.0)
    while not ended:
        tick = row.tick
        command_tick = -(-tick // cmd) * cmd
        last = command_tick // seg
        window = sorted({(j * seg // cam) * cam for j in range(max(0, last - fuse + 1), last + 1)})
        if tick in window:
            frames[tick] = row.frame()
        if tick % cmd == 0:
            fused = np.logical_or.reduce([frames[k].mask for k in window])
            command = navigator.step(fused, frames[window[-1]].depth)
            action = (command.v, command.omega)
            frames = {}
        ended, _ = row.step(action)
    return row.trajectory


@pytest.mark.parametrize("method", ["segmin", "segzeros"])
def test_the_runtime_in_the_env_reproduces_the_old_loop(method: str) -> None:
    config = _config(length_m=4.0)
    old = _old_loop(FakeWorld(), config, method, seed=7)
    world = FakeWorld()
    env = RowFollowEnv(None, config=config, world=world, renderer=FakeRenderer(world))
    new = run_episode(env, make_follower(OracleSegmenter(), method, 5.0, config), seed=7).trajectory
    for key in ("t", "x", "y", "yaw", "v", "omega"):
        assert np.array_equal(getattr(old, key), getattr(new, key)), key


def test_gymnasium_make_builds_a_shipped_field() -> None:
    env = gymnasium.make("segmin/RowFollow-v0", field="straight_vineyard", overrides=TINY)
    try:
        obs, info = env.reset(seed=0)
        assert obs["rgb"].shape == (32, 32, 3) and info["mask"].any()
        obs, _, terminated, truncated, info = env.step(np.array([0.4, 0.0]))
        assert float(obs["t"]) == pytest.approx(1 / 30) and not (terminated or truncated)
        # The IMU: the robot's roll and pitch on this field's rough ground.
        assert obs["attitude"].shape == (2,) and env.observation_space["attitude"].contains(obs["attitude"])
        assert np.allclose(obs["attitude"], imu_attitude(env.unwrapped.row.robot.state))
        assert np.abs(obs["attitude"]).max() > 1e-3
    finally:
        env.close()
    assert env.unwrapped._context is None  # pybullet released


class _AttitudeSpy(Navigator):
    """SegMin that declares it reads the IMU and records the attitude each command receives."""

    def __init__(self) -> None:
        super().__init__(NavigatorConfig(method="segmin", depth_threshold=5.0))
        self.inputs = NavigatorInputs(attitude=True)
        self.seen: list = []

    def command(self, fused, depth, attitude=None, rgb=None):
        self.seen.append(attitude)
        return super().command(fused, depth, attitude, rgb)


@pytest.mark.parametrize("imu", [True, False])
def test_the_rollout_gives_the_imu_to_the_navigator_unless_switched_off(imu: bool) -> None:
    from segmin.nav_eval.runtime.follower import RowFollower

    env = _fake_env(length_m=0.5)
    env.config.perception.imu = imu
    spy = _AttitudeSpy()
    run_episode(env, RowFollower(OracleSegmenter(), spy), seed=0)
    assert spy.seen
    if imu:
        assert all(a == pytest.approx((0.0, 0.0)) for a in spy.seen)  # flat stand-in ground
    else:
        assert all(a is None for a in spy.seen)
