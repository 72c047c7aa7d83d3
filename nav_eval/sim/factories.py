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
    from segmin.nav_eval.runtime.protocols import MaskNavigator


def field_label(field: str) -> str:
    """Short name of a field for tables and files: the spec name for a path."""
    p = Path(field)
    return p.stem if p.suffix in (".yaml", ".yml") else field


def nav_camera(config: NavEvalConfig, backend: str = "tiny") -> CameraModel:
    """The robot camera of the evaluation: the CameraModel default at perception.width/height, its
    depth noise sampled as perception.depth_noise_sampling says (auto: from noise fields with the
    gl `backend`, per pixel with TinyRenderer)."""
    from segmin.data.synth.camera import CameraModel

    perception = config.perception
    sampling = perception.depth_noise_sampling
    if sampling == "auto":
        sampling = "field" if backend == "gl" else "pixels"
    changes = {k: v for k, v in (("width", perception.width), ("height", perception.height)) if v}
    return dataclasses.replace(CameraModel(), depth_noise_sampling=sampling, **changes)


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
    """The simulator's segmenter: 'oracle' -> OracleSegmenter; otherwise an ONNX file or a shipped
    model name, run by the robot's OnnxSegmenter on each frame's image."""
    if str(model) == "oracle":
        from segmin.nav_eval.sim.oracle import OracleSegmenter

        return OracleSegmenter()
    from segmin.nav_eval.runtime.segmenter import OnnxSegmenter
    from segmin.nav_eval.runtime.shipped_models import resolve_model
    from segmin.nav_eval.sim.segmentation import OnnxFrameSegmenter

    return OnnxFrameSegmenter(OnnxSegmenter(resolve_model(model), threads=threads))


def make_navigator(method: str, depth_threshold: float, config: NavEvalConfig) -> MaskNavigator:
    """The method's navigator with the evaluation's fusion window (perception.fuse_frames):
    the paper's `Navigator` (its `navigator` section), or SegCorridor (its `corridor` section,
    with the evaluation camera's intrinsics and mount)."""
    if method == "segcorridor":
        from segmin.nav_eval.runtime.corridor import CameraGeometry, CorridorConfig, CorridorNavigator

        corridor = CorridorConfig(
            depth_threshold=depth_threshold, fuse_frames=config.perception.fuse_frames, **config.corridor
        )
        return CorridorNavigator(corridor, CameraGeometry.from_camera(nav_camera(config)))
    from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig

    return Navigator(
        NavigatorConfig(
            method=method,
            depth_threshold=depth_threshold,
            fuse_frames=config.perception.fuse_frames,
            **config.navigator,
        )
    )


def make_follower(method: str, depth_threshold: float, config: NavEvalConfig) -> RowFollower:
    """The robot runtime at the evaluation's rates: what nav-eval drives in the simulator. It has
    no segmenter of its own: the simulator segments every frame it renders (`run_episode`) and
    hands the runtime the mask with the frame."""
    from segmin.nav_eval.runtime.follower import RowFollower, RuntimeConfig

    rates = config.rates
    return RowFollower(
        None,
        make_navigator(method, depth_threshold, config),
        RuntimeConfig(segment_hz=rates.segment_hz, command_hz=rates.command_hz, checks=config.sensor_checks),
    )
