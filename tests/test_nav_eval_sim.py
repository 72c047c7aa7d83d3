"""The closed loop on an analytic stand-in world (no pybullet): timing, end conditions, determinism.

The stand-in renders trunks as upright boxes of the right width and height into a pinhole
camera (z-buffered, column ranges), which is all SegMin needs to steer down a row gap. The real
synth worlds are exercised in test_nav_eval_fields.py.
"""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from segmin.data.synth.camera import CameraModel
from segmin.nav_eval.evaluation.rollout import run_episode
from segmin.nav_eval.runtime.follower import RowFollower
from segmin.nav_eval.runtime.navigator import Command, Navigator, NavigatorConfig
from segmin.nav_eval.sim.config import NavEvalConfig, Perception, Rates, RunSettings
from segmin.nav_eval.sim.factories import make_follower
from segmin.nav_eval.sim.oracle import OracleSegmenter
from segmin.nav_eval.sim.row_env import RowEnv


@dataclasses.dataclass
class Frame:
    rgb: np.ndarray | None
    depth: np.ndarray
    mask: np.ndarray
    camera_pose: tuple


class FakeWorld:
    """Four straight vine rows 1.8 m apart along +x (the gap between the middle two), flat ground."""

    canopy_half_width = 0.25

    def __init__(self, length: float = 12.0, spacing: float = 1.8, plant_step: float = 0.6) -> None:
        xs = np.arange(0.0, length + 6.0, plant_step)
        rows = [-1.5 * spacing, -spacing / 2, spacing / 2, 1.5 * spacing]
        self.plant_circles = np.array([[x, y, 0.05] for y in rows for x in xs])
        self.obstacle_circles = np.zeros((0, 3))
        cx = np.arange(0.0, length + 0.01, 0.25)
        self.centrelines = [np.stack([cx, np.zeros_like(cx)], 1)]
        self.gap_half_widths = [spacing / 2 - 0.1]
        self.spec = SimpleNamespace(name="fake", family="vineyards", terrain=SimpleNamespace(roughness=0.0))

    def terrain_height(self, x, y):
        return 0.0 * np.asarray(x, dtype=float)

    def terrain_normal(self, x, y):
        return np.array([0.0, 0.0, 1.0])


class FakeRenderer:
    """Pinhole camera 0.2 m ahead of the robot; each vine a 0.5 m wide, 1.5 m tall box of leaves, on
    flat ground under a sky (which returns no depth)."""

    def __init__(self, world: FakeWorld, size: int = 48, hfov_deg: float = 69.0) -> None:
        self.world, self.size = world, size
        self.f = (size / 2) / math.tan(math.radians(hfov_deg) / 2)
        # Its size for the simulator; noise-free depth (the stand-in has no sensor model).
        self.camera = CameraModel(width=size, height=size, hfov_deg=hfov_deg, depth_noise_enabled=False)
        self.calls = self.colour_calls = 0

    def render(self, x, y, yaw, *, rng=None, noisy_depth=False, pose_offset=None, colour=True) -> Frame:
        self.calls += 1
        self.colour_calls += colour
        n = self.size
        cx, cy = x + 0.2 * math.cos(yaw), y + 0.2 * math.sin(yaw)
        depth = np.full((n, n), np.inf, dtype=np.float32)
        # Flat ground below the horizon (the level camera 0.4 m up), as a depth camera sees it;
        # no return from the sky.
        below = np.arange(n) + 0.5 - n / 2
        depth[below > 0] = (0.4 * self.f / below[below > 0])[:, None]
        mask = np.zeros((n, n), dtype=bool)
        r = self.world.canopy_half_width
        for px, py, _ in self.world.plant_circles:
            dx, dy = px - cx, py - cy
            fwd = math.cos(yaw) * dx + math.sin(yaw) * dy
            left = -math.sin(yaw) * dx + math.cos(yaw) * dy
            if fwd < 0.3:
                continue
            u0 = int(np.floor(n / 2 - self.f * (left + r) / fwd))
            u1 = int(np.ceil(n / 2 - self.f * (left - r) / fwd))
            top = int(np.floor(n / 2 - self.f * (1.5 - 0.4) / fwd))
            bottom = int(np.ceil(n / 2 + self.f * 0.4 / fwd))
            u0, u1, top, bottom = max(u0, 0), min(u1, n), max(top, 0), min(bottom, n)
            if u0 >= u1 or top >= bottom:
                continue
            region = depth[top:bottom, u0:u1]
            closer = fwd < region
            region[closer] = fwd
            mask[top:bottom, u0:u1] |= closer
        mask &= np.isfinite(depth)
        ground = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
        if noisy_depth and rng is not None:
            ground = ground + rng.normal(0, 0.01, ground.shape).astype(np.float32) * (ground > 0)
        rgb = np.empty((n, n, 3), dtype=np.uint8)
        rgb[below > 0] = (110, 85, 60)  # brown ground under a pale sky: no camera sees black there
        rgb[below <= 0] = (135, 150, 200)
        rgb[mask] = (40, 160, 40)
        return Frame(rgb if colour else None, ground, mask, (cx, cy, yaw))


def _config(**run) -> NavEvalConfig:
    settings = dict(length_m=8.0, time_limit_s=40.0)
    settings.update(run)
    return NavEvalConfig(rates=Rates(), perception=Perception(width=48, height=48), run=RunSettings(**settings))


def _run(method: str = "segmin", seed: int = 3, **run):
    world = FakeWorld()
    config = _config(**run)
    renderer = FakeRenderer(world)
    simulator = RowEnv(world, renderer, config)
    return run_episode(simulator, make_follower(method, 5.0, config), OracleSegmenter(), seed), renderer, simulator


def test_oracle_run_succeeds_on_the_stand_in_row() -> None:
    episode, renderer, _env = _run()
    assert episode.reason == "success", episode.reason
    assert episode.clearance_time == pytest.approx(episode.trajectory.t[-1])
    assert 8.0 / 0.5 < episode.clearance_time < 40.0
    # Rendering schedule: 3 of every 4 segmentation ticks per 0.2 s command period = 15 frames/s.
    assert renderer.calls == pytest.approx(15 * episode.clearance_time, abs=4)
    # Commands at 5 Hz, robot samples at 60 Hz.
    assert len(episode.commands) == pytest.approx(5 * episode.clearance_time, abs=2)
    assert np.allclose(np.diff(episode.trajectory.t), 1 / 60)
    assert np.max(np.abs(episode.trajectory.y)) < 0.4


@pytest.mark.parametrize("method", ["segmind", "segcorridor"])
def test_the_oracle_renders_colour_only_for_a_navigator_that_reads_it(method: str) -> None:
    """The oracle reads masks, SegMinD depth: their frames come without colour; SegCorridor
    declares rgb (its trunk test), so its frames have it. The runs are the same either way."""
    episode, renderer, _env = _run(method, length_m=2.0)
    assert renderer.calls > 10 and episode.reason == "success"
    assert renderer.colour_calls == (renderer.calls if method == "segcorridor" else 0)
    world, config = FakeWorld(), _config(length_m=2.0)
    follower = make_follower(method, 5.0, config)
    with_colour = _ColourReader()
    same = run_episode(RowEnv(world, FakeRenderer(world), config), follower, with_colour, 3)
    assert np.array_equal(same.trajectory.x, episode.trajectory.x) and with_colour.images == renderer.calls


class _ColourReader(OracleSegmenter):
    """The oracle, declaring (and checking) that it reads each frame's image."""

    reads_colour = True

    def __init__(self) -> None:
        self.images = 0

    def segment_frame(self, frame) -> np.ndarray:
        assert frame.rgb is not None
        self.images += 1
        return super().segment_frame(frame)


def test_frames_render_on_demand_at_the_current_pose() -> None:
    world = FakeWorld()
    renderer = FakeRenderer(world)
    env = RowEnv(world, renderer, _config())
    env.reset(seed=0)
    assert renderer.calls == 0
    first = env.frame()
    assert env.frame() is first and renderer.calls == 1  # cached until the robot moves
    ended, info = env.step((0.4, 0.0))
    assert not ended and env.tick == 2 and info["t"] == pytest.approx(2 / 60)  # one camera period
    assert env.frame() is not first and renderer.calls == 2


def test_a_frame_without_colour_keeps_its_depth_when_colour_is_asked_later() -> None:
    """Depth noise is drawn once a tick: a colour-free frame, then colour at the same tick, gives
    the frames of a run that asked colour from the start (same depth, same image)."""
    world = FakeWorld()
    config = dataclasses.replace(_config(), perception=Perception(width=48, height=48, depth_noise=True))
    with_colour, without = FakeRenderer(world), FakeRenderer(world)
    with_colour.camera = without.camera = CameraModel(width=48, height=48)  # the sensor's depth noise on
    runs = [RowEnv(world, r, config) for r in (with_colour, without)]
    for env in runs:
        env.reset(seed=5)
    for _ in range(3):
        bare = runs[1].frame(colour=False)
        assert bare.rgb is None
        full, later = runs[0].frame(), runs[1].frame()
        assert np.array_equal(full.depth, later.depth) and np.array_equal(full.rgb, later.rgb)
        assert later.depth is bare.depth and np.any(later.depth != 0)
        for env in runs:
            env.step((0.4, 0.0))
    assert without.calls == 6 and without.colour_calls == 3


def test_same_seed_same_trajectory_and_seeded_start() -> None:
    a, _, _ = _run(seed=11)
    b, _, _ = _run(seed=11)
    c, _, _ = _run(seed=12)
    assert np.array_equal(a.trajectory.x, b.trajectory.x) and np.array_equal(a.trajectory.y, b.trajectory.y)
    assert a.start_pose != c.start_pose
    for ep in (a, c):
        assert abs(ep.start_pose[1]) <= 0.15 and abs(ep.start_pose[2]) <= math.radians(5) + 1e-12


class _Straight(Navigator):
    """A navigator that ignores the camera and commands a fixed (v, omega)."""

    def __init__(self, v: float, omega: float) -> None:
        super().__init__(NavigatorConfig(method="segmin", depth_threshold=5.0))
        self.v, self.omega = v, omega

    def command(self, fused, depth, attitude=None, rgb=None) -> Command:
        return Command(v=self.v, omega=self.omega, target_column=None, histogram=np.zeros(0), valid=True)


def _drive(config: NavEvalConfig, navigator: Navigator):
    world = FakeWorld()
    simulator = RowEnv(world, FakeRenderer(world), config)
    return run_episode(simulator, RowFollower(None, navigator), OracleSegmenter(), seed=0)


def test_driving_into_the_row_is_a_collision_and_standing_still_stalls() -> None:
    config = _config(start_lateral_max=0.0, start_heading_max_deg=0.0)
    ep = _drive(config, _Straight(0.4, 0.6))
    assert ep.reason == "collision" and ep.collisions == 1 and not ep.success
    assert math.isnan(ep.clearance_time or math.nan)
    config = _config(stall_time_s=3.0, time_limit_s=10.0)
    ep = _drive(config, _Straight(0.0, 0.0))
    assert ep.reason == "stalled" and 3.0 <= ep.trajectory.t[-1] < 3.5


@pytest.mark.parametrize(
    ("sampling", "backend", "expected"),
    [("auto", "gl", "field"), ("auto", "tiny", "pixels"), ("pixels", "gl", "pixels"), ("field", "tiny", "field")],
)
def test_the_camera_samples_depth_noise_as_the_config_and_backend_say(sampling, backend, expected) -> None:
    from segmin.nav_eval.sim.config import load_nav_config
    from segmin.nav_eval.sim.factories import nav_camera

    config = load_nav_config(overrides=[f"perception.depth_noise_sampling={sampling}", "perception.width=64"])
    camera = nav_camera(config, backend)
    assert (camera.depth_noise_sampling, camera.width) == (expected, 64)


def test_an_unknown_depth_noise_sampling_is_refused_by_name() -> None:
    from segmin.nav_eval.sim.config import load_nav_config

    with pytest.raises(ValueError, match="perception.depth_noise_sampling"):
        load_nav_config(overrides=["perception.depth_noise_sampling=texture"])
