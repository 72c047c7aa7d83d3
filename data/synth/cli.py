"""`segmin synth render|preview`."""

from __future__ import annotations

import argparse
from pathlib import Path

from segmin.common.cli_args import NamesThenOverrides, add_executor_options, add_overrides, executor_of, overrides_of


def register(commands, bench) -> None:
    synth = commands.add_parser("synth", help="procedural orchard/vineyard worlds: render datasets, previews")
    sub = synth.add_subparsers(dest="synth_command", metavar="ACTION", required=True)

    r = sub.add_parser("render", help="render RGB + depth + mask frames in the AgriSeg formatted layout")
    _world_args(r)
    r.add_argument("--frames", type=int, required=True, help="number of frames in the whole dataset")
    r.add_argument("--out", type=Path, required=True, help="dataset root (DIR/<domain>/<domain>_<k>/...)")
    r.add_argument("--workers", type=int, default=1, help="parallel render processes (default 1)")
    add_executor_options(r)
    r.add_argument("--shard", default="0/1", help="render only part I of N (frames with id %% N == I)")
    r.add_argument("--overwrite", action="store_true", help="start over instead of resuming")
    r.add_argument("--seed", type=int, default=None, help="dataset seed (default: the world's seed)")
    r.add_argument("--frames-per-subset", type=int, default=1000, help="frames per <domain>_<k> folder")
    r.add_argument("--exact-depth", action="store_true", help="write noise-free depth (default: RealSense-like noise)")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.set_defaults(func=_render)

    pv = sub.add_parser("preview", help="contact sheet (RGB | mask overlay | depth) of a few frames per world")
    pv.add_argument(
        "--world",
        nargs="+",
        required=True,
        action=NamesThenOverrides,
        help="world names or YAML paths (KEY=VALUE tokens after them are overrides)",
    )
    pv.add_argument("--out", type=Path, required=True, help="PNG file to write")
    pv.add_argument("--frames", type=int, default=2, help="frames per world (default 2)")
    pv.add_argument("--size", default="224", help="frame size W or WxH (default 224)")
    add_overrides(pv, example="rows.length=10")
    pv.set_defaults(func=_preview)


def _world_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", required=True, help="world name (configs/worlds/<name>.yaml) or YAML path")
    add_overrides(p, example="rows.length=10")
    p.add_argument("--size", default="224", help="frame size W or WxH (default 224)")


def camera_from_size(size: str):
    """The camera of a `--size` flag: W or WxH pixels (the benchmarks take the same flag)."""
    from segmin.data.synth.camera import CameraModel

    try:
        if "x" in size:
            w, h = (int(v) for v in size.lower().split("x"))
        else:
            w = h = int(size)
    except ValueError as exc:
        raise ValueError(f"--size: expected W or WxH, got {size!r}") from exc
    return CameraModel(width=w, height=h)


def _render(args) -> int:
    from segmin.data.synth.spec import load_world_spec
    from segmin.data.synth.writer import RenderJob, parse_shard, render_dataset

    # --out is checked (and created) by render_dataset, first thing: after the spec and the
    # arguments, so a refused command leaves no empty folder behind.
    spec = load_world_spec(args.world, overrides_of(args))
    job = RenderJob(
        spec=spec,
        out=args.out,
        frames=args.frames,
        camera=camera_from_size(args.size),
        seed=args.seed,
        frames_per_subset=args.frames_per_subset,
        noisy_depth=not args.exact_depth,
        workers=args.workers,
        shard=parse_shard(args.shard),
        overwrite=args.overwrite,
        progress=not args.no_progress,
        executor=executor_of(args),
    )
    summary = render_dataset(job)
    print(
        f"wrote {summary['written']} frames ({summary['skipped']} already done) to {summary['out']} "
        f"in {summary['seconds']:.1f} s: {summary['fps']:.1f} frames/s"
    )
    return 0


def preview_sheet(worlds: list[str], frames: int, camera, overrides=()):
    """Rows of RGB | mask overlay | depth for `frames` poses along each world's evaluation gap."""
    import cv2
    import numpy as np
    import pybullet as p

    from segmin.data.overlay import MAGENTA, depth_colours, tint_mask
    from segmin.data.synth.nets import shade_under_nets
    from segmin.data.synth.render import Renderer
    from segmin.data.synth.spec import load_world_spec
    from segmin.data.synth.world import build_world

    rows = []
    for name in worlds:
        spec = load_world_spec(name, overrides)
        client = p.connect(p.DIRECT)
        try:
            world = build_world(spec, client)
            renderer = Renderer(world, camera)
            gap = world.eval_gap
            for k in range(frames):
                s = 1.0 + k * (spec.rows.length - 4.0) / max(frames, 1)
                x, y, yaw = world.gap_pose(gap, s)
                rng = None if k == 0 else np.random.default_rng([spec.seed, k])
                if rng is not None:
                    renderer.randomize_appearance(rng)
                f = renderer.render(x, y, yaw, rng=rng)
                shade_under_nets(f, world.net_shade, renderer.camera)
                overlay = tint_mask(f.rgb, f.mask, MAGENTA, opacity=0.55)
                row = np.concatenate([f.rgb, overlay, depth_colours(f.depth)], axis=1)
                label = f"{spec.name}  s={s:.0f} m"
                cv2.putText(row, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
                cv2.putText(row, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
                rows.append(row)
        finally:
            p.disconnect(client)
    return np.concatenate(rows, axis=0)


def _preview(args) -> int:
    import cv2

    from segmin.common.atomic import write_bytes
    from segmin.common.outputs import check_output_file

    check_output_file(args.out, "--out")  # before rendering anything
    if args.frames < 1:
        raise ValueError(f"--frames: must be >= 1, got {args.frames}")
    sheet = preview_sheet(args.world, args.frames, camera_from_size(args.size), overrides_of(args))
    ok, png = cv2.imencode(".png", sheet[:, :, ::-1])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    write_bytes(args.out, png.tobytes())
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]}, {len(args.world)} world(s) x {args.frames} frame(s))")
    return 0
