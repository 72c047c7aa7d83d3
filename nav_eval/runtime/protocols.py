"""The runtime's two interfaces: what `RowFollower` needs of a segmenter and of a navigator.

They are `typing.Protocol`s, checked by mypy, not base classes: any object with these methods
is one (the ONNX and LiteRT segmenters, a test's stand-in; the paper's `Navigator`, `CorridorNavigator`).

- `Segmenter`: an RGB frame in, a vegetation mask out. The robot's only kind. (The simulator's
  exact-mask oracle needs the rendered frame, not its image: it is a `FrameSegmenter` of
  `nav_eval.sim.protocols`, and the simulator hands it frames; it is never a `Segmenter`.)
- `MaskNavigator`: masks pushed at the segmentation rate, fused and turned into a smoothed command
  at the command rate. What a navigator reads besides the masks is declared as data,
  `inputs: NavigatorInputs`, so the runtime hands it exactly that and checks it when the frame
  arrives; its per-run statistics come back through `statistics()`.

A new navigator implements `MaskNavigator` and declares its inputs and the names of its
statistics (`methods.METHOD_STATISTICS`); the runtime, the simulator and the evaluation need no
change. numpy only (the bare robot install).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from .camera import CameraGeometry
from .control import Command


@runtime_checkable
class Segmenter(Protocol):
    """What the runtime needs from perception: camera images in, vegetation masks out."""

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        """uint8 H x W x 3 RGB frame -> bool H x W vegetation mask."""
        ...

    def probabilities(self, rgb: np.ndarray) -> np.ndarray:
        """uint8 H x W x 3 RGB frame -> float32 H x W vegetation probability in [0, 1]."""
        ...


@dataclass(frozen=True)
class NavigatorInputs:
    """What a navigator reads besides its fused masks; the runtime gives it exactly these.

    `depth`: it cannot run without depth frames (SegMinD, SegCorridor); otherwise the runtime
    fills a missing depth frame with the depth threshold, so every mask pixel counts as near.
    `rgb`: `command` gets the newest image (SegCorridor's trunk test reads its colour).
    `attitude`: `command` gets the IMU's (roll, pitch) (SegCorridor levels its 3-D points).
    `camera`: the camera it was built for (SegCorridor back-projects pixels); frames of another
    size are refused when they arrive.
    """

    depth: bool = False
    rgb: bool = False
    attitude: bool = False
    camera: CameraGeometry | None = None


class NavigatorSettings(Protocol):
    """The settings the runtime reads of a navigator's config."""

    @property
    def method(self) -> str: ...

    @property
    def depth_threshold(self) -> float: ...

    @property
    def fuse_frames(self) -> int: ...


class MaskNavigator(Protocol):
    """A navigator as `RowFollower` drives it (the paper's `Navigator`, `CorridorNavigator`)."""

    @property
    def config(self) -> NavigatorSettings:
        """Its settings: the method's name, the depth threshold and the fusion window."""
        ...

    @property
    def inputs(self) -> NavigatorInputs:
        """What it reads besides the masks (see `NavigatorInputs`)."""
        ...

    def reset(self) -> None:
        """Forget masks, smoothing and per-run statistics: a new run starts."""
        ...

    def push_mask(self, mask: np.ndarray, stamp: float = 0.0) -> None:
        """Add one mask, taken at time `stamp` (seconds), to the fusion window."""
        ...

    def fused_mask(self, not_before: float | None = None) -> np.ndarray | None:
        """The OR of the window's masks stamped at or after `not_before`; None if none qualifies."""
        ...

    def command(
        self,
        fused: np.ndarray,
        depth: np.ndarray,
        attitude: tuple[float, float] | None = None,
        rgb: np.ndarray | None = None,
    ) -> Command:
        """The smoothed command for a fused mask and the newest depth frame; `attitude` and `rgb`
        are given when `inputs` asks for them, else None."""
        ...

    def stop(self) -> Command:
        """An invalid stop command; the smoothing restarts from rest."""
        ...

    def statistics(self) -> dict[str, float]:
        """Per-run statistics since `reset`, by result column name (empty when it keeps none)."""
        ...
