"""Factories for one closed-loop run: a field built in pybullet, its simulator, its segmenter and
its navigator.

They live apart from `evaluate` (the matrix runner) so that figures, benches and the runner can
all build the same objects without importing one another.
"""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from segmin.nav_eval.sim.config import NavEvalConfig
from segmin.nav_eval.sim.protocols import FrameSegmenter
from segmin.nav_eval.sim.row_env import RowEnv

if TYPE_CHECKING:
    from segmin.data.synth.camera import CameraModel
    from segmin.nav_eval.runtime.follower import RowFollower
    from segmin.nav_eval.runtime.follower_config import FollowerConfig
    from segmin.nav_eval.runtime.protocols import MaskNavigator


def field_label(field: str) -> str:
    """Short name of a field for tables and files: the spec name for a path."""
    p = Path(field)
    return p.stem if p.suffix in (".yaml", ".yml") else field


def nav_camera(config: NavEvalConfig, backend: str = "tiny") -> CameraModel:
    """The robot camera of the evaluation: the CameraModel default at perception.width/height on
    the follower's camera mount, its depth noise sampled as perception.depth_noise_sampling says
    (auto: from noise fields with the gl `backend`, per pixel with TinyRenderer)."""
    from segmin.data.synth.camera import CameraModel

    perception, mount = config.perception, config.follower.camera
    sampling = perception.depth_noise_sampling
    if sampling == "auto":
        sampling = "field" if backend == "gl" else "pixels"
    changes = {k: v for k, v in (("width", perception.width), ("height", perception.height)) if v}
    return dataclasses.replace(
        CameraModel(),
        depth_noise_sampling=sampling,
        mount_height=mount.mount_height,
        tilt_deg=mount.tilt_deg,
        mount_forward=mount.mount_forward,
        **changes,
    )


class FieldContext:
    """A field built in its own pybullet DIRECT client, with its renderer."""

    def __init__(self, field: str, config: NavEvalConfig) -> None:
        import pybullet as p

        from segmin.data.synth.render import Renderer, resolve_backend
        from segmin.data.synth.spec import load_world_spec
        from segmin.data.synth.world import build_world

        self.spec = load_world_spec(field)
        self.client = p.connect(p.DIRECT)
        self.world = build_world(self.spec, self.client)
        backend = config.render.backend or self.spec.render.backend
        self.camera = nav_camera(config, resolve_backend(backend))
        self.renderer = Renderer(self.world, self.camera, backend=backend)
        self.depth_threshold = config.depth_threshold(self.spec.name, self.spec.family)
        self.gap = config.run.gap if config.run.gap is not None else self.spec.eval_gap

    def close(self) -> None:
        import pybullet as p

        with contextlib.suppress(Exception):  # already gone
            p.disconnect(self.client)


def make_simulator(ctx: FieldContext, config: NavEvalConfig) -> RowEnv:
    """The simulator on an already built field (a worker builds each field once, for many runs)."""
    return RowEnv(ctx.world, ctx.renderer, config, gap=ctx.gap)


def make_segmenter(model: str, threads: int = 1) -> FrameSegmenter:
    """The simulator's segmenter: 'oracle' -> OracleSegmenter; otherwise an ONNX or LiteRT file or a
    shipped model name, run by the robot's segmenter for it (`load_segmenter`) on each frame's image."""
    if str(model) == "oracle":
        from segmin.nav_eval.sim.oracle import OracleSegmenter

        return OracleSegmenter()
    from segmin.nav_eval.runtime.segmenter import load_segmenter
    from segmin.nav_eval.sim.segmentation import ModelFrameSegmenter

    return ModelFrameSegmenter(load_segmenter(model, threads=threads))


def follower_config(method: str, depth_threshold: float, config: NavEvalConfig) -> FollowerConfig:
    """The robot runtime's config of one run: `method` at the field's `depth_threshold`, with the
    evaluation's `follower` section (nav_eval.sim.config.EvalFollower)."""
    return config.follower.config(method, depth_threshold)


def make_navigator(method: str, depth_threshold: float, config: NavEvalConfig) -> MaskNavigator:
    """The method's navigator under the evaluation's config, on the simulated camera (which
    SegCorridor places its pixels with): the runtime's own `make_navigator`."""
    from segmin.nav_eval.runtime.camera import CameraGeometry
    from segmin.nav_eval.runtime.follower_config import make_navigator as build

    camera = CameraGeometry.from_camera(nav_camera(config))
    return build(follower_config(method, depth_threshold, config), camera)


def make_follower(method: str, depth_threshold: float, config: NavEvalConfig) -> RowFollower:
    """The robot runtime at the evaluation's rates: what nav-eval drives in the simulator. It has
    no segmenter of its own: the simulator segments every frame it renders (`run_episode`) and
    hands the runtime the mask with the frame."""
    from segmin.nav_eval.runtime.follower import RowFollower

    return RowFollower(None, make_navigator(method, depth_threshold, config), config.follower.runtime)
