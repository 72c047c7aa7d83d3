"""`segmin/RowFollow-v0`: a real Gymnasium env over the simulator, and nav-eval as a rollout of the
runtime in the simulator."""

from __future__ import annotations

import math
import subprocess
import sys

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from test_nav_eval_sim import FakeRenderer, FakeWorld, _config

import segmin.envs  # noqa: F401  (registers segmin/RowFollow-v0)
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
    assert obs["rgb"].shape == (32, 32, 3) and obs["depth"].shape == (32, 32, 1) and obs["t"].shape == (1,)
    assert obs["depth"].dtype == np.float32 and obs["t"][0] == 0.0
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
    for bad in ([1, 2], "pose", [("pose", (0.5, 0.0, 0.0))]):
        with pytest.raises(TypeError, match=r"^reset options must be a dict such as \{'pose'"):
            env.reset(options=bad)


def _old_loop(world: FakeWorld, config, method: str, seed: int):
    """The pre-runtime nav-eval loop, by its tick arithmetic: at each command tick, OR the masks
    of the camera frames under the last `fuse_frames` segmentation ticks, depth of the newest."""
    renderer = FakeRenderer(world)
    row = RowEnv(world, renderer, config)
    navigator = Navigator(NavigatorConfig(method=method, depth_threshold=5.0, fuse_frames=1))
    r, runtime = config.rates, config.follower.runtime
    cam, seg, cmd = r.physics_hz // r.camera_hz, r.physics_hz // runtime.segment_hz, r.physics_hz // runtime.command_hz
    fuse = config.follower.config(method, 5.0).navigator.fuse_frames
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
    new = run_episode(env.simulator, make_follower(method, 5.0, config), OracleSegmenter(), seed=7).trajectory
    for key in ("t", "x", "y", "yaw", "v", "omega"):
        assert np.array_equal(getattr(old, key), getattr(new, key)), key


def test_gymnasium_make_builds_a_shipped_field() -> None:
    env = gymnasium.make("segmin/RowFollow-v0", field="straight_vineyard", overrides=TINY)
    try:
        obs, info = env.reset(seed=0)
        assert obs["rgb"].shape == (32, 32, 3) and info["mask"].any()
        obs, _, terminated, truncated, info = env.step(np.array([0.4, 0.0]))
        assert obs["t"][0] == pytest.approx(1 / 30) and not (terminated or truncated)
        # The IMU: the robot's roll and pitch on this field's rough ground.
        assert obs["attitude"].shape == (2,) and env.observation_space["attitude"].contains(obs["attitude"])
        assert np.allclose(obs["attitude"], imu_attitude(env.unwrapped.simulator.robot.state))
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
    run_episode(env.simulator, RowFollower(None, spy), OracleSegmenter(), seed=0)
    assert spy.seen
    if imu:
        assert all(a == pytest.approx((0.0, 0.0)) for a in spy.seen)  # flat stand-in ground
    else:
        assert all(a is None for a in spy.seen)


def test_the_env_observes_what_the_simulator_renders() -> None:
    """The env is a thin adapter: its observations are the simulator's frames, step for step."""
    env = _fake_env(time_limit_s=1.0)
    world = FakeWorld()
    simulator = RowEnv(world, FakeRenderer(world, size=32), env.config)
    obs, _ = env.reset(seed=4)
    info = simulator.reset(4)
    for _ in range(5):
        frame = simulator.frame()
        assert np.array_equal(obs["rgb"], frame.rgb) and np.array_equal(obs["depth"][..., 0], frame.depth)
        assert obs["t"][0] == simulator.t and tuple(obs["attitude"]) == simulator.attitude
        obs, reward, *_ = env.step(np.array([0.4, 0.1]))
        s = info["s"]
        _, info = simulator.step((0.4, 0.1))
        assert reward == info["s"] - s


@pytest.mark.parametrize(
    ("pose", "message"),
    [
        ((math.nan, 0.0, 0.0), "three finite numbers"),
        ((1.0, 0.0, math.inf), "three finite numbers"),
        ("abc", "three finite numbers"),
        (("a", 0.0, 0.0), "three finite numbers"),
        ((1.0, 0.0), "three finite numbers"),
        ((1000.0, 1000.0, 0.0), "outside row gap 0"),  # it used to report success at reset
        ((9.0, 0.0, 0.0), "outside row gap 0"),  # past the goal (8 m)
        ((2.0, 0.85, 0.0), "outside row gap 0"),  # in the vine row (free half-width 0.8 m)
        ((-1.5, 0.0, 0.0), "outside row gap 0"),  # further behind the start than run.back_margin_m
    ],
)
def test_a_start_pose_must_be_finite_and_inside_the_row_gap(pose, message: str) -> None:
    env = _fake_env()
    env.reset(seed=0)
    start = env.simulator.start_pose
    with pytest.raises(ValueError, match=r"options\['pose'\]") as raised:
        env.reset(seed=1, options={"pose": pose})
    assert message in str(raised.value)
    assert env.simulator.start_pose == start  # the refused reset changed nothing
    obs, info = env.reset(seed=1, options={"pose": (0.5, 0.3, 0.2)})  # inside: a run that can start
    assert info["reason"] is None and np.isfinite(obs["depth"]).all() and obs["depth"].any()


@pytest.mark.parametrize("action", ["go", None, [0.1], [0.1, math.nan], [[0.1, 0.2], [0.3]]])
def test_a_bad_action_is_refused_by_name(action) -> None:
    env = _fake_env()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be two finite numbers \(v, omega\), got"):
        env.step(action)


def test_a_closed_env_says_so() -> None:
    env = _fake_env()
    env.reset(seed=0)
    env.close()
    for call in (lambda: env.step(np.array([0.1, 0.0])), lambda: env.reset(seed=0)):
        with pytest.raises(RuntimeError, match="closed RowFollowEnv"):
            call()


def test_the_simulator_refuses_a_step_before_its_first_reset() -> None:
    world = FakeWorld()
    with pytest.raises(RuntimeError, match="before the first reset"):
        RowEnv(world, FakeRenderer(world), _config()).step((0.1, 0.0))


def test_a_fresh_interpreter_makes_the_env_after_importing_segmin_envs() -> None:
    """`import segmin` needs no gymnasium; `import segmin.envs` registers without pybullet or the
    simulator; `gymnasium.make` then builds the field."""
    script = f"""
import sys
import segmin
assert "gymnasium" not in sys.modules, "import segmin loaded gymnasium"
import gymnasium
import segmin.envs
loaded = [m for m in ("pybullet", "segmin.nav_eval.sim.gym_env", "segmin.nav_eval.sim.row_env") if m in sys.modules]
assert not loaded, f"registering loaded {{loaded}}"
env = gymnasium.make("segmin/RowFollow-v0", field="straight_vineyard", overrides={TINY!r})
obs, info = env.reset(seed=0)
assert obs["rgb"].shape == (32, 32, 3) and info["mask"].any()
env.close()
print("made")
"""
    done = subprocess.run([sys.executable, "-c", script], check=False, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "made", done.stderr[-2000:]


def test_gymnasium_finds_the_env_by_module_with_no_import() -> None:
    """gymnasium.make("segmin.envs:segmin/RowFollow-v0") imports the registering module itself: the
    env's own error for an unknown field shows that it was found and built."""
    script = """
import gymnasium
try:
    gymnasium.make("segmin.envs:segmin/RowFollow-v0", field="no_such_field")
except gymnasium.error.Error as exc:
    raise SystemExit(f"not registered: {exc}")
except (ValueError, FileNotFoundError) as exc:
    print("built:", exc)
"""
    done = subprocess.run([sys.executable, "-c", script], check=False, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.startswith("built:"), done.stdout + done.stderr[-2000:]


def test_on_the_bare_install_segmin_envs_names_the_missing_extra() -> None:
    script = """
import sys
sys.modules["gymnasium"] = None  # as if not installed
import segmin
try:
    import segmin.envs
except ModuleNotFoundError as exc:
    print(exc)
"""
    done = subprocess.run([sys.executable, "-c", script], check=False, capture_output=True, text=True, timeout=120)
    assert "needs gymnasium, part of the [sim] extra" in done.stdout, done.stdout + done.stderr[-2000:]


def test_obs_keys_pick_the_observation_and_its_space() -> None:
    world = FakeWorld()
    env = RowFollowEnv(
        None, config=_config(), world=world, renderer=FakeRenderer(world, size=32), obs_keys=("mask", "depth")
    )
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=2)
    assert sorted(obs) == ["depth", "mask"] and env.observation_space.contains(obs)
    assert obs["mask"].dtype == np.uint8 and np.array_equal(obs["mask"][..., 0].astype(bool), info["mask"])


def test_observations_without_rgb_are_rendered_without_colour() -> None:
    """mask + depth asks the simulator for colour-free frames, with the depth and mask of the
    colour frames an rgb observation gets (same seed, same actions)."""
    world = FakeWorld()
    renderers = [FakeRenderer(world, size=32) for _ in range(2)]
    envs = [
        RowFollowEnv(None, config=_config(), world=world, renderer=r, obs_keys=keys)
        for r, keys in zip(renderers, [("rgb", "depth", "mask"), ("mask", "depth")])
    ]
    observations = [env.reset(seed=3)[0] for env in envs]
    for _ in range(4):
        assert np.array_equal(observations[0]["depth"], observations[1]["depth"])
        assert np.array_equal(observations[0]["mask"], observations[1]["mask"])
        observations = [env.step(np.array([0.4, 0.05]))[0] for env in envs]
    assert renderers[0].colour_calls == renderers[0].calls == 5 and renderers[1].colour_calls == 0


def test_a_shipped_model_name_gives_its_mask_of_each_colour_frame(exported, tmp_path, monkeypatch) -> None:
    """model="vineyards" (here the tiny exported model released under that name) adds `model_mask`,
    the runtime's segmentation of the frame the env renders, beside the oracle's `mask`."""
    import shutil

    from segmin.nav_eval.runtime.segmenter import OnnxSegmenter
    from segmin.nav_eval.runtime.shipped_models import ENV_MODELS_DIR

    monkeypatch.setenv(ENV_MODELS_DIR, str(tmp_path))
    shutil.copy(exported[0], tmp_path / "vineyards.onnx")
    world = FakeWorld()
    env = RowFollowEnv(None, config=_config(), world=world, renderer=FakeRenderer(world, size=32), model="vineyards")
    assert env.obs_keys == ("rgb", "depth", "t", "attitude", "model_mask")
    check_env(env, skip_render_check=True)
    reference = OnnxSegmenter(exported[0])
    obs, _ = env.reset(seed=4)
    for _ in range(3):
        assert obs["model_mask"].dtype == np.uint8 and env.observation_space.contains(obs)
        assert np.array_equal(obs["model_mask"][..., 0], reference.segment(obs["rgb"]).astype(np.uint8))
        assert 0 < obs["model_mask"].mean() < 1  # a mask with content: the comparison can tell frames apart
        obs, *_ = env.step(np.array([0.4, 0.0]))
    masks_only = RowFollowEnv(
        None,
        config=_config(),
        world=world,
        renderer=FakeRenderer(world, size=32),
        model=exported[0],
        obs_keys=("model_mask", "mask"),
    )
    obs, _ = masks_only.reset(seed=4)
    assert sorted(obs) == ["mask", "model_mask"] and masks_only.simulator.renderer.colour_calls == 1


@pytest.mark.parametrize(
    ("option", "message"),
    [
        ({"obs_keys": ("model_mask", "depth")}, "obs_keys: 'model_mask' needs model="),
        ({"model": "vineyards", "obs_keys": ("rgb", "depth")}, "model: given, but obs_keys has no 'model_mask'"),
        ({"model": "apples"}, "apples"),
    ],
)
def test_a_model_option_that_cannot_work_is_refused_by_name(option: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RowFollowEnv("straight_vineyard", overrides=TINY, **option)


@pytest.mark.parametrize(
    ("option", "message"),
    [
        ({"obs_keys": ("rgb", "colour")}, "obs_keys"),
        ({"obs_keys": ()}, "obs_keys"),
        ({"obs_keys": ("depth", "depth")}, "obs_keys"),
        ({"size": 0}, "size"),
        ({"size": (32, 32, 3)}, "size"),
        ({"size": "small"}, "size"),
    ],
)
def test_bad_observation_options_are_refused_by_name(option: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RowFollowEnv("straight_vineyard", overrides=TINY, **option)


def _rollout(env, seed: int, steps: int = 3) -> list[dict]:
    obs, _ = env.reset(seed=seed)
    frames = [obs]
    for _ in range(steps):
        obs, *_ = env.step(np.tile([0.4, 0.05], (env.num_envs, 1)))
        frames.append(obs)
    return frames


def test_make_vec_sync_and_async_agree_and_seed_each_env() -> None:
    """Sub-env i is reset with seed + i (Gymnasium's vector rule): distinct start poses, the same
    ones again for the same seed, and the same in an async vector (a process and a pybullet client per env) as in sync."""
    options = {"overrides": TINY, "obs_keys": ("mask", "depth", "attitude"), "size": (24, 32)}
    sync = gymnasium.make_vec("segmin/RowFollow-v0", num_envs=2, vectorization_mode="sync", **options)
    first, again = _rollout(sync, seed=7), _rollout(sync, seed=7)
    sync.close()
    # Spawned: this process has rendered with gl (the default backend), and OpenGL does not survive a fork.
    vec = gymnasium.make_vec(
        "segmin/RowFollow-v0", num_envs=2, vectorization_mode="async", vector_kwargs={"context": "spawn"}, **options
    )
    try:
        assert vec.observation_space.contains(first[0]) and vec.single_observation_space["mask"].shape == (24, 32, 1)
        from_async = _rollout(vec, seed=7)
    finally:
        vec.close()
    assert not np.array_equal(first[0]["attitude"][0], first[0]["attitude"][1])  # distinct seeds
    for a, b, c in zip(first, again, from_async, strict=True):
        for key in a:
            assert np.array_equal(a[key], b[key]) and np.array_equal(a[key], c[key]), key


def test_bench_gym_times_a_vector_and_tabulates_against_the_single_env_and_the_first_backend() -> None:
    from benchmarks.gym import GymBenchRow, format_gym_rows, time_env

    rate = time_env("sync", 2, ("mask", "depth"), 16, 3, "straight_vineyard", backend="gl")
    table = format_gym_rows(
        [
            GymBenchRow("single", 1, "mask+depth", 16, rate / 4, "tiny"),
            GymBenchRow("single", 1, "mask+depth", 16, rate / 2, "gl"),
            GymBenchRow("sync", 2, "mask+depth", 16, rate, "gl"),
        ]
    )
    assert rate > 0 and "| mask+depth | 16 | gl | sync | 2 |" in table
    assert "| mask+depth | 16 | gl | single | 1 |" in table and "| 1.00 | 2.00 |" in table  # x single, x tiny
    assert "| 2.00 | n/a |" in table  # no tiny vector was timed


def test_bench_gym_names_a_bad_backend(capsys) -> None:
    from benchmarks.cli import main

    assert main(["gym", "--backends", "vulkan"]) == 2
    assert "--backends vulkan" in capsys.readouterr().err
