"""`segmin/RowFollow-v0` as RL libraries use it: Stable-Baselines3's checker and PPO on the default
observation, Gymnasium's checker with rendering, RecordVideo, the human window and the legacy
observation shapes."""

from __future__ import annotations

import warnings

import cv2
import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from test_gym_env import TINY
from test_nav_eval_sim import FakeRenderer, FakeWorld, _config

from segmin.nav_eval.replay.video import overlay
from segmin.nav_eval.runtime.navigator import target_column
from segmin.nav_eval.sim import human_view
from segmin.nav_eval.sim.gym_env import RowFollowEnv

SIDE = 36  # the smallest image Stable-Baselines3's default CNN takes


def _env(size: int = SIDE, **options) -> RowFollowEnv:
    world = FakeWorld()
    return RowFollowEnv(
        None, config=_config(time_limit_s=2.0), world=world, renderer=FakeRenderer(world, size=size), **options
    )


def test_stable_baselines3_checks_the_default_observation_and_ppo_trains_on_it() -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_checker import check_env

    env = _env()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    said = " | ".join(str(w.message) for w in caught)
    # What SB3 could not use as it is (a 0-d or H x W entry, float64 actions) would be warned about.
    assert "unconventional shape" not in said and "float64" not in said, said
    model = PPO("MultiInputPolicy", env, n_steps=8, batch_size=8, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=16)
    assert model.num_timesteps == 16
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (2,) and env.action_space.contains(action)


def test_rgb_array_draws_the_observed_mask_and_segmins_target_as_nav_evals_videos() -> None:
    env = _env(render_mode="rgb_array", obs_keys=("rgb", "depth", "mask"))
    obs, info = env.reset(seed=0)
    obs, *_, info = env.step(np.array([0.4, 0.0], dtype=np.float32))
    picture = env.render()
    column = target_column(info["mask"], obs["depth"][..., 0], method="segmin", depth_threshold=env.depth_threshold)
    assert column is not None and 0 <= column < SIDE
    assert np.array_equal(picture, overlay(obs["rgb"], info["mask"], column))
    assert (picture[:, int(round(column))] == (255, 0, 0)).all()  # the target, drawn in red
    assert not np.array_equal(picture, obs["rgb"])


def test_rgb_array_renders_colour_when_the_observation_has_none() -> None:
    env = _env(render_mode="rgb_array", obs_keys=("mask", "depth"))
    env.reset(seed=0)
    picture = env.render()
    assert picture.shape == (SIDE, SIDE, 3) and picture.dtype == np.uint8 and env.simulator.renderer.colour_calls == 1


def test_render_needs_a_reset_and_a_render_mode() -> None:
    with pytest.raises(RuntimeError, match=r"render\(\) before the first reset"):
        _env(render_mode="rgb_array").render()
    env = _env()
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode='rgb_array'"):
        assert env.render() is None
    with pytest.raises(ValueError, match=r"render_mode: 'rgb' is not one of \['rgb_array', 'human'\]"):
        _env(render_mode="rgb")


def test_record_video_writes_the_rendered_episode(tmp_path) -> None:
    env = gymnasium.wrappers.RecordVideo(
        _env(size=40, render_mode="rgb_array"), str(tmp_path), episode_trigger=lambda episode: True
    )
    env.reset(seed=0)
    first = env.render()
    for _ in range(5):
        env.step(np.array([0.4, 0.0], dtype=np.float32))
    env.close()
    capture = cv2.VideoCapture(str(tmp_path / "rl-video-episode-0.mp4"))
    frames = []
    while (read := capture.read())[0]:
        frames.append(cv2.cvtColor(read[1], cv2.COLOR_BGR2RGB))
    capture.release()
    # The reset's frame and one per step; MoviePy's writer may drop the last one.
    assert len(frames) in (5, 6) and frames[0].shape == (40, 40, 3)
    assert np.abs(frames[0].astype(int) - first).mean() < 12  # the rendered picture, through a lossy codec


def test_gymnasium_checks_the_made_env_in_the_render_modes_usable_here(monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    env = gymnasium.make("segmin/RowFollow-v0", field="straight_vineyard", overrides=TINY, render_mode="rgb_array")
    try:
        assert env.metadata["render_modes"] == ["rgb_array"] and env.metadata["render_fps"] == 30
        gymnasium_check_env(env.unwrapped)  # renders, and makes the env again in each mode listed
        env.reset(seed=0)
        assert env.render().shape == (32, 32, 3)
    finally:
        env.close()


def test_human_without_a_display_is_refused_in_one_line(monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(ValueError, match=r"^render_mode='human' cannot open a window: no display [^\n]*$"):
        _env(render_mode="human")
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(human_view, "opencv_has_gui", lambda: False)
    with pytest.raises(ValueError, match=r"has no GUI \(opencv-python-headless\)"):
        _env(render_mode="human")


def test_human_shows_each_frame_in_an_opencv_window(monkeypatch) -> None:
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(human_view, "opencv_has_gui", lambda: True)
    shown: list[np.ndarray] = []
    monkeypatch.setattr(cv2, "imshow", lambda title, bgr: shown.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)))
    monkeypatch.setattr(cv2, "waitKey", lambda delay: -1)
    closed: list[str] = []
    monkeypatch.setattr(cv2, "destroyWindow", closed.append)
    env = _env(render_mode="human")
    assert env.metadata["render_modes"] == ["rgb_array", "human"]
    env.reset(seed=0)
    env.step(np.array([0.4, 0.0], dtype=np.float32))
    assert env.render() is None and len(shown) == 3
    twin = _env(render_mode="rgb_array")
    twin.reset(seed=0)
    twin.step(np.array([0.4, 0.0], dtype=np.float32))
    assert np.array_equal(shown[-1], twin.render())
    env.close()
    assert len(closed) == 1


def test_legacy_observation_keeps_the_old_shapes_with_a_warning() -> None:
    with pytest.warns(FutureWarning, match=r"^legacy_observation=True: the previous release's observation shapes"):
        env = _env(size=32, legacy_observation=True, obs_keys=("rgb", "depth", "mask", "t", "attitude"))
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs) and env.action_space.dtype == np.float64
    shapes = {key: value.shape for key, value in obs.items()}
    assert shapes == {"rgb": (32, 32, 3), "depth": (32, 32), "mask": (32, 32), "t": (), "attitude": (2,)}
    new = _env(size=32, obs_keys=("rgb", "depth", "mask", "t", "attitude"))
    new_obs, _ = new.reset(seed=0)
    for key in obs:
        assert np.array_equal(obs[key], new_obs[key].reshape(obs[key].shape)), key
