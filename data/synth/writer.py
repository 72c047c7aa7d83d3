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
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segmin.common.atomic import write_bytes, write_json
from segmin.common.config import to_dict
from segmin.common.executor import LOCAL, Executor
from segmin.common.lock import writer_lock
from segmin.common.outputs import check_writable, make_dirs
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.nets import shade_under_nets
from segmin.data.synth.spec import WorldSpec

FORMAT = "segmin-synth/1"

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FramePlan:
    """Where the camera is for one frame, drawn from (seed, frame) only."""

    frame: int
    gap: int
    s: float
    reverse: bool
    robot_pose: tuple[float, float, float]
    pose_offset: tuple[float, float, float, float]  # lateral, yaw, pitch, roll
    block: int  # appearance block
    # hfov_deg, mount_height, tilt_deg; None = job camera, a None entry keeps the job camera's value
    capture: tuple[float | None, float | None, float | None] | None = None


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


# --------------------------------------------------------------------------------- paths
def subset_dir(out: Path, domain: str, frame: int, per_subset: int) -> Path:
    k = frame // per_subset + 1
    return Path(out) / domain / f"{domain}_{k}"


def frame_paths(out: Path, domain: str, frame: int, per_subset: int) -> dict[str, Path]:
    sub = subset_dir(out, domain, frame, per_subset)
    n = frame
    return {
        "images": sub / "images" / f"Image{n}" / f"Image{n}.png",
        "masks": sub / "masks" / f"Image{n}" / f"Segmentation{n}.png",
        "depths": sub / "depths" / f"Image{n}" / f"Depth{n}.png",
    }


def frame_done(paths: dict[str, Path]) -> bool:
    return all(p.is_file() for p in paths.values())


# --------------------------------------------------------------------------------- planning
def plan_frame(world, job_seed: int, frame: int, appearance_every: int) -> FramePlan:
    """The pose of frame `frame`: a random gap, position, direction and camera perturbation."""
    rng = np.random.default_rng([job_seed, 1, frame])
    spec = world.spec
    gap = int(rng.integers(spec.n_gaps))
    reverse = bool(rng.uniform() < 0.25)
    length = spec.rows.length
    s = float(rng.uniform(-1.5, length - 1.0)) if not reverse else float(rng.uniform(1.0, length + 1.5))
    x, y, yaw = world.gap_pose(gap, s)
    if reverse:
        yaw += math.pi
    half = world.gap_half_widths[gap]
    offset = (
        float(rng.uniform(-0.6, 0.6) * half),
        float(np.clip(rng.normal(0, math.radians(8)), -math.radians(20), math.radians(20))),
        float(np.clip(rng.normal(0, math.radians(2)), -math.radians(5), math.radians(5))),
        float(np.clip(rng.normal(0, math.radians(2)), -math.radians(5), math.radians(5))),
    )
    capture = None
    cs = spec.capture
    if any(lo != hi for lo, hi in (cs.hfov_deg, cs.mount_height, cs.tilt_deg)):
        # Drawn after the pose, so worlds without camera variety keep their poses.
        hfov, height, tilt = (
            float(rng.uniform(lo, hi)) if lo != hi else None for lo, hi in (cs.hfov_deg, cs.mount_height, cs.tilt_deg)
        )
        capture = (hfov, height, tilt)
    return FramePlan(
        frame=frame,
        gap=gap,
        s=s,
        reverse=reverse,
        robot_pose=(x, y, float(yaw)),
        pose_offset=offset,
        block=frame // appearance_every,
        capture=capture,
    )


def frame_camera(camera: CameraModel, plan: FramePlan) -> CameraModel:
    """The job camera with the frame's drawn field of view, mount height and tilt (if any)."""
    if plan.capture is None:
        return camera
    hfov, height, tilt = plan.capture
    changes = {k: v for k, v in (("hfov_deg", hfov), ("mount_height", height), ("tilt_deg", tilt)) if v is not None}
    return dataclasses.replace(camera, **changes)


# --------------------------------------------------------------------------------- encoding
def encode_frame(frame) -> dict[str, bytes]:
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
    ok1, rgb = cv2.imencode(".png", np.ascontiguousarray(frame.rgb[:, :, ::-1]), params)
    ok2, mask = cv2.imencode(".png", frame.mask.astype(np.uint8) * 255, params)
    mm = np.clip(np.round(frame.depth.astype(np.float64) * 1000.0), 0, 65535).astype(np.uint16)
    ok3, depth = cv2.imencode(".png", mm, params)
    if not (ok1 and ok2 and ok3):
        raise RuntimeError("PNG encoding failed")
    return {"images": rgb.tobytes(), "masks": mask.tobytes(), "depths": depth.tobytes()}


def write_frame(paths: dict[str, Path], data: dict[str, bytes]) -> None:
    """Write one frame so that no reader ever sees part of it.

    Each file is written into a hidden staging folder beside its `ImageN/` folder, which is
    then renamed into place (a rename is atomic): `ImageN/` appears complete or not at all.
    Depth and mask go first, the RGB image last. Unlike `segmin.common.atomic`, the files are not
    fsync'ed one by one: three fsyncs per frame cost more than rendering it, and what they
    protect against (power loss, not a killed process) a rerun repairs by re-rendering frames
    whose files fail to decode. Files replaced in an existing folder go through `segmin.common.atomic`.
    """
    for kind in ("depths", "masks", "images"):
        final = paths[kind]
        folder = final.parent
        if folder.is_dir():  # a previous run (or --overwrite): replace the file in place
            write_bytes(final, data[kind])
            continue
        make_dirs(folder.parent)
        staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".staging", dir=folder.parent))
        try:
            with open(staging / final.name, "wb") as handle:
                handle.write(data[kind])
            os.rename(staging, folder)
        except OSError:
            if folder.is_dir():  # lost a race with another writer of the same frame: same bytes
                shutil.rmtree(staging, ignore_errors=True)
            else:
                raise


def clean_stale(out: Path, domain: str, owns) -> int:
    """Remove staging folders and temporary files left by a killed run (own frames only)."""
    removed = 0
    root = Path(out) / domain
    if not root.is_dir():
        return 0
    for kind_dir in root.glob(f"{domain}_*/*"):
        if not kind_dir.is_dir():
            continue
        for entry in kind_dir.iterdir():
            name = entry.name
            frame = _frame_of(name)
            if frame is None or not owns(frame):
                continue
            if name.startswith(".") and name.endswith(".staging"):
                shutil.rmtree(entry, ignore_errors=True)
                removed += 1
            elif entry.is_dir():
                for tmp in entry.glob(".*.tmp"):
                    tmp.unlink(missing_ok=True)
                    removed += 1
    return removed


def _frame_of(name: str) -> int | None:
    core = name.lstrip(".")
    if not core.startswith("Image"):
        return None
    digits = ""
    for ch in core[5:]:
        if not ch.isdigit():
            break
        digits += ch
    return int(digits) if digits else None


# --------------------------------------------------------------------------------- worker
class FrameRenderer:
    """A world built in a private pybullet client, rendering planned frames to bytes."""

    def __init__(
        self, spec: WorldSpec, camera: CameraModel, job_seed: int, appearance_every: int, noisy_depth: bool
    ) -> None:
        import pybullet as p

        from segmin.data.synth.render import Renderer
        from segmin.data.synth.world import build_world

        self.client = p.connect(p.DIRECT)
        self.world = build_world(spec, self.client)
        self.renderer = Renderer(self.world, camera)
        self.camera = camera
        self.job_seed = job_seed
        self.appearance_every = appearance_every
        self.noisy_depth = noisy_depth
        self._block: int | None = None

    def render(self, frame: int):
        plan = plan_frame(self.world, self.job_seed, frame, self.appearance_every)
        blank = blank_frame(self.world, frame_camera(self.camera, plan), plan, self.job_seed)
        if blank is not None:
            return blank
        if plan.block != self._block:
            self.renderer.randomize_appearance(np.random.default_rng([self.job_seed, 4, plan.block]))
            self._block = plan.block
        x, y, yaw = plan.robot_pose
        self.renderer.set_camera(frame_camera(self.camera, plan))
        out = self.renderer.render(
            x,
            y,
            yaw,
            rng=np.random.default_rng([self.job_seed, 2, frame]),
            noisy_depth=False,
            pose_offset=plan.pose_offset,
        )
        # Before the depth noise: the shade follows the true depth.
        shade_under_nets(out, self.world.net_shade, self.renderer.camera)
        if self.noisy_depth:
            out.depth = self.renderer.camera.apply_depth_noise(
                out.depth, np.random.default_rng([self.job_seed, 3, frame])
            )
        return out

    def close(self) -> None:
        import pybullet as p

        p.disconnect(self.client)


def is_blank(spec: WorldSpec, job_seed: int, frame: int) -> bool:
    """Whether frame `frame` is a blank frame (`capture.blank_frames`): a draw of its own stream,
    so the other frames keep their bytes."""
    share = spec.capture.blank_frames
    return share > 0 and bool(np.random.default_rng([job_seed, 5, frame]).uniform() < share)


def blank_frame(world, camera: CameraModel, plan: FramePlan, job_seed: int):
    """The frame a covered, dazzled or failing camera delivers, or None for a rendered frame.

    All black (lens cap, night), all white (saturated) or one colour (a leaf or a glove on the
    lens), with faint sensor noise; the mask is empty (a model must paint nothing on such a frame)
    and depth is 0 (no return)."""
    if not is_blank(world.spec, job_seed, plan.frame):
        return None
    from segmin.data.synth.render import RenderedFrame, camera_pose

    rng = np.random.default_rng([job_seed, 6, plan.frame])
    kind = int(rng.integers(3))
    if kind == 0:
        colour = rng.uniform(0, 14, 3)
    elif kind == 1:
        colour = rng.uniform(240, 255, 3)
    else:
        colour = rng.uniform(0, 255) * (1 + rng.uniform(-0.3, 0.3, 3))
    shape = (camera.height, camera.width)
    rgb = colour[None, None, :] + rng.normal(0, rng.uniform(0, 2.5), (*shape, 3))
    return RenderedFrame(
        rgb=np.clip(np.round(rgb), 0, 255).astype(np.uint8),
        depth=np.zeros(shape, np.float32),
        mask=np.zeros(shape, bool),
        camera_pose=camera_pose(world, camera, *plan.robot_pose, pose_offset=plan.pose_offset),
        robot_pose=plan.robot_pose,
        stats={"blank": ("black", "white", "colour")[kind]},
    )


class RenderWorker:
    """One executor worker of a job: a FrameRenderer whose results are each frame's encoded files.

    The files travel back to the process that runs `render_dataset`, which writes them: so a
    worker on another machine (a Ray node) needs no access to the output folder, and resuming
    (which frames exist) is decided in one place whatever the executor."""

    def __init__(self, job: RenderJob) -> None:
        self.renderer = FrameRenderer(job.spec, job.camera, job.dataset_seed, job.appearance_every, job.noisy_depth)

    def run(self, frames: list[int]) -> list[tuple[int, dict[str, bytes]]]:
        return [(f, encode_frame(self.renderer.render(f))) for f in frames]

    def close(self) -> None:
        self.renderer.close()


# --------------------------------------------------------------------------------- meta
def _fingerprint(job: RenderJob) -> dict:
    return {
        "format": FORMAT,
        "world": to_dict(job.spec),
        "camera": to_dict(job.camera),
        "dataset_seed": job.dataset_seed,
        "frames_per_subset": job.frames_per_subset,
        "appearance_every": job.appearance_every,
        "noisy_depth": job.noisy_depth,
    }


def write_meta(job: RenderJob, world) -> list[Path]:
    """One meta.json per subset: the spec, camera intrinsics, seeds and every frame's poses.
    Its content depends only on the job, so shards writing it concurrently agree byte for byte."""
    fp = _fingerprint(job)
    written = []
    n_subsets = (job.frames - 1) // job.frames_per_subset + 1
    for k in range(n_subsets):
        first = k * job.frames_per_subset
        last = min(job.frames, first + job.frames_per_subset)
        sub = subset_dir(job.out, job.spec.domain, first, job.frames_per_subset)
        meta_path = sub / "meta.json"
        if meta_path.is_file() and not job.overwrite:
            _check_same_settings(meta_path, fp)
        meta = dict(fp)
        meta.update(
            {
                "domain": job.spec.domain,
                "subset": sub.name,
                "intrinsics": job.camera.intrinsics(),
                "world_seed": job.spec.seed,
                "depth_units": "millimetre (uint16 PNG), 0 = invalid",
                "mask_values": "0 = background, 255 = vegetation",
                "frames": {str(f): _frame_meta(job, world, f, sub) for f in range(first, last)},
            }
        )
        write_json(meta_path, meta)
        written.append(meta_path)
    return written


def _check_same_settings(meta_path: Path, fp: dict) -> None:
    """A rerun continues a subset only when its meta.json was written with the same settings."""
    try:
        old = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"{meta_path}: unreadable meta file ({exc}); use --overwrite to start over") from exc
    old_fp = {key: old.get(key) for key in fp}
    if json.loads(json.dumps(old_fp)) != json.loads(json.dumps(fp)):
        changed = sorted(
            key for key in fp if json.dumps(old_fp[key], sort_keys=True) != json.dumps(fp[key], sort_keys=True)
        )
        raise ValueError(
            f"{meta_path}: was rendered with different settings ({', '.join(changed)}); "
            "use another --out or --overwrite"
        )


def _frame_meta(job: RenderJob, world, frame: int, sub: Path) -> dict:
    """One frame's entry: where the robot and the camera were, its appearance block and its files."""
    from segmin.data.synth.render import camera_pose

    plan = plan_frame(world, job.dataset_seed, frame, job.appearance_every)
    cam = frame_camera(job.camera, plan)
    pose = camera_pose(world, cam, *plan.robot_pose, pose_offset=plan.pose_offset)
    extra = (
        {}
        if plan.capture is None
        else {
            "intrinsics": cam.intrinsics(),
            "mount_height": round(cam.mount_height, 6),
            "tilt_deg": round(cam.tilt_deg, 6),
        }
    )
    if is_blank(job.spec, job.dataset_seed, frame):
        extra["blank"] = True
    return {
        "gap": plan.gap,
        "s": round(plan.s, 6),
        "reverse": plan.reverse,
        "robot_pose": [round(v, 6) for v in plan.robot_pose],
        "pose_offset": [round(v, 6) for v in plan.pose_offset],
        "camera_pose": np.round(pose, 6).tolist(),
        "appearance_block": plan.block,
        "files": {
            kind: str(p.relative_to(sub))
            for kind, p in frame_paths(job.out, job.spec.domain, frame, job.frames_per_subset).items()
        },
        **extra,
    }


# --------------------------------------------------------------------------------- run
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


def rendered_frame_count(out: Path, domain: str) -> int:
    """How many frames the dataset's meta files describe (highest frame id + 1; 0 when none)."""
    count = 0
    for meta_path in sorted((Path(out) / domain).glob("*/meta.json")):
        try:
            frames = json.loads(meta_path.read_text()).get("frames", {})
        except (OSError, ValueError, AttributeError) as exc:
            raise ValueError(f"{meta_path}: unreadable meta file ({exc}); use --overwrite to start over") from exc
        ids = [int(k) for k in frames if str(k).isdigit()]
        count = max([count, *(i + 1 for i in ids)])
    return count


def check_frame_count(job: RenderJob) -> None:
    """A rerun may extend a dataset (more frames: the missing ones are rendered) or continue it
    (the same count), never shrink it: rewriting meta.json for fewer frames would drop the
    poses of frames that stay on disk."""
    existing = rendered_frame_count(job.out, job.spec.domain)
    if existing > job.frames:
        raise ValueError(
            f"{job.out / job.spec.domain}: already holds {existing} frames, --frames {job.frames} would drop "
            f"the metadata of {existing - job.frames}; pass --frames {existing} (or more, to extend it), "
            "another --out, or --overwrite to start over"
        )


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
    locally: this process holds no pybullet client by now); write each frame as it comes back,
    `tick(n)` as each task ends."""

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
        job.executor.run(tasks, make_worker, min(job.workers, len(tasks)), done, failed, start_method="fork")


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
