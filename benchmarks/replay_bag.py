"""`python -m benchmarks replay-bag`: `segmin replay --bag` against `segmin replay` on the same frames as folders.

The bag's colour and depth frames are written out as PNG colour frames and float32 metre .npy
depth (lossless: both replays feed the runtime the same arrays), then both replays run with the
same model and settings; the figure is frames per second of each, outputs included (commands,
overlay video, plot). The commands are checked to be the same.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from segmin.nav_eval.replay.bags import bag_frames
from segmin.nav_eval.replay.run import replay
from segmin.nav_eval.ros2 import topics


def bench_replay_bag(model: Path, bag: Path, threads: int, method: str, depth_threshold: float) -> str:
    """Frames per second of the bag replay and of the folder replay (see the module docstring)."""
    settings = {"method": method, "depth_threshold": depth_threshold, "threads": threads}
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        (root / "rgb").mkdir()
        (root / "depth").mkdir()
        times = []
        for i, (_, t, rgb, depth, _) in enumerate(bag_frames(bag, topics.COLOUR, topics.DEPTH).frames):
            cv2.imwrite(str(root / "rgb" / f"{i:06d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            np.save(root / "depth" / f"{i:06d}.npy", depth)
            times.append(t)
        (root / "times.txt").write_text("\n".join(repr(t) for t in times) + "\n")
        start = time.perf_counter()
        from_bag = replay(
            model, None, root / "bag_out", source=bag_frames(bag, topics.COLOUR, topics.DEPTH), **settings
        )
        bag_s = time.perf_counter() - start
        start = time.perf_counter()
        from_folders = replay(
            model, root / "rgb", root / "folder_out", depth=root / "depth", timestamps=root / "times.txt", **settings
        )
        folder_s = time.perf_counter() - start
    same = from_bag.commands == from_folders.commands
    count = len(times)
    return "\n".join(
        [
            f"python -m benchmarks replay-bag: {count} frames, {method}, {Path(model).name}, {threads} thread(s)",
            f"replay --bag: {count / bag_s:.1f} frames/s ({bag_s:.2f} s)",
            f"replay of the same frames as folders (PNG + .npy): {count / folder_s:.1f} frames/s ({folder_s:.2f} s)",
            f"same commands: {same} ({len(from_bag.commands)} commands)",
        ]
    )
