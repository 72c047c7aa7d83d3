"""`python -m benchmarks render-agreement`: the gl backend against TinyRenderer (the reference) on every test field.

Both renderers draw the same built world (the gl backend leaves pybullet's bodies alone), from the
same poses along the evaluation gap, with the same per-frame randomness (tints, light, sky,
exposure), so any difference is the rasteriser's. Per field: mask IoU, the share of pixels whose
body id agrees, planar depth error on the pixels both hit (median and 95th percentile, metres),
mean absolute RGB difference, and each backend's CPU milliseconds per frame.

Shadows are compared on their own: at each pose both backends draw the raw image (no sky or
exposure) with and without shadows under one sun (direction drawn from the world's sun elevations,
`sun_distance` metres away); a pixel is shadowed where the shadow made it darker. The figures are
each backend's shadowed share and the IoU of the two shadow masks. The world's own frames put the
sun 100 m away, beyond the camera's far plane, where TinyRenderer's shadow pass (and so the gl
backend's) sees nothing and shadows nothing: the default `sun_distance` brings it within reach so
that there is something to compare. The side-by-side
sheet shows, per field, TinyRenderer's and the gl backend's RGB, where the masks differ and both
depths.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from segmin.data.synth.camera import CameraModel
from segmin.data.synth.render import RenderedFrame, Renderer
from segmin.data.synth.spec import TEST_FIELDS, WorldSpec

BACKENDS = ("tiny", "gl")
SUN_DISTANCE = 40.0  # within the default camera's 60 m far plane from every field's rows


@dataclass(frozen=True)
class AgreementOptions:
    """What `python -m benchmarks render-agreement` takes (benchmarks/cli.py has the command-line help)."""

    camera: CameraModel
    poses: int = 8
    fields: tuple[str, ...] = TEST_FIELDS
    sheet: Path | None = None  # side-by-side PNG
    sun_distance: float = SUN_DISTANCE  # metres from the world origin to the sun of the shadow figures

    def __post_init__(self) -> None:
        if self.poses < 1:
            raise ValueError(f"--poses {self.poses}: must be >= 1")
        if self.sun_distance <= 0:
            raise ValueError(f"--sun-distance {self.sun_distance}: must be > 0")


@dataclass
class FieldAgreement:
    """How closely the gl backend's frames of one field follow TinyRenderer's."""

    mask_iou_mean: float
    mask_iou_min: float
    ids_equal: float  # share of pixels with the same body id (or nothing hit in both)
    depth_median_m: float
    depth_p95_m: float
    rgb_mad: float  # mean absolute difference, 0..255
    cpu_ms: dict[str, float]  # per backend, render() CPU milliseconds per frame
    shadow_share: dict[str, float]  # per backend, share of pixels its shadows darkened
    shadow_iou: float  # of the two backends' shadow masks


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks; 1 when both are empty (they agree)."""
    union = int((a | b).sum())
    return 1.0 if union == 0 else float((a & b).sum()) / union


def shadow_mask(renderer: Renderer, pose: np.ndarray, look: dict) -> np.ndarray:
    """Pixels of the raw image at `pose` (culled for it already) that `look`'s shadows darken."""
    lit, _, _ = renderer.rasterise(pose, {**look, "shadow": False})
    shaded, _, _ = renderer.rasterise(pose, {**look, "shadow": True})
    assert lit is not None and shaded is not None  # colour frames
    return (shaded < lit).any(axis=-1)


def field_agreement(
    spec: WorldSpec, camera: CameraModel, poses: int, sun_distance: float = SUN_DISTANCE
) -> tuple[FieldAgreement, np.ndarray]:
    """Render `poses` frames of `spec` with both backends; returns the figures and the sheet row of
    the middle pose."""
    import pybullet as p

    from segmin.data.synth.render import sun_look
    from segmin.data.synth.world import build_world

    client = p.connect(p.DIRECT)
    try:
        world = build_world(spec, client)
        renderers = {name: Renderer(world, camera, backend=name) for name in BACKENDS}
        frames: dict[str, list[RenderedFrame]] = {name: [] for name in BACKENDS}
        shadows: dict[str, list[np.ndarray]] = {name: [] for name in BACKENDS}
        cpu = dict.fromkeys(BACKENDS, 0.0)
        for k in range(poses):
            x, y, yaw = world.gap_pose(world.eval_gap, 1.0 + k * (spec.rows.length - 2.0) / poses)
            sun_rng = np.random.default_rng([spec.seed, k, 1])
            azimuth, elevation = sun_rng.uniform(0, 2 * np.pi), np.radians(sun_rng.uniform(*spec.sky.sun_elevation))
            sun = [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
            for name, renderer in renderers.items():
                rng = np.random.default_rng([spec.seed, k])
                renderer.randomize_appearance(rng)
                started = time.process_time()
                frame = renderer.render(x, y, yaw, rng=rng)
                cpu[name] += time.process_time() - started
                frames[name].append(frame)
                shadows[name].append(shadow_mask(renderer, frame.camera_pose, sun_look(sun, sun_distance)))
    finally:
        p.disconnect(client)
    pairs = list(zip(frames["tiny"], frames["gl"]))
    ious = [mask_iou(a.mask, b.mask) for a, b in pairs]
    errors = np.concatenate([np.abs(a.depth - b.depth)[(a.depth > 0) & (b.depth > 0)] for a, b in pairs])
    figures = FieldAgreement(
        mask_iou_mean=float(np.mean(ious)),
        mask_iou_min=float(np.min(ious)),
        ids_equal=float(np.mean([np.mean(a.body_ids == b.body_ids) for a, b in pairs])),
        depth_median_m=float(np.median(errors)) if errors.size else 0.0,
        depth_p95_m=float(np.percentile(errors, 95)) if errors.size else 0.0,
        rgb_mad=float(np.mean([np.abs(a.rgb.astype(np.int16) - b.rgb).mean() for a, b in pairs])),
        cpu_ms={name: 1000 * cpu[name] / poses for name in BACKENDS},
        shadow_share={name: float(np.mean(shadows[name])) for name in BACKENDS},
        shadow_iou=mask_iou(np.stack(shadows["tiny"]), np.stack(shadows["gl"])),
    )
    return figures, side_by_side(*pairs[poses // 2], label=spec.name)


def side_by_side(reference: RenderedFrame, fast: RenderedFrame, label: str = "") -> np.ndarray:
    """One sheet row: TinyRenderer RGB | gl RGB | masks (grey both, red TinyRenderer only, green gl
    only) | TinyRenderer depth | gl depth."""
    from segmin.data.overlay import depth_colours

    masks = np.zeros_like(reference.rgb)
    masks[reference.mask & fast.mask] = (150, 150, 150)
    masks[reference.mask & ~fast.mask] = (255, 0, 0)
    masks[fast.mask & ~reference.mask] = (0, 255, 0)
    tiles = [reference.rgb, fast.rgb, masks, depth_colours(reference.depth), depth_colours(fast.depth)]
    row = np.concatenate(tiles, axis=1)
    width = reference.rgb.shape[1]
    for k, title in enumerate((f"tiny {label}", "gl", "masks", "tiny depth", "gl depth")):
        origin = (k * width + 3, 12)
        cv2.putText(row, title, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(row, title, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
    return row


def bench_render_agreement(options: AgreementOptions) -> dict[str, FieldAgreement]:
    """Print one line per field as it is measured and write the sheet; returns the figures."""
    from segmin.common.atomic import write_bytes
    from segmin.common.machine import load_average
    from segmin.data.synth.spec import load_world_spec

    specs = {name: load_world_spec(name) for name in options.fields}  # a bad name fails before the table
    cam = options.camera
    print(
        f"python -m benchmarks render-agreement: gl against tiny (TinyRenderer), {cam.width}x{cam.height}, "
        f"{options.poses} poses per field, shadows with the sun {options.sun_distance:g} m away, {load_average()}"
    )
    print(
        f"{'field':20s} {'IoU mean':>9s} {'IoU min':>8s} {'ids =':>7s} {'depth med':>10s} {'depth p95':>10s} "
        f"{'RGB MAD':>8s} {'tiny ms':>8s} {'gl ms':>7s} {'ratio':>6s} {'shadow tiny':>11s} {'gl':>5s} {'IoU':>5s}"
    )
    results, rows = {}, []
    for name, spec in specs.items():
        figures, row = field_agreement(spec, cam, options.poses, options.sun_distance)
        results[name], ms = figures, figures.cpu_ms
        rows.append(row)
        print(
            f"{name:20s} {figures.mask_iou_mean:9.4f} {figures.mask_iou_min:8.4f} {figures.ids_equal:7.4f} "
            f"{figures.depth_median_m:9.5f}m {figures.depth_p95_m:9.5f}m {figures.rgb_mad:8.2f} "
            f"{ms['tiny']:8.1f} {ms['gl']:7.1f} {ms['tiny'] / max(ms['gl'], 1e-9):5.1f}x "
            f"{figures.shadow_share['tiny']:11.3f} {figures.shadow_share['gl']:5.3f} {figures.shadow_iou:5.3f}",
            flush=True,
        )
    print("ms: CPU milliseconds of render() per frame, all threads (independent of other load)")
    print("shadow: share of pixels the shadows darken, per backend, and the IoU of the two shadow masks")
    if options.sheet is not None:
        ok, png = cv2.imencode(".png", np.concatenate(rows, axis=0)[:, :, ::-1])
        if not ok:
            raise RuntimeError("PNG encoding failed")
        write_bytes(options.sheet, png.tobytes())
        print(f"wrote {options.sheet}")
    return results
