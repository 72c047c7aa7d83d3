"""`RowFollowEnv`: the closed-loop world as a Gymnasium env (`segmin/RowFollow-v0`).

One step is one camera frame: the action (v, omega) is held for 1 / camera_hz seconds of
simulated time (the robot integrates at physics_hz and the end conditions are checked at every
physics tick), and the observation is the next camera frame.

- observation: Dict(rgb uint8 H x W x 3, depth float32 H x W metres (0 = no reading), t float64
  seconds, attitude float64 (roll, pitch) radians: the IMU, REP 103), what
  `nav_eval.runtime.RowFollower.step` takes;
- action: Box([-max_v, -max_omega], [max_v, max_omega]) float64, the robot's hardware limits
  (float64 so a command reaches the robot unrounded);
- reward: progress along the row's centreline during the step, in metres (negative when the
  robot backs up), so the return of a run is the distance it covered along the row;
- terminated: "success" (goal distance covered), "collision", "left_row"; truncated: "timeout"
  (run.time_limit_s) and "stalled" (no progress over run.stall_time_s), which say nothing
  about the state itself;
- info: t, s (progress), lateral error, pose (x, y, yaw, ground truth), reason, the oracle
  (exact) vegetation mask of the frame, and `rendered`.

`reset(seed=..., options={"pose": (x, y, yaw)})` replaces the seeded start pose. A run's start
noise and depth noise depend on its seed only. `close()` disconnects the pybullet client.

Rendering is the cost of a step. A caller that knows it will not use the next frame (the
runtime's `needs_frame`) sets `skip_next_render = True`: the next observation then holds
zero images and `info["rendered"]` is False. nav-eval uses it to render only the frames the
runtime segments; the frames it does render, and their noise, are then the same.

Registered as `segmin/RowFollow-v0` when this module is imported (it imports gymnasium, not
pybullet: the field is built in `__init__`):

    import gymnasium, segmin.nav_eval.sim.gym_env
    env = gymnasium.make("segmin/RowFollow-v0", field="straight_vineyard")
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces

from segmin.nav_eval.sim.config import NavEvalConfig, load_nav_config
from segmin.nav_eval.sim.row_env import RowEnv

ENV_ID = "segmin/RowFollow-v0"
TERMINAL = ("success", "collision", "left_row")
TRUNCATING = ("timeout", "stalled")


class RowFollowEnv(gymnasium.Env):
    """A robot in one row gap of a field (shipped name or world spec YAML)."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(
        self,
        field: str | None = "straight_vineyard",
        *,
        config: NavEvalConfig | str | None = None,
        overrides: list[str] | tuple[str, ...] = (),
        gap: int | None = None,
        world: Any = None,
        renderer: Any = None,
    ) -> None:
        """`config`: a NavEvalConfig, a config name/path, or None (the shipped default) plus
        `overrides` (key=value). `world` + `renderer` replace the field (tests, custom worlds)."""
        if not isinstance(config, NavEvalConfig):
            config = load_nav_config(config, list(overrides))
        elif overrides:
            raise ValueError("overrides apply to a config name or path, not to a NavEvalConfig")
        self.config = config
        self._context = None
        if world is None:
            if field is None:
                raise ValueError("give a field (name or world spec YAML) or a world and a renderer")
            from segmin.nav_eval.sim.factories import FieldContext

            self._context = FieldContext(field, config)
            world, renderer = self._context.world, self._context.renderer
            gap = self._context.gap if gap is None else gap
        elif renderer is None:
            raise ValueError("a world needs its renderer")
        self.field = field
        self.row = RowEnv(world, renderer, config, gap=gap)
        self.depth_threshold = (
            self._context.depth_threshold
            if self._context is not None
            else config.depth_threshold(world.spec.name, world.spec.family)
        )
        height, width = self._camera_size(renderer)
        robot = config.robot
        self.observation_space = spaces.Dict(
            {
                "rgb": spaces.Box(0, 255, (height, width, 3), dtype=np.uint8),
                "depth": spaces.Box(0.0, np.inf, (height, width), dtype=np.float32),
                "t": spaces.Box(0.0, np.inf, (), dtype=np.float64),
                "attitude": spaces.Box(-np.pi / 2, np.pi / 2, (2,), dtype=np.float64),
            }
        )
        self.action_space = spaces.Box(
            np.array([-robot.max_v, -robot.max_omega]), np.array([robot.max_v, robot.max_omega]), dtype=np.float64
        )
        self.skip_next_render = False
        self._s = 0.0

    def _camera_size(self, renderer: Any) -> tuple[int, int]:
        camera = getattr(renderer, "camera", None)
        if camera is not None:
            return int(camera.height), int(camera.width)
        size = getattr(renderer, "size", None)
        if size is not None:
            return int(size), int(size)
        frame = renderer.render(*self.row.centreline[0], 0.0, rng=None, noisy_depth=False)
        return tuple(np.asarray(frame.depth).shape[:2])

    @property
    def camera_period(self) -> float:
        """Seconds between two observations."""
        return 1.0 / self.config.rates.camera_hz

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        run_seed = int(seed) if seed is not None else int(self.np_random.integers(0, 2**63 - 1))
        options = dict(options or {})
        pose = options.pop("pose", None)
        if options:
            raise ValueError(f"reset options: unknown {sorted(options)}; allowed: ['pose']")
        info = self.row.reset(run_seed, None if pose is None else tuple(float(v) for v in pose))
        self._s = info["s"]
        self.skip_next_render = False
        return self._observe(info)

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (2,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be two finite numbers (v, omega), got {action!r}")
        _, info = self.row.step((float(a[0]), float(a[1])))
        reward = float(info["s"] - self._s)
        self._s = info["s"]
        obs, info = self._observe(info)
        reason = info["reason"]
        return obs, reward, reason in TERMINAL, reason in TRUNCATING, info

    def _observe(self, info: dict[str, Any]) -> tuple[dict, dict]:
        space = self.observation_space
        info = dict(info, pose=self.row.pose, rendered=not self.skip_next_render, mask=None)
        if self.skip_next_render:
            rgb = np.zeros(space["rgb"].shape, dtype=np.uint8)
            depth = np.zeros(space["depth"].shape, dtype=np.float32)
        else:
            frame = self.row.frame()
            rgb = np.asarray(frame.rgb, dtype=np.uint8)
            depth = np.asarray(frame.depth, dtype=np.float32)
            info["mask"] = np.asarray(frame.mask, dtype=bool)
        self.skip_next_render = False
        return {
            "rgb": rgb,
            "depth": depth,
            "t": np.array(self.row.t, dtype=np.float64),
            "attitude": np.array(self.row.attitude, dtype=np.float64),
        }, info

    def close(self) -> None:
        if self._context is not None:
            self._context.close()
            self._context = None
        super().close()


def register_env() -> None:
    """Register `segmin/RowFollow-v0` (idempotent)."""
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="segmin.nav_eval.sim.gym_env:RowFollowEnv")


register_env()
