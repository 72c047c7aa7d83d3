"""The oracle segmenter: the simulator's exact vegetation mask, no network.

It tells perception errors from control errors: a run that fails with the oracle fails because
of the controller, the robot or the world; one that fails only with the model fails because of
the model.

It is a `FrameSegmenter` (nav_eval.sim.protocols): the simulator hands it the whole rendered
frame, whose exact mask it returns. It is not a runtime `Segmenter`: an RGB image alone does
not carry the mask, so a robot (or `segmin replay`) cannot use it.
"""

from __future__ import annotations

import numpy as np

from segmin.nav_eval.sim.protocols import FrameSegmenter, SimFrame


class OracleSegmenter(FrameSegmenter):
    """Returns the rendered frame's exact vegetation mask."""

    name = "oracle"
    reads_colour = False

    def segment_frame(self, frame: SimFrame) -> np.ndarray:
        return np.asarray(frame.mask, dtype=bool)
