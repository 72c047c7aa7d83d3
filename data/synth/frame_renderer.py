"""Rendering planned frames to pixels: a world in a private pybullet client per worker.

A worker returns encoded files rather than writing them, so it needs no access to the output
folder (a Ray node on another machine) and which frames exist is decided in one place.
"""

from __future__ import annotations

import numpy as np

from segmin.data.synth.camera import CameraModel
from segmin.data.synth.frame_files import encode_frame
from segmin.data.synth.frame_plan import FramePlan, frame_camera, is_blank, plan_frame
from segmin.data.synth.nets import shade_under_nets
from segmin.data.synth.render_job import RenderJob
from segmin.data.synth.spec import WorldSpec


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
