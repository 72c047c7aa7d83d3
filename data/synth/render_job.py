"""What a dataset render is asked to do: the world, where to, how many frames, how to split the work.

Checked on construction so that a bad flag fails naming it before any world is built;
`segmin.data.synth.writer.render_dataset` carries it out.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from segmin.common.executor import LOCAL, Executor
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.spec import WorldSpec


@dataclass
class RenderJob:
    spec: WorldSpec
    out: Path
    frames: int
    camera: CameraModel = dataclasses.field(default_factory=CameraModel)
    seed: int | None = None  # dataset seed; default: the spec's seed
    frames_per_subset: int = 1000
    appearance_every: int = 10
    noisy_depth: bool = True
    workers: int = 1
    shard: tuple[int, int] = (0, 1)
    overwrite: bool = False
    progress: bool = True
    executor: Executor = LOCAL  # where the workers run

    def __post_init__(self) -> None:
        self.out = Path(self.out)
        if self.frames < 1:
            raise ValueError(f"--frames: must be >= 1, got {self.frames}")
        if self.frames_per_subset < 1:
            raise ValueError(f"--frames-per-subset: must be >= 1, got {self.frames_per_subset}")
        if self.appearance_every < 1:
            raise ValueError(f"appearance_every: must be >= 1, got {self.appearance_every}")
        if self.workers < 1:
            raise ValueError(f"--workers: must be >= 1, got {self.workers}")
        i, n = self.shard
        if not (n >= 1 and 0 <= i < n):
            raise ValueError(f"--shard: expected I/N with 0 <= I < N, got {i}/{n}")

    @property
    def dataset_seed(self) -> int:
        return self.spec.seed if self.seed is None else int(self.seed)


def parse_shard(text: str) -> tuple[int, int]:
    """'I/N' -> (I, N)."""
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError as exc:
        raise ValueError(f"--shard: expected I/N (e.g. 0/4), got {text!r}") from exc
    if not (n >= 1 and 0 <= i < n):
        raise ValueError(f"--shard: expected I/N with 0 <= I < N, got {text!r}")
    return i, n
