"""Segmentation in the simulator: the robot's exported model on rendered frames, and the helper
thread that segments one frame while the next one renders.

`ModelFrameSegmenter` makes the robot's `OnnxSegmenter` or `LiteRtSegmenter` a `FrameSegmenter` (it reads the frame's
image, nothing else). `BackgroundSegmenter` runs any `FrameSegmenter` on one helper thread; the
masks are those of `segment_frame`, only earlier.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np

from segmin.nav_eval.sim.protocols import FrameSegmenter, SimFrame

if TYPE_CHECKING:
    from segmin.nav_eval.runtime.segmenter import LiteRtSegmenter, OnnxSegmenter, PreparedFrame


class ModelFrameSegmenter(FrameSegmenter):
    """An exported model (`OnnxSegmenter`, `LiteRtSegmenter`) on the simulator's frames: it
    segments `frame.rgb`.

    The work splits as the segmenter splits it: the checks and the resize (`prepare`, which
    holds the GIL) on the caller's thread, the runtime (`segment_prepared`, which releases it)
    in the call `prepare_frame` returns.
    """

    def __init__(self, model: OnnxSegmenter | LiteRtSegmenter) -> None:
        self.model = model
        self.name = model.name  # "onnx" or "litert"

    def segment_frame(self, frame: SimFrame) -> np.ndarray:
        return self.prepare_frame(frame)()

    def prepare_frame(self, frame: SimFrame) -> Callable[[], np.ndarray]:
        return functools.partial(self.segment_prepared, self.model.prepare(frame.rgb))

    def segment_prepared(self, prepared: PreparedFrame) -> np.ndarray:
        """The bool mask of a frame the model prepared (the part run on a helper thread)."""
        return np.asarray(self.model.segment_prepared(prepared), dtype=bool)

    def __repr__(self) -> str:
        return f"ModelFrameSegmenter({self.model!r})"


class BackgroundSegmenter:
    """Segments frames on one helper thread while the caller renders the next one.

    `submit` returns only once the helper has started the job. A thread waiting for the GIL
    gets it at the holder's next switch point, and pybullet holds the GIL for the whole of
    `getCameraImage`: without the handshake the helper would start after the next render, and
    nothing would overlap. Once started, the helper releases the GIL inside onnxruntime.
    Jobs run one at a time in submission order, so a segmenter's own random stream (mask
    dropout) is drawn in the order of the frames.
    """

    def __init__(self, segmenter: FrameSegmenter) -> None:
        self.segmenter = segmenter
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="segmin-segment")

    def submit(self, frame: SimFrame) -> Future[np.ndarray]:
        """Start segmenting `frame`; the future holds its bool mask."""
        # Prepare on this thread: OpenCV's resize releases the GIL, which would hand it to this
        # thread's next render and stall the helper before it reached onnxruntime.
        finish = self.segmenter.prepare_frame(frame)
        started = threading.Event()

        def job() -> np.ndarray:
            started.set()
            return finish()

        future = self._pool.submit(job)
        started.wait()
        return future

    def __enter__(self) -> BackgroundSegmenter:
        return self

    def __exit__(self, *exc: object) -> None:
        self._pool.shutdown(wait=True)
