"""What the simulator needs of the things it is given: a world, a renderer, and a segmenter.

`typing.Protocol`s, so a test's analytic stand-ins serve as well as the synth package's built
worlds (`segmin.data.synth.world.World`) and pybullet renderer (`...render.Renderer`):

- `SimWorld`: one field's ground truth (row gaps, plants, obstacles, terrain);
- `SimRenderer`: renders the robot camera (`camera`, a `CameraModel`: size and depth noise) at a pose;
- `SimFrame`: what a rendered frame holds for perception: the image, planar depth and the exact
  vegetation mask;
- `FrameSegmenter`: the simulator's perception, a mask for a rendered frame. The exact-mask
  oracle is one (it reads `frame.mask`), and so is the robot's ONNX model on the frame's image
  (`nav_eval.sim.segmentation.ModelFrameSegmenter`). The robot runtime's own `Segmenter` takes an
  image only, which is all a robot has.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from segmin.data.synth.camera import CameraModel


class SimFrame(Protocol):
    """A rendered camera frame as perception reads it."""

    @property
    def rgb(self) -> np.ndarray | None:
        """uint8 H x W x 3 image; None for a frame rendered without colour."""
        ...

    @property
    def depth(self) -> np.ndarray:
        """float32 H x W planar depth in metres, 0 = no reading."""
        ...

    @property
    def mask(self) -> np.ndarray:
        """bool H x W exact vegetation mask (ground truth: only the oracle may read it)."""
        ...


class FrameSegmenter(Protocol):
    """The simulator's perception: the vegetation mask of a rendered frame.

    `prepare_frame` splits the work for `nav_eval.sim.segmentation.BackgroundSegmenter`, which
    segments on a helper thread while the next frame renders: the part that must run on the
    caller's thread now, and the rest as a call for the helper. A class that subclasses this
    protocol gets the default (all of it in the call).

    `reads_colour`: whether it reads `frame.rgb`. One that does not (the oracle) lets nav-eval
    render frames without colour when nothing else wants the image.
    """

    reads_colour: bool = True

    def segment_frame(self, frame: SimFrame) -> np.ndarray:
        """bool H x W vegetation mask of `frame`."""
        ...

    def prepare_frame(self, frame: SimFrame) -> Callable[[], np.ndarray]:
        """Start on `frame` here; the returned call finishes `segment_frame(frame)`."""
        return functools.partial(self.segment_frame, frame)


class TerrainSpec(Protocol):
    @property
    def roughness(self) -> float:
        """Standard deviation of the ground height (m): the skid-steer robot slips more on rough ground."""
        ...


class WorldSpec(Protocol):
    @property
    def name(self) -> str: ...

    @property
    def family(self) -> str:
        """The field's kind (vineyards, ...), which picks the depth threshold."""
        ...

    @property
    def terrain(self) -> TerrainSpec: ...


class SimWorld(Protocol):
    """One field's ground truth, in world coordinates (metres)."""

    @property
    def spec(self) -> WorldSpec: ...

    @property
    def centrelines(self) -> Sequence[np.ndarray]:
        """Per row gap, its centreline (K x 2, from the row entrance)."""
        ...

    @property
    def gap_half_widths(self) -> Sequence[float]:
        """Per row gap, half its free width at ground level."""
        ...

    @property
    def plant_circles(self) -> np.ndarray:
        """(N, 3) trunks as circles (x, y, radius): collisions and plant distances."""
        ...

    @property
    def obstacle_circles(self) -> np.ndarray:
        """(M, 3) posts and other obstacles as circles: collisions only."""
        ...

    def terrain_height(self, x: Any, y: Any) -> Any:
        """Ground height at (x, y): a float for scalars, an array for arrays."""
        ...

    def terrain_normal(self, x: Any, y: Any) -> np.ndarray:
        """Unit ground normal at (x, y)."""
        ...


class SimRenderer(Protocol):
    """Renders the robot camera in one world."""

    @property
    def camera(self) -> CameraModel:
        """The camera model: frame size and the depth-noise model the simulator applies."""
        ...

    def render(
        self,
        x: float,
        y: float,
        yaw: float,
        *,
        rng: np.random.Generator | None = None,
        noisy_depth: bool = False,
        colour: bool = True,
    ) -> SimFrame:
        """The frame of a robot at (x, y, yaw); `rng` randomises light and sky (None: fixed);
        `colour=False`: depth and mask only (`rgb` None), as the colour frame has them."""
        ...
