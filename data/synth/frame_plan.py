"""Where the camera stands for each dataset frame, drawn from (dataset seed, frame id) only.

Each draw has its own seeded stream (pose: 1, blank frames: 5), so a frame's plan does not depend
on which frames were planned before it, on workers or on shards: that is what makes a dataset's
bytes reproducible frame by frame (see `segmin.data.synth.writer`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from segmin.data.synth.camera import CameraModel
from segmin.data.synth.spec import WorldSpec


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


def is_blank(spec: WorldSpec, job_seed: int, frame: int) -> bool:
    """Whether frame `frame` is a blank frame (`capture.blank_frames`): a draw of its own stream,
    so the other frames keep their bytes."""
    share = spec.capture.blank_frames
    return share > 0 and bool(np.random.default_rng([job_seed, 5, frame]).uniform() < share)
