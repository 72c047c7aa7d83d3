"""`segmin bench navigator`: time one `Navigator.step` per method on one thread, and the robot runtime per frame."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.speed_targets import SpeedTarget
from segmin.common.timing import time_calls
from segmin.nav_eval.demo.scenes import CLOSED_CANOPY_SCENE, DEMO_SCENES, render_scene
from segmin.nav_eval.runtime.corridor import CameraGeometry, CorridorConfig, CorridorNavigator
from segmin.nav_eval.runtime.methods import METHODS
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig

# Per step at 224 x 224 on one thread: the paper's navigators, and SegCorridor (more work per step).
STEP_TARGET = SpeedTarget("median_ms", "median", 0.2, "ms")
CORRIDOR_STEP_TARGET = SpeedTarget("median_ms", "segcorridor median", 0.5, "ms")
# The shipped trees model's setting: each mask closed with an 8 px disc first (one closing a step
# here; on a robot one a mask at 20 Hz, so 1 ms is 2 % of a core).
CLOSING = {"mask_closing": 8}
CLOSING_STEP_TARGET = SpeedTarget("median_ms", "segmind with mask_closing 8 median", 1.0, "ms")
# centre_hold's settings for sloped, gappy rows (docs/reference/equations.md): the slope feedforward
# and the rule that leaves out a row seen only far ahead (each frame takes two quantiles more).
SLOPED_ROWS = {"hold_slope_drift": 0.5, "row_start_max": 2.5, "trim": 2.0}


def untrained_onnx(folder: Path, size: int = 224) -> Path:
    """An untrained (random-weight) model exported with the export package, for timing only."""
    import onnx
    import torch

    from segmin.export.onnx import build_metadata, export_graph, set_metadata
    from segmin.models import build_model
    from segmin.models.checkpoint import model_info

    torch.manual_seed(0)
    path = folder / "untrained.onnx"
    model = build_model(backbone_weights="none").eval()
    opset = export_graph(model, path, input_size=(size, size), exporter="legacy")
    proto = onnx.load(str(path))
    info = model_info(backbone_weights="none", input_size=(size, size), family="untrained", train_data="none")
    set_metadata(proto, build_metadata(info, input_size=(size, size), exporter="legacy", opset=opset))
    onnx.save(proto, str(path))
    return path


def bench_navigator(*, size: int = 224, steps: int = 3000, warmup: int = 200) -> list[dict]:
    """Median and p95 milliseconds per step for each method on the demo's vineyard and tree frames,
    SegCorridor's on a closed canopy over trunks (its trunk mode: another code path) and with the
    centre-hold law of a slipping robot, also with its settings for sloped rows; SegMinD also with
    the masks closed as for the shipped trees model."""
    frames = [render_scene(scene, size=size, seed=i) for i, scene in enumerate(DEMO_SCENES[:3])]
    mask, depth = render_scene(CLOSED_CANOPY_SCENE, size=size)
    # The image only makes the trunk test pay for its colour check (leaves green, the rest brown:
    # the check removes nothing here).
    rgb = np.where(mask[..., None], np.array([60, 140, 50], np.uint8), np.array([90, 60, 40], np.uint8)).astype(
        np.uint8
    )
    canopy = [(mask, depth, None, rgb)]
    rolled = [(*frame, (0.05, 0.0)) for frame in frames]  # 3 degrees: a cross slope
    runs: list[tuple[str, str, list, str, dict[str, Any]]] = [
        (method, method, frames, "pursuit", {}) for method in METHODS
    ] + [
        ("segmind", "segmind, mask_closing 8", frames, "pursuit", CLOSING),
        ("segcorridor", "segcorridor, trunk mode", canopy, "pursuit", {}),
        ("segcorridor", "segcorridor, centre hold", rolled, "centre_hold", {}),
        ("segcorridor", "segcorridor, centre hold, sloped rows", rolled, "centre_hold", SLOPED_ROWS),
    ]
    rows = []
    for method, label, inputs, controller, changes in runs:
        navigator = _navigator(method, size, controller, changes)
        ms = time_calls(_stepper(navigator), runs=steps, warmup=warmup, inputs=inputs) * 1e3
        rows.append(
            {
                "method": method,
                "label": label,
                "median_ms": float(np.median(ms)),
                "p95_ms": float(np.percentile(ms, 95)),
                "target": _target(method, changes),
            }
        )
        if label.endswith("trunk mode") and not navigator.mode_counts["trunks"]:
            raise RuntimeError("the closed-canopy bench scene did not reach SegCorridor's trunk mode")
    return rows


def _stepper(navigator: Navigator | CorridorNavigator) -> Callable[[tuple], object]:
    """One step on a frame: (mask, depth), and for SegCorridor (attitude, rgb) where given."""
    return lambda frame: navigator.step(*frame)


def _navigator(
    method: str, size: int, controller: str, changes: dict[str, Any] | None = None
) -> Navigator | CorridorNavigator:
    """A paper navigator, or SegCorridor with the simulator's camera at `size` x `size` steering
    with `controller` (and the CorridorConfig `changes`)."""
    if method != "segcorridor":
        return Navigator(NavigatorConfig(method=method, depth_threshold=5.0, fuse_frames=3, **(changes or {})))
    from segmin.data.synth.camera import CameraModel

    camera = CameraGeometry.from_camera(CameraModel(width=size, height=size))
    # Trunk pixels scale with the image's area: below 224 px the trunk test's minimum shrinks with it.
    trunk_min_points = min(
        CorridorConfig.trunk_min_points, max(1, round(CorridorConfig.trunk_min_points * (size / 224) ** 2))
    )
    return CorridorNavigator(
        CorridorConfig(
            depth_threshold=5.0,
            fuse_frames=3,
            trunk_min_points=trunk_min_points,
            controller=controller,
            **(changes or {}),
        ),
        camera,
    )


def _target(method: str, changes: dict[str, Any]) -> SpeedTarget:
    """The step budget of a run: by method, and the closing's own when the masks are closed."""
    if changes.get("mask_closing"):
        return CLOSING_STEP_TARGET
    return CORRIDOR_STEP_TARGET if method == "segcorridor" else STEP_TARGET


def format_rows(rows: list[dict], size: int) -> str:
    """One line per method: median and p95, and the median as a multiple of its target."""
    lines = [
        f"Navigator.step at {size} x {size}, fuse_frames 3, one thread (targets: {STEP_TARGET}, {CORRIDOR_STEP_TARGET}, "
        f"{CLOSING_STEP_TARGET})"
    ]
    for row in rows:
        target = row["target"]
        lines.append(
            f"  {row['label']:<24} median {row['median_ms']:.3f} ms  p95 {row['p95_ms']:.3f} ms  "
            f"({row['median_ms'] / target.limit:.2f}x the target budget: {'met' if target.met(row['median_ms']) else 'NOT met'})"
        )
    return "\n".join(lines)


def single_thread_environment() -> None:
    """Pin numpy's thread pools to one thread (the benchmark measures one core)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def _percentiles(seconds: list[float]) -> str:
    ms = np.asarray(seconds) * 1e3
    return f"median {np.median(ms):.3f} ms  p95 {np.percentile(ms, 95):.3f} ms"


def bench_runtime(
    *, size: int = 224, steps: int = 3000, model: str | None = None, threads: int = 2, camera_hz: int = 30
) -> str:
    """The robot runtime per camera frame at the paper's rates (30 Hz camera, 20 / 5 Hz, 3 masks).

    First with the masks given (segmentation excluded: the runtime's own bookkeeping, fusion and
    the navigator), then with an ONNX segmenter: the full perception + fusion + command step of
    a frame at which a command is computed. Without `model` an untrained model is exported to a
    temporary file (needs the [train] extra; that part is skipped without it).
    """
    import tempfile

    from segmin.nav_eval.runtime.follower import RowFollower

    frames = _RuntimeFrames(size, camera_hz)
    lines = [f"RowFollower at {size} x {size}, camera {camera_hz} Hz, masks 20 Hz, commands 5 Hz, fuse 3 (SegMinD)"]
    follower = RowFollower(None, Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0)))
    every, fresh = frames.drive(follower, steps, with_masks=True)
    lines.append(
        f"  per frame, segmentation excluded: {_percentiles(every)} over {len(every)} frames; "
        f"frames with a command: {_percentiles(fresh)}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        lines.append(_full_step_line(frames, model, size, steps, threads, Path(tmp)))
    return "\n".join(lines)


class _RuntimeFrames:
    """The demo's first three scenes as camera frames (RGB, depth, mask), fed to a RowFollower in turn."""

    def __init__(self, size: int, camera_hz: int) -> None:
        self.scenes = [render_scene(scene, size=size, seed=i) for i, scene in enumerate(DEMO_SCENES[:3])]
        self.rgbs = []
        for mask, _ in self.scenes:
            rgb = np.full((*mask.shape, 3), (120, 95, 70), dtype=np.uint8)
            rgb[mask] = (40, 140, 35)
            self.rgbs.append(rgb)
        self.camera_hz = camera_hz

    def drive(self, follower, frames: int, with_masks: bool, start: int = 0) -> tuple[list[float], list[float]]:
        """Seconds per `follower.step`: of every frame, and of the frames that computed a command."""
        every, fresh = [], []
        for i in range(start, start + frames):
            mask, depth = self.scenes[i % len(self.scenes)]
            started = time.perf_counter()
            out = follower.step(
                self.rgbs[i % len(self.scenes)], depth, i / self.camera_hz, mask=mask if with_masks else None
            )
            elapsed = time.perf_counter() - started
            every.append(elapsed)
            if out.fresh:
                fresh.append(elapsed)
        return every, fresh


def _full_step_line(frames: _RuntimeFrames, model: str | None, size: int, steps: int, threads: int, tmp: Path) -> str:
    """The full step with OnnxSegmenter on `model` (or an untrained export), or why it was skipped."""
    from segmin.nav_eval.runtime.follower import RowFollower
    from segmin.nav_eval.runtime.segmenter import OnnxSegmenter

    if model is None:
        try:
            model, label = str(untrained_onnx(tmp, size=size)), "untrained model exported to a temp file"
        except ModuleNotFoundError as exc:
            return (
                f"  full step skipped: exporting a model needs the [train] extra ({exc.name}); "
                "give --model an .onnx file"
            )
    else:
        label = Path(model).name
    follower = RowFollower(
        OnnxSegmenter(model, threads=threads), Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0))
    )
    frames.drive(follower, 30, with_masks=False)  # warm-up
    every, fresh = frames.drive(follower, max(60, min(steps, 600)), with_masks=False, start=30)
    return (
        f"  full step with OnnxSegmenter ({label}, {threads} threads), a frame with a command "
        f"(segment + fuse + command): {_percentiles(fresh)} over {len(fresh)} commands; "
        f"every frame: {_percentiles(every)}"
    )
