"""`RowFollowEnv`: the simulator as a Gymnasium env (`segmin/RowFollow-v0`), a thin adapter.

One step is one camera frame: the action (v, omega) is held for 1 / camera_hz seconds of
simulated time (the robot integrates at physics_hz and the end conditions are checked at every
physics tick), and the observation is the next camera frame. The simulator itself
(`nav_eval.sim.row_env.RowEnv`) is `env.simulator`.

- observation: Dict(rgb uint8 H x W x 3, depth float32 H x W x 1 metres (0 = no reading), t
  float64 shape (1,) seconds, attitude float64 (roll, pitch) radians: the IMU, REP 103), what
  `nav_eval.runtime.RowFollower.step` takes, shaped as RL libraries expect (images H x W x C,
  scalars as shape-(1,) boxes: Stable-Baselines3's `check_env` and `MultiInputPolicy` take it
  as it is). `legacy_observation=True` keeps the shapes of the previous release (depth and
  masks H x W, t 0-d, float64 actions) for one more release. `obs_keys` picks the entries (also
  `mask`, the oracle vegetation mask as uint8 0/1 H x W x 1, for learning from masks;
  `model_mask`, the mask a segmentation model makes of the colour frame, with `model`) and
  `size` the camera's (height, width): a learner that wants mask + depth at the model's size renders fewer pixels and
  no colour (without `rgb` the frame is asked without colour: the gl backend then draws depth and
  body ids only, and no backend composes sky or exposure; TinyRenderer has no depth-only pass);
- model: a shipped model name (`"vineyards"`, `"trees"`) or an exported ONNX file: the env then
  observes `model_mask`, the mask the robot would act on, so a controller can be trained or
  tested on a model's errors instead of the oracle's exact mask;
- action: Box([-max_v, -max_omega], [max_v, max_omega]) float32, the robot's hardware limits
  (float32, the dtype RL libraries sample and cast to; a float64 action is still applied
  unrounded);
- reward: progress along the row's centreline during the step, in metres (negative when the
  robot backs up), so the return of a run is the distance it covered along the row;
- terminated: "success" (goal distance covered), "collision", "left_row"; truncated: "timeout"
  (run.time_limit_s) and "stalled" (no progress over run.stall_time_s), which say nothing
  about the state itself;
- info: t, s (progress), lateral error, pose (x, y, yaw, ground truth), reason, and the oracle
  (exact) vegetation mask of the frame;
- render_mode: "rgb_array" returns the camera frame with the observed mask (the model's with a
  `model`, else the oracle's) tinted and SegMin's target column on that mask drawn, the picture
  of nav-eval's videos (`nav_eval.replay.video.overlay`), so `gymnasium.wrappers.RecordVideo`
  records it; "human" shows it in an OpenCV window at every reset and step (where there is a
  display and OpenCV has a GUI; otherwise the env is refused in one line saying why).

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
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces

import segmin.envs  # noqa: F401  (registers segmin/RowFollow-v0 for code that imports only this module)
from segmin.nav_eval.replay.video import overlay
from segmin.nav_eval.runtime.navigator import target_column
from segmin.nav_eval.sim.config import NavEvalConfig, load_nav_config
from segmin.nav_eval.sim.human_view import FrameWindow, human_view_unavailable
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
RENDER_MODES = ("rgb_array", "human")
"""What `render_mode` can be (None: no rendering)."""
RENDER_TARGET_METHOD = "segmin"
"""The navigator whose target column the rendered frame shows: the paper's SegMin, on the mask
observed, as a reference for a learner's own steering."""
LEGACY_OBSERVATION_WARNING = (
    "legacy_observation=True: the previous release's observation shapes (depth and masks H x W, t 0-d, "
    "float64 actions) will be removed in the next release; use the default observation"
)


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


def observation_spaces(height: int, width: int, *, legacy: bool = False) -> dict[str, spaces.Space]:
    """The space of every entry of OBS_KEYS for a camera of `height` x `width`: images as
    H x W x C, scalars as shape-(1,) boxes; `legacy`: the previous release's shapes (H x W depth
    and masks, a 0-d t), which Stable-Baselines3 cannot flatten."""
    plane = (height, width) if legacy else (height, width, 1)
    return {
        "rgb": spaces.Box(0, 255, (height, width, 3), dtype=np.uint8),
        "depth": spaces.Box(0.0, np.inf, plane, dtype=np.float32),
        "mask": spaces.Box(0, 1, plane, dtype=np.uint8),
        "model_mask": spaces.Box(0, 1, plane, dtype=np.uint8),
        "t": spaces.Box(0.0, np.inf, () if legacy else (1,), dtype=np.float64),
        "attitude": spaces.Box(-np.pi / 2, np.pi / 2, (2,), dtype=np.float64),
    }


def check_render_mode(render_mode: str | None) -> str | None:
    """`render_mode` as given, or a ValueError naming it: one of RENDER_MODES or None, and
    "human" only where a window can open (`human_view_unavailable` says why not)."""
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode: {render_mode!r} is not one of {list(RENDER_MODES)} or None")
    if render_mode == "human":
        reason = human_view_unavailable()
        if reason is not None:
            raise ValueError(f"render_mode='human' cannot open a window: {reason}; use render_mode='rgb_array'")
    return render_mode


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

    # gymnasium.make reads it from the class (every mode it may pass on), but gymnasium's Env
    # annotates it per instance (its wrappers turn it into a property). An instance's own lists
    # the modes usable on this machine, with its camera's rate: Gymnasium's check_env makes the
    # env in each of them.
    metadata: ClassVar[dict[str, Any]] = {"render_modes": list(RENDER_MODES), "render_fps": 30}  # type: ignore[misc]

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
        render_mode: str | None = None,
        legacy_observation: bool = False,
    ) -> None:
        """`config`: a NavEvalConfig, a config name/path, or None (the shipped default) plus
        `overrides` (key=value). `world` + `renderer` replace the field (tests, custom worlds).
        `obs_keys`: the observation's entries (of OBS_KEYS; default DEFAULT_OBS_KEYS, plus
        `model_mask` with a model); `size`: the camera's side or (height, width) in pixels,
        replacing perception.width / height (a field's camera only); `model`: a shipped model name
        or an ONNX file whose mask of each colour frame is `model_mask` (2 onnxruntime threads);
        `render_mode`: None, "rgb_array" or "human" (module docstring); `legacy_observation`: the
        previous release's observation shapes, with a FutureWarning (a DeprecationWarning would
        stay hidden: the env is built inside gymnasium.make, not in the user's code)."""
        self.obs_keys = check_obs_keys(obs_keys, model)
        self.render_mode = check_render_mode(render_mode)
        self.legacy_observation = bool(legacy_observation)
        if self.legacy_observation:
            warnings.warn(LEGACY_OBSERVATION_WARNING, FutureWarning, stacklevel=2)
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
        every = observation_spaces(height, width, legacy=self.legacy_observation)
        self.observation_space = spaces.Dict({key: every[key] for key in self.obs_keys})
        action_dtype = np.dtype(np.float64 if self.legacy_observation else np.float32)
        limits = np.array([robot.max_v, robot.max_omega], dtype=action_dtype)
        self.action_space = spaces.Box(-limits, limits, dtype=action_dtype)
        usable = [mode for mode in RENDER_MODES if mode != "human" or human_view_unavailable() is None]
        self.metadata = {"render_modes": usable, "render_fps": nav_config.rates.camera_hz}  # type: ignore[misc]
        self._window = FrameWindow(f"segmin/RowFollow-v0: {field or world.spec.name}")
        self._view: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # rgb, mask, depth
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
        observed = self._observe(info)
        self._show_if_human()
        return observed

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
        self._show_if_human()
        reason = info["reason"]
        return obs, reward, reason in TERMINAL, reason in TRUNCATING, info

    def _observe(self, info: dict[str, Any]) -> tuple[dict, dict]:
        colour = "rgb" in self.obs_keys or self.segmenter is not None or self.render_mode is not None
        frame = self.simulator.frame(colour=colour)
        mask = np.asarray(frame.mask, dtype=bool)
        model_mask = None if self.segmenter is None else self._model_mask(frame.rgb)
        info = dict(info, pose=self.simulator.pose, mask=mask)
        if self.render_mode is not None:
            self._view = (frame.rgb, mask if model_mask is None else model_mask.view(bool), frame.depth)
        scalar_shape = () if self.legacy_observation else (1,)
        entries: dict[str, Callable[[], np.ndarray]] = {  # only the asked entries are converted
            "rgb": lambda: np.asarray(frame.rgb, dtype=np.uint8),
            "depth": lambda: self._plane(np.asarray(frame.depth, dtype=np.float32)),
            "mask": lambda: self._plane(mask.view(np.uint8)),
            "t": lambda: np.full(scalar_shape, self.simulator.t, dtype=np.float64),
            "attitude": lambda: np.array(self.simulator.attitude, dtype=np.float64),
        }
        if model_mask is not None:  # check_obs_keys: model_mask is asked exactly when there is a model
            entries["model_mask"] = lambda: self._plane(model_mask)
        return {key: entries[key]() for key in self.obs_keys}, info

    def _plane(self, image: np.ndarray) -> np.ndarray:
        """An H x W frame as observed: H x W x 1 (H x W with `legacy_observation`)."""
        return image if self.legacy_observation else image[..., np.newaxis]

    def render(self) -> np.ndarray | None:
        """The current frame as nav-eval's videos draw it (uint8 H x W x 3) with "rgb_array"; with
        "human" it is shown in the window (and None returned); without a render mode, None with
        Gymnasium's warning."""
        self._refuse_if_closed("render")
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() without a render mode: make the env with render_mode='rgb_array' or 'human'"
            )
            return None
        if self._view is None:
            raise RuntimeError("render() before the first reset(): there is no frame yet")
        rgb, mask, depth = self._view
        column = target_column(mask, depth, method=RENDER_TARGET_METHOD, depth_threshold=self.depth_threshold)
        picture = overlay(rgb, mask, column)
        if self.render_mode == "human":
            self._window.show(picture)
            return None
        return picture

    def _show_if_human(self) -> None:
        """Gymnasium's human mode: the window follows every reset and step by itself."""
        if self.render_mode == "human":
            self.render()

    def _model_mask(self, rgb: np.ndarray) -> np.ndarray:
        """The model's vegetation mask of the frame, uint8 0/1 at the camera's size."""
        assert self.segmenter is not None  # check_obs_keys: model_mask is asked only with a model
        return self.segmenter.segment(np.asarray(rgb, dtype=np.uint8)).view(np.uint8)

    def _refuse_if_closed(self, call: str) -> None:
        if self._closed:
            raise RuntimeError(f"{call}() on a closed RowFollowEnv: close() released its simulator; make a new env")

    def close(self) -> None:
        self._closed = True
        self._window.close()
        if self._context is not None:
            self._context.close()
            self._context = None
        super().close()
