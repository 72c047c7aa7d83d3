"""Render a world into a dataset in the AgriSeg formatted layout: atomic, resumable, sharded.

Layout (read unchanged by the AgriSeg loader; N is the global frame id, k = 1 + N // per_subset):

    DIR/<domain>/<domain>_<k>/images/ImageN/ImageN.png          RGB
    DIR/<domain>/<domain>_<k>/masks/ImageN/SegmentationN.png    uint8, 0 / 255
    DIR/<domain>/<domain>_<k>/depths/ImageN/DepthN.png          uint16 millimetres, 0 = invalid
    DIR/<domain>/<domain>_<k>/meta.json                         spec, camera, seeds, poses

Every frame is a pure function of (world spec, dataset seed, frame id): its pose, light, sky,
depth noise and its appearance block (texture variants and tints, re-drawn every
`appearance_every` frames) come from generators seeded with those numbers only. So the
bytes do not depend on the number of workers, on shards, or on what was rendered before.
Each file is written atomically into a hidden staging folder which is then renamed to
`ImageN/`, so a reader never sees a half-written frame folder; a frame counts as done when
all three folders exist, which is what a rerun checks to continue after a kill.

This module runs a job (`render_dataset`) and is the one to import from; the parts are split by
job and re-exported here: `render_job` (what to render), `frame_plan` (each frame's pose and
camera), `frame_renderer` (pixels, in workers), `frame_files` (paths, encoding, atomic frame
folders) and `dataset_meta` (meta.json and the rerun checks).
"""

from __future__ import annotations

import functools
import logging
import shutil
import time
from pathlib import Path

from segmin.common.lock import writer_lock
from segmin.common.outputs import check_writable
from segmin.common.processes import StartMethod
from segmin.data.synth import gl_raster
from segmin.data.synth.dataset_meta import FORMAT, check_frame_count, rendered_frame_count, write_meta
from segmin.data.synth.frame_files import (
    clean_stale,
    encode_frame,
    frame_done,
    frame_paths,
    subset_dir,
    write_frame,
)
from segmin.data.synth.frame_plan import FramePlan, frame_camera, is_blank, plan_frame
from segmin.data.synth.frame_renderer import FrameRenderer, RenderWorker, blank_frame
from segmin.data.synth.render_job import RenderJob, parse_shard

log = logging.getLogger(__name__)


def lock_path(job: RenderJob) -> Path:
    """The dataset's writer lock: one per domain and shard (shards of one job run side by side).

    It sits beside the domain folder, not inside it, so `--overwrite` removing the folder keeps it.
    """
    shard, n_shards = job.shard
    suffix = "" if n_shards == 1 else f".shard-{shard}-of-{n_shards}"
    return job.out / f".{job.spec.domain}{suffix}.render.lock"


def render_dataset(job: RenderJob) -> dict:
    """Render the job's frames (this shard's part), skipping finished ones; returns a summary.

    Holds the dataset's writer lock throughout: a second writer of the same dataset (and shard)
    is refused (LockHeldError naming the holder) instead of deleting the first one's staging
    folders in its clean-up; the lock of a killed writer is taken over.
    """
    check_writable(job.out)
    with writer_lock(lock_path(job), f"dataset {job.out / job.spec.domain}") as previous:
        if previous:
            log.warning(
                "%s: taking over the lock of pid %s on %s, which has stopped; resuming its work",
                lock_path(job),
                previous.get("pid"),
                previous.get("host"),
            )
        return _render_locked(job)


def _render_locked(job: RenderJob) -> dict:
    """render_dataset's work, under the writer lock: meta files, then this shard's missing frames."""
    domain = job.spec.domain
    shard, n_shards = job.shard
    if job.overwrite and n_shards == 1 and (job.out / domain).exists():
        shutil.rmtree(job.out / domain)
    if not job.overwrite:
        check_frame_count(job)

    def owns(frame: int) -> bool:
        return frame % n_shards == shard

    clean_stale(job.out, domain, owns)
    _write_world_meta(job)
    mine = [f for f in range(job.frames) if owns(f)]
    todo = [f for f in mine if job.overwrite or not frame_done(frame_paths(job.out, domain, f, job.frames_per_subset))]
    rate = _Rate(_progress(len(todo), job.progress))
    if todo:
        _render_tasks(job, _tasks(todo, job.appearance_every), rate.tick)
    return rate.summary(skipped=len(mine) - len(todo), out=str(job.out / domain))


def _write_world_meta(job: RenderJob) -> None:
    """The meta files' ground truth, from a world built in a private client of this process."""
    import pybullet as p

    from segmin.data.synth.world import build_world

    client = p.connect(p.DIRECT)
    try:
        write_meta(job, build_world(job.spec, client))
    finally:
        p.disconnect(client)


def _tasks(todo: list[int], appearance_every: int) -> list[list[int]]:
    """Up to 16 frames a task, never across appearance blocks: a worker re-draws the look once per task at most."""
    tasks: list[list[int]] = []
    for f in todo:
        if tasks and tasks[-1][-1] // appearance_every == f // appearance_every and len(tasks[-1]) < 16:
            tasks[-1].append(f)
        else:
            tasks.append([f])
    return tasks


def _render_tasks(job: RenderJob, tasks: list[list[int]], tick) -> None:
    """Render every task, in this process or on `job.workers` workers of `job.executor` (forked
    locally, which saves each worker the imports: this process holds no pybullet client by now;
    spawned once it has rendered with gl, as OpenGL does not survive a fork); write each frame as
    it comes back, `tick(n)` as each task ends."""

    def done(_: list[int], frames: list[tuple[int, dict[str, bytes]]]) -> None:
        for f, data in frames:
            write_frame(frame_paths(job.out, job.spec.domain, f, job.frames_per_subset), data)
        tick(len(frames))

    def failed(task: list[int], why: str) -> list[tuple[int, dict[str, bytes]]]:
        raise RuntimeError(f"synth render: frames {task[0]}-{task[-1]} not rendered: {why}")

    if job.workers == 1 and job.executor.kind == "local":
        worker = RenderWorker(job)
        try:
            for task in tasks:
                done(task, worker.run(task))
        finally:
            worker.close()
    else:
        make_worker = functools.partial(RenderWorker, job)
        start_method: StartMethod = "spawn" if gl_raster.opened_in_this_process() else "fork"
        job.executor.run(tasks, make_worker, min(job.workers, len(tasks)), done, failed, start_method=start_method)


class _Rate:
    """Frames written over time: the whole run's rate, and the steady rate after the workers
    have built their worlds and returned a first task."""

    def __init__(self, bar) -> None:
        self.bar = bar
        self.start = time.perf_counter()
        self.done = 0
        self.first: tuple[float, int] | None = None  # (time, frames) when the first task came back

    def tick(self, n: int) -> None:
        self.done += n
        self.bar.update(n)
        if self.first is None:
            self.first = (time.perf_counter(), self.done)

    def summary(self, *, skipped: int, out: str) -> dict:
        """render_dataset's summary (closes the progress bar)."""
        self.bar.close()
        end = time.perf_counter()
        seconds, done, first = end - self.start, self.done, self.first
        steady = (done - first[1]) / (end - first[0]) if first and done > first[1] and end > first[0] else 0.0
        return {
            "written": done,
            "skipped": skipped,
            "seconds": seconds,
            "fps": done / seconds if seconds > 0 and done else 0.0,
            "steady_fps": steady,
            "out": out,
        }


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, unit="frame", disable=not enabled or total == 0, dynamic_ncols=True)


__all__ = [
    "FORMAT",
    "FramePlan",
    "FrameRenderer",
    "RenderJob",
    "RenderWorker",
    "blank_frame",
    "check_frame_count",
    "clean_stale",
    "encode_frame",
    "frame_camera",
    "frame_done",
    "frame_paths",
    "is_blank",
    "lock_path",
    "parse_shard",
    "plan_frame",
    "render_dataset",
    "rendered_frame_count",
    "subset_dir",
    "write_frame",
    "write_meta",
]
