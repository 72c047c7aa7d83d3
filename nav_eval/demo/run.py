"""`segmin navigate-demo`: SegMin, SegMinD and SegZeros on analytic scenes, drawn like the paper's Figure 4.

For each scene the figure shows the vegetation mask, the masked depth (what survives the depth
cut), and the SegMin and SegMinD histograms with the chosen column marked; the SegZeros target
(or its absence) is marked on the SegMin panel. A text summary lists every command.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segmin.common.atomic import atomic_path, write_text
from segmin.common.outputs import make_dirs
from segmin.nav_eval.demo.scenes import DEMO_SCENES, DemoScene, render_scene
from segmin.nav_eval.runtime.methods import PAPER_METHODS as METHODS
from segmin.nav_eval.runtime.navigator import (
    Navigator,
    NavigatorConfig,
    column_histogram,
    moving_average,
)


@dataclass(frozen=True)
class DemoResult:
    """One method on one scene: the target and the command once the EMA has settled."""

    scene: str
    method: str
    target_column: float | None
    v: float
    omega: float
    valid: bool


def run_demo(
    out_dir: str | Path, *, size: int = 224, settle_steps: int = 12, figure: bool = True
) -> tuple[Path | None, Path, list[DemoResult]]:
    """Render the demo scenes, run every method, write `summary.txt` and (with `figure`) `navigator_demo.png`.

    The figure needs matplotlib (the `[sim]` extra); the summary needs only numpy, so the robot
    runtime install can run the demo with `figure=False`.
    """
    out_dir = Path(out_dir)
    make_dirs(out_dir, "--out")
    frames = [(scene, *render_scene(scene, size=size)) for scene in DEMO_SCENES]
    results = [
        _settled_command(scene, mask, depth, method, settle_steps)
        for scene, mask, depth in frames
        for method in METHODS
    ]
    figure_path = out_dir / "navigator_demo.png" if figure else None
    if figure_path is not None:
        _draw_figure(frames, results, figure_path)
    summary_path = out_dir / "summary.txt"
    write_text(summary_path, format_summary(results, size))
    return figure_path, summary_path, results


def _settled_command(scene: DemoScene, mask: np.ndarray, depth: np.ndarray, method: str, steps: int) -> DemoResult:
    """Feed the same frame `steps` times so fusion and EMA settle on the frame's own command."""
    navigator = Navigator(NavigatorConfig(method=method, depth_threshold=scene.depth_threshold))
    for _ in range(steps):
        command = navigator.step(mask, depth)
    return DemoResult(scene.name, method, command.target_column, command.v, command.omega, command.valid)


def format_summary(results: list[DemoResult], width: int) -> str:
    """A plain-text table of the commands, one line per scene and method."""
    lines = [f"segmin navigator demo: {width} x {width} frames, commands after the EMA settled", ""]
    lines.append(f"{'scene':<34} {'method':<9} {'target col':>10} {'v m/s':>7} {'omega rad/s':>11}  note")
    for r in results:
        target = f"{r.target_column:10.1f}" if r.target_column is not None else f"{'none':>10}"
        note = "" if r.valid else "no free corridor: stop"
        lines.append(f"{r.scene:<34} {r.method:<9} {target} {r.v:7.3f} {r.omega:11.3f}  {note}")
    return "\n".join(lines) + "\n"


def _draw_figure(frames: list, results: list[DemoResult], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by_key = {(r.scene, r.method): r for r in results}
    fig, axes = plt.subplots(len(frames), 4, figsize=(15, 3.3 * len(frames)), squeeze=False)
    for row, (scene, mask, depth) in enumerate(frames):
        threshold = scene.depth_threshold
        near = mask & (depth > 0) & (depth <= threshold)
        masked_depth = np.where(near, depth, np.nan)
        axes[row, 0].imshow(mask, cmap="Greens", vmin=0, vmax=1)
        axes[row, 0].set_title("vegetation mask")
        axes[row, 0].set_ylabel(scene.name, fontsize=10)
        im = axes[row, 1].imshow(masked_depth, cmap="viridis_r", vmin=0, vmax=threshold)
        axes[row, 1].set_title(f"masked depth (<= {threshold:g} m)")
        fig.colorbar(im, ax=axes[row, 1], fraction=0.046, label="m")
        for ax in axes[row, :2]:
            ax.set_xticks([])
            ax.set_yticks([])
        for col, method in ((2, "segmin"), (3, "segmind")):
            ax = axes[row, col]
            raw = column_histogram(mask, depth, method=method, depth_threshold=threshold)
            smooth = moving_average(raw, 11)
            ax.plot(raw, color="0.7", lw=0.8, label="column sums")
            ax.plot(smooth, color="tab:blue" if method == "segmin" else "tab:red", lw=1.6, label="moving average")
            result = by_key[(scene.name, method)]
            ax.axvline(result.target_column, color="k", ls="--", lw=1.2, label=f"x_h = {result.target_column:.1f}")
            ax.axvline((mask.shape[1] - 1) / 2, color="0.5", ls=":", lw=1.0)
            if method == "segmin":
                zeros = by_key[(scene.name, "segzeros")]
                if zeros.target_column is not None:
                    ax.axvline(
                        zeros.target_column, color="tab:orange", lw=1.2, label=f"SegZeros {zeros.target_column:.1f}"
                    )
                else:
                    ax.text(
                        0.02, 0.92, "SegZeros: no free corridor", transform=ax.transAxes, color="tab:orange", fontsize=8
                    )
            ax.set_xlim(0, mask.shape[1] - 1)
            ax.set_title(
                f"{'SegMin' if method == 'segmin' else 'SegMinD'}: v={result.v:.2f}, omega={result.omega:+.2f}"
            )
            ax.set_xlabel("image column")
            ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
