"""The figure of `segmin replay`: target column and commands over time (needs the [sim] extra)."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from segmin.common.atomic import write_bytes


def plot_commands(path: Path, rows: list[tuple[float, float, float, float | None, bool]]) -> None:
    """Three stacked panels sharing the time axis; invalid commands (stops) marked in red."""
    t = np.array([r[0] for r in rows], dtype=float)
    column = np.array([np.nan if r[3] is None else r[3] for r in rows], dtype=float)
    v = np.array([r[1] for r in rows], dtype=float)
    omega = np.array([r[2] for r in rows], dtype=float)
    stops = np.array([not r[4] for r in rows], dtype=bool)
    fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
    for ax, values, label in zip(axes, (column, v, omega), ("target column (px)", "v (m/s)", "omega (rad/s)")):
        ax.step(t, values, where="post")
        if stops.any():
            ax.plot(t[stops], np.nan_to_num(values[stops]), "rx", label="stop")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    write_bytes(path, buffer.getvalue())
