"""`RowFollowEnv`: the simulator as a Gymnasium env (`segmin/RowFollow-v0`), a thin adapter.

One step is one camera frame: the action (v, omega) is held for 1 / camera_hz seconds of
simulated time (the robot integrates at physics_hz and the end conditions are checked at every
physics tick), and the observation is the next camera frame. The simulator itself
(`nav_eval.sim.row_env.RowEnv`) is `env.simulator`.

- observation: Dict(rgb uint8 H x W x 3, depth float32 H x W metres (0 = no reading), t float64
  seconds, attitude float64 (roll, pitch) radians: the IMU, REP 103), what
  `nav_eval.runtime.RowFollower.step` takes. `obs_keys` picks the entries (also `mask`, the
  oracle vegetation mask as uint8 0/1, for learning from masks; `model_mask`, the mask a
  segmentation model makes of the colour frame, with `model`) and `size` the camera's
  (height, width): a learner that wants mask + depth at the model's size renders fewer pixels and
  no colour (without `rgb` the frame is asked without colour: the gl backend then draws depth and
  body ids only, and no backend composes sky or exposure; TinyRenderer has no depth-only pass);
- model: a shipped model name (`"vineyards"`, `"trees"`) or an exported ONNX file: the env then
  observes `model_mask`, the mask the robot would act on, so a controller can be trained or
  tested on a model's errors instead of the oracle's exact mask;
- action: Box([-max_v, -max_omega], [max_v, max_omega]) float64, the robot's hardware limits
  (float64 so a command reaches the robot unrounded);
- reward: progress along the row's centreline during the step, in metres (negative when the
  robot backs up), so the return of a run is the distance it covered along the row;
- terminated: "success" (goal distance covered), "collision", "left_row"; truncated: "timeout"
  (run.time_limit_s) and "stalled" (no progress over run.stall_time_s), which say nothing
  about the state itself;
- info: t, s (progress), lateral error, pose (x, y, yaw, ground truth), reason, and the oracle
  (exact) vegetation mask of the frame.

`reset(seed=..., options={"pose": (x, y, yaw)})` replaces the seeded start pose, which must be
finite and inside the row gap (`RowEnv.check_pose`). A run's start noise and depth noise depend on
its seed only. `close()` disconnects the pybullet client; a closed env refuses `reset` and `step`.

Every step renders its frame: that is what an observation is. nav-eval, which renders only the
frames the robot runtime segments, drives the simulator directly (`nav_eval.evaluation.rollout`).

Registered by `segmin.envs` (which imports gymnasium, not pybullet or this module: the field is
built when the env is made):

    import gymnasium, segmin.envs
    env = gymnasium.make("segmin/RowFollow-v0", field="straight_vineyard")
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces

import segmin.envs  # noqa: F401  (registers segmin/RowFollow-v0 for code that imports only this module)
from segmin.nav_eval.sim.config import NavEvalConfig, load_nav_config
from segmin.nav_eval.sim.protocols import SimRenderer, SimWorld
from segmin.nav_eval.sim.row_env import RowEnv

if TYPE_CHECKING:
    from segmin.nav_eval.runtime.segmenter import OnnxSegmenter

TERMINAL = ("success", "collision", "left_row")
TRUNCATING = ("timeout", "stalled")
OBS_KEYS = ("rgb", "depth", "mask", "model_mask", "t", "attitude")
"""Every observation entry `obs_keys` can pick."""
DEFAULT_OBS_KEYS = ("rgb", "depth", "t", "attitude")
"""What `RowFollower.step` takes: the default observation (with a `model`, also `model_mask`)."""


def check_obs_keys(obs_keys: Sequence[str] | None, model: str | os.PathLike[str] | None) -> tuple[str, ...]:
    """`obs_keys` as a tuple (None: the default for whether there is a `model`), or a ValueError
    naming the option: some of OBS_KEYS, each once, `model_mask` exactly when a model is given."""
    if obs_keys is None:
        return (*DEFAULT_OBS_KEYS, "model_mask") if model is not None else DEFAULT_OBS_KEYS
    keys = (obs_keys,) if isinstance(obs_keys, str) else tuple(obs_keys)
    unknown = [k for k in keys if k not in OBS_KEYS]
    if not keys or unknown or len(set(keys)) != len(keys):
        raise ValueError(f"obs_keys: {list(keys)!r} is not a non-empty list of distinct keys of {list(OBS_KEYS)}")
    if ("model_mask" in keys) != (model is not None):
        raise ValueError(
            "obs_keys: 'model_mask' needs model= (a shipped name or an ONNX file)"
            if model is None
            else "model: given, but obs_keys has no 'model_mask' to observe its mask in"
        )
    return keys


def check_size(size: int | Sequence[int]) -> tuple[int, int]:
    """`size` (one side, or height and width) as (height, width), or a ValueError naming it."""
    sides = [size] if isinstance(size, int | np.integer) else list(size) if isinstance(size, Sequence) else []
    if len(sides) == 1:
        sides *= 2
    if len(sides) != 2 or not all(isinstance(n, int | np.integer) and 8 <= n <= 4096 for n in sides):
        raise ValueError(f"size: {size!r} must be one side or (height, width), whole pixels from 8 to 4096")
    return int(sides[0]), int(sides[1])


class RowFollowEnv(gymnasium.Env):
    """A robot in one row gap of a field (shipped name or world spec YAML)."""

    # gymnasium.make reads it from the class, but gymnasium's Env annotates it per instance (its
    # wrappers turn it into a property).
    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}  # type: ignore[misc]

    def __init__(
        self,
        field: str | None = "straight_vineyard",
        *,
        config: NavEvalConfig | str | None = None,
        overrides: list[str] | tuple[str, ...] = (),
        gap: int | None = None,
        world: SimWorld | None = None,
        renderer: SimRenderer | None = None,
        obs_keys: Sequence[str] | None = None,
        size: int | Sequence[int] | None = None,
        model: str | os.PathLike[str] | None = None,
    ) -> None:
        """`config`: a NavEvalConfig, a config name/path, or None (the shipped default) plus
        `overrides` (key=value). `world` + `renderer` replace the field (tests, custom worlds).
        `obs_keys`: the observation's entries (of OBS_KEYS; default DEFAULT_OBS_KEYS, plus
        `model_mask` with a model); `size`: the camera's side or (height, width) in pixels,
        replacing perception.width / height (a field's camera only); `model`: a shipped model name
        or an ONNX file whose mask of each colour frame is `model_mask` (2 onnxruntime threads)."""
        self.obs_keys = check_obs_keys(obs_keys, model)
        self.segmenter: OnnxSegmenter | None = None
        if model is not None:  # loaded first: a bad name fails before the field is built
            from segmin.nav_eval.runtime.segmenter import OnnxSegmenter

            self.segmenter = OnnxSegmenter(model)
        if isinstance(config, NavEvalConfig):
            if overrides:
                raise ValueError("overrides apply to a config name or path, not to a NavEvalConfig")
            nav_config = config
        else:
            nav_config = load_nav_config(config, list(overrides))
        if size is not None:
            if world is not None:
                raise ValueError("size sets a field's camera; a given renderer keeps its own")
            height, width = check_size(size)
            nav_config = dataclasses.replace(
                nav_config, perception=dataclasses.replace(nav_config.perception, width=width, height=height)
            )
        self.config = nav_config
        self._context = None
        if world is None:
            if field is None:
                raise ValueError("give a field (name or world spec YAML) or a world and a renderer")
            from segmin.nav_eval.sim.factories import FieldContext

            self._context = FieldContext(field, nav_config)
            world, renderer = self._context.world, self._context.renderer
            gap = self._context.gap if gap is None else gap
        elif renderer is None:
            raise ValueError("a world needs its renderer")
        self.field = field
        self.simulator = RowEnv(world, renderer, nav_config, gap=gap)
        self.depth_threshold = nav_config.depth_threshold(world.spec.name, world.spec.family)
        self._closed = False
        height, width = self.simulator.camera_size
        robot = nav_config.robot
        every: dict[str, spaces.Space] = {
            "rgb": spaces.Box(0, 255, (height, width, 3), dtype=np.uint8),
            "depth": spaces.Box(0.0, np.inf, (height, width), dtype=np.float32),
            "mask": spaces.Box(0, 1, (height, width), dtype=np.uint8),
            "model_mask": spaces.Box(0, 1, (height, width), dtype=np.uint8),
            "t": spaces.Box(0.0, np.inf, (), dtype=np.float64),
            "attitude": spaces.Box(-np.pi / 2, np.pi / 2, (2,), dtype=np.float64),
        }
        self.observation_space = spaces.Dict({key: every[key] for key in self.obs_keys})
        self.action_space = spaces.Box(
            np.array([-robot.max_v, -robot.max_omega]), np.array([robot.max_v, robot.max_omega]), dtype=np.float64
        )
        self._s = 0.0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        self._refuse_if_closed("reset")
        super().reset(seed=seed)
        run_seed = int(seed) if seed is not None else int(self.np_random.integers(0, 2**63 - 1))
        if options is not None and not isinstance(options, Mapping):  # dict([1, 2]) would fail naming nothing
            raise TypeError(f"reset options must be a dict such as {{'pose': (x, y, yaw)}} or None, got {options!r}")
        options = dict(options or {})
        pose = options.pop("pose", None)
        if options:
            raise ValueError(f"reset options: unknown {sorted(options)}; allowed: ['pose']")
        if pose is not None:
            pose = self.simulator.check_pose(pose, "options['pose']")
        info = self.simulator.reset(run_seed, pose)
        self._s = info["s"]
        return self._observe(info)

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        self._refuse_if_closed("step")
        try:
            a = np.asarray(action, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):  # a string, a ragged list: not two numbers
            a = np.empty(0)
        if a.shape != (2,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be two finite numbers (v, omega), got {action!r}")
        _, info = self.simulator.step((float(a[0]), float(a[1])))
        reward = float(info["s"] - self._s)
        self._s = info["s"]
        obs, info = self._observe(info)
        reason = info["reason"]
        return obs, reward, reason in TERMINAL, reason in TRUNCATING, info

    def _observe(self, info: dict[str, Any]) -> tuple[dict, dict]:
        frame = self.simulator.frame(colour="rgb" in self.obs_keys or self.segmenter is not None)
        mask = np.asarray(frame.mask, dtype=bool)
        info = dict(info, pose=self.simulator.pose, mask=mask)
        entries: dict[str, Callable[[], np.ndarray]] = {  # only the asked entries are converted
            "rgb": lambda: np.asarray(frame.rgb, dtype=np.uint8),
            "depth": lambda: np.asarray(frame.depth, dtype=np.float32),
            "mask": lambda: mask.view(np.uint8),
            "model_mask": lambda: self._model_mask(frame.rgb),
            "t": lambda: np.array(self.simulator.t, dtype=np.float64),
            "attitude": lambda: np.array(self.simulator.attitude, dtype=np.float64),
        }
        return {key: entries[key]() for key in self.obs_keys}, info

    def _model_mask(self, rgb: np.ndarray) -> np.ndarray:
        """The model's vegetation mask of the frame, uint8 0/1 at the camera's size."""
        assert self.segmenter is not None  # check_obs_keys: model_mask is asked only with a model
        return self.segmenter.segment(np.asarray(rgb, dtype=np.uint8)).view(np.uint8)

    def _refuse_if_closed(self, call: str) -> None:
        if self._closed:
            raise RuntimeError(f"{call}() on a closed RowFollowEnv: close() released its simulator; make a new env")

    def close(self) -> None:
        self._closed = True
        if self._context is not None:
            self._context.close()
            self._context = None
        super().close()
