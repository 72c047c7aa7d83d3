"""A dataset's meta.json files: the spec, camera, seeds and every frame's poses, and the checks a
rerun makes against them (same settings, never fewer frames) before it continues a dataset.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from segmin.common.atomic import write_json
from segmin.common.config import to_dict
from segmin.data.synth.frame_files import frame_paths, subset_dir
from segmin.data.synth.frame_plan import frame_camera, is_blank, plan_frame
from segmin.data.synth.render_job import RenderJob

FORMAT = "segmin-synth/1"


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
