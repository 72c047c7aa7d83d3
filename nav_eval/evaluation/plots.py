"""Figures of the evaluation (matplotlib, Agg backend: no display needed).

Per field:
- `<field>_trajectories.png`: top view (trunks, posts, ground-truth centreline, each method's
  path; run 0 solid, other runs thin) and, below, the lateral deviation along the row, where
  centimetre differences are visible;
- `<field>_histograms.png`: the paper's histogram figure: the camera frame (mask tinted, chosen
  columns marked) | SegMin histogram | SegMinD histogram, of the same frame, rendered on the
  centreline a few metres into the row and segmented by the evaluated segmenter.
With `--video`: `videos/<field>_<method>.mp4` (GIF where no MP4 encoder exists), the camera view with the fused mask and the
chosen column, one frame per command.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from segmin.common.atomic import write_bytes
from segmin.data.overlay import GREEN, tint_mask
from segmin.nav_eval.replay.video import write_video  # noqa: F401  (kept importable from here)
from segmin.nav_eval.sim.track import project_onto_polyline

log = logging.getLogger(__name__)

COLOURS = {"segmin": "tab:red", "segmind": "tab:blue", "segzeros": "tab:orange", "segcorridor": "tab:green"}


def save_figure(fig: Any, path: Path) -> None:
    """Write `fig` as a PNG atomically and close it."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    write_bytes(path, buffer.getvalue())


def trajectory_figure(path: Path, field: str, env: Any, results: list[Any]) -> None:
    """Top view and lateral deviation of every run of one field."""
    fig, (top, lat) = plt.subplots(2, 1, figsize=(11, 7), gridspec_kw={"height_ratios": [1.4, 1]})
    line = env.centreline
    xs = [line[:, 0]] + [r.trajectory.x for r in results if r.trajectory is not None]
    ys = [line[:, 1]] + [r.trajectory.y for r in results if r.trajectory is not None]
    # Show the two rows that border the gap: the centreline +- its free half-width, plus a margin.
    d = np.gradient(line, axis=0)
    normal = np.stack([-d[:, 1], d[:, 0]], 1) / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
    for side in (-1.0, 1.0):
        edge = line + side * (env.half_width + 1.0) * normal
        xs.append(edge[:, 0])
        ys.append(edge[:, 1])
    lo = np.array([min(v.min() for v in xs), min(v.min() for v in ys)]) - 1.0
    hi = np.array([max(v.max() for v in xs), max(v.max() for v in ys)]) + 1.0
    for circles, colour, label in ((env.plants, "saddlebrown", "trunks"), (env.obstacles, "grey", "posts")):
        if len(circles):
            inside = np.all((circles[:, :2] >= lo) & (circles[:, :2] <= hi), axis=1)
            c = circles[inside]
            top.scatter(c[:, 0], c[:, 1], s=np.clip((c[:, 2] * 60) ** 2, 4, 200), c=colour, label=label, zorder=2)
    top.plot(line[:, 0], line[:, 1], "k--", lw=1, label="centreline", zorder=3)
    seen = set()
    for r in results:
        if r.trajectory is None:
            continue
        colour = COLOURS.get(r.method, "k")
        run_label = None if r.method in seen else f"{r.method}"  # one legend entry per method
        seen.add(r.method)
        width = 1.8 if r.run == 0 else 0.8
        top.plot(r.trajectory.x, r.trajectory.y, color=colour, lw=width, label=run_label, zorder=4)
        if not r.success:
            top.plot(r.trajectory.x[-1], r.trajectory.y[-1], "x", color=colour, ms=9, mew=2, zorder=5)
        s, e, _ = project_onto_polyline(np.stack([r.trajectory.x, r.trajectory.y], 1), line)
        lat.plot(s, e, color=colour, lw=width, label=run_label)
    top.set_xlim(lo[0], hi[0])
    top.set_ylim(lo[1], hi[1])
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title(f"{field}: trajectories (x = failed run ends)")
    top.legend(loc="upper right", fontsize=8, ncol=3)
    lat.axhline(0, color="k", lw=0.8, ls="--")
    lat.set_xlabel("distance along the centreline (m)")
    lat.set_ylabel("lateral deviation (m, + left)")
    lat.grid(alpha=0.3)
    save_figure(fig, path)


def histogram_figure(path: Path, field: str, frame: Any, mask: np.ndarray, depth_threshold: float) -> None:
    """RGB (mask tinted, targets marked) | SegMin histogram | SegMinD histogram of one frame."""
    from segmin.nav_eval.runtime.navigator import histogram_minimum, smoothed_histogram

    depth = np.asarray(frame.depth, dtype=np.float32)
    hists, targets = {}, {}
    for method in ("segmin", "segmind"):
        h = smoothed_histogram(mask, depth, method=method, depth_threshold=depth_threshold, smooth_window=11)
        hists[method], targets[method] = h, histogram_minimum(h)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    axes[0].imshow(tint_mask(frame.rgb, mask, GREEN, opacity=0.4))
    for method, x in targets.items():
        axes[0].axvline(x, color=COLOURS[method], lw=2, label=f"{method} target")
    axes[0].set_title(f"{field}: RGB + mask (green)")
    axes[0].legend(fontsize=7, loc="lower right")
    axes[0].axis("off")
    for ax, method in zip(axes[1:], ("segmin", "segmind")):
        h = hists[method]
        ax.bar(np.arange(h.size), h, width=1.0, color=COLOURS[method], alpha=0.7)
        ax.axvline(targets[method], color="k", ls="--", lw=1.2, label=f"min at {targets[method]:.0f}")
        ax.axvline((h.size - 1) / 2, color="grey", ls=":", lw=1, label="image centre")
        ax.set_xlim(0, h.size - 1)
        ax.set_title(f"{'SegMin' if method == 'segmin' else 'SegMinD'} histogram (d_th = {depth_threshold:g} m)")
        ax.set_xlabel("image column")
        ax.legend(fontsize=7)
    axes[1].set_ylabel("near-vegetation pixels (smoothed)")
    axes[2].set_ylabel("depth-weighted sum (smoothed)")
    save_figure(fig, path)


def make_field_figures(out: Path, results: list[Any], fields: list[str], config: Any, model: str) -> list[str]:
    """Both figures for every field; returns their paths relative to `out`. Never raises."""
    from segmin.nav_eval.sim.factories import FieldContext, field_label
    from segmin.nav_eval.sim.row_env import RowEnv

    written: list[str] = []
    segmenters: dict[str, Any] = {}
    for field in fields:
        label = field_label(field)
        try:
            ctx = FieldContext(field, config)
        except Exception as exc:  # the field could not even be built: the rows already say so
            log.warning("nav-eval: no figures for %s: %s: %s", label, type(exc).__name__, exc)
            continue
        try:
            env = RowEnv(ctx.world, ctx.renderer, config, gap=ctx.gap)
            rel = f"{label}_trajectories.png"
            trajectory_figure(out / rel, label, env, [r for r in results if r.field == label])
            written.append(rel)
            rel = f"{label}_histograms.png"
            histogram_for_field(out / rel, label, ctx, env, config, segmenters, model)
            written.append(rel)
        except Exception as exc:  # a figure never sinks the evaluation
            log.warning("nav-eval: figures for %s failed: %s: %s", label, type(exc).__name__, exc)
        finally:
            ctx.close()
    return written


def histogram_for_field(
    path: Path, label: str, ctx: Any, env: Any, config: Any, segmenters: dict[str, Any], model: str
) -> None:
    """Render the centreline view a few metres into the row and draw the histogram figure."""
    from segmin.nav_eval.sim.factories import make_segmenter
    from segmin.nav_eval.sim.row_env import depth_noise_camera
    from segmin.nav_eval.sim.track import point_on_polyline

    if model not in segmenters:
        segmenters[model] = make_segmenter(model)
    s = config.run.start_s + min(4.0, 0.5 * config.run.length_m)
    x, y, yaw = point_on_polyline(env.centreline, s)
    frame = ctx.renderer.render(x, y, yaw, rng=None, noisy_depth=False)
    camera = depth_noise_camera(ctx.renderer, config.perception.depth_noise_scale)
    if config.perception.depth_noise and camera is not None:
        frame.depth = camera.apply_depth_noise(frame.depth, np.random.default_rng(0))
    histogram_figure(path, label, frame, segmenters[model].segment_frame(frame), ctx.depth_threshold)
