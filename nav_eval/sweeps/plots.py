"""Figures of a robustness sweep (matplotlib, Agg backend).

- `sweep_<parameter>.png`: success rate (left) and MAE mean ± sample std over runs (right)
  against the parameter's values, one line per method;
- `envelope.png`: every parameter in one grid, its success-rate panel over its MAE panel, the
  overview a user reads before deploying.

Values sit at evenly spaced positions in the spec's order (they may be words, such as
'straight' or 'skid_steer'); methods are nudged apart so their error bars do not hide each other.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from segmin.nav_eval.evaluation.plots import COLOURS, save_figure
from segmin.nav_eval.sweeps.spec import PARAMETERS


def _series(rows: list[dict], method: str, key: str) -> np.ndarray:
    return np.array([r[key] for r in rows if r["method"] == method], dtype=float)


def _axis_label(name: str) -> str:
    unit = PARAMETERS[name].unit
    return f"{name} ({unit})" if unit else name


def _values_axis(ax: Any, name: str, rows: list[dict]) -> np.ndarray:
    """Evenly spaced positions for the values (spec order), labelled as written."""
    labels = list(dict.fromkeys(r["value"] for r in rows))
    x = np.arange(len(labels))
    ax.set_xticks(x, labels)
    ax.set_xlabel(_axis_label(name))
    ax.grid(alpha=0.3)
    return x


def _nudge(plan: Any, i: int, step: float) -> float:
    """Methods side by side around each value, so their markers and bars do not hide each other."""
    return (i - (len(plan.spec.methods) - 1) / 2) * step


def _success_panel(ax: Any, plan: Any, name: str, rows: list[dict]) -> None:
    x = _values_axis(ax, name, rows)
    for i, method in enumerate(plan.spec.methods):
        success = 100 * _series(rows, method, "success_rate")
        ax.plot(x + _nudge(plan, i, 0.04), success, "o-", color=COLOURS.get(method, "k"), label=method)
    ax.set_ylim(-5, 105)
    ax.set_ylabel("success %")


def _mae_panel(ax: Any, plan: Any, name: str, rows: list[dict]) -> None:
    x = _values_axis(ax, name, rows)
    for i, method in enumerate(plan.spec.methods):
        ax.errorbar(
            x + _nudge(plan, i, 0.08),
            _series(rows, method, "mae_mean"),
            yerr=_series(rows, method, "mae_std"),
            fmt="o-",
            capsize=3,
            color=COLOURS.get(method, "k"),
            label=method,
        )
    ax.set_ylabel("MAE m (mean ± std)")
    ax.set_ylim(bottom=0)


def _setting(plan: Any) -> str:
    """What every panel of a sweep shares: field, robot, runs per value, run length."""
    runs = plan.spec.runs
    return (
        f"{plan.base_label}, {plan.base_config.robot.model} robot, {runs} run{'s' if runs > 1 else ''} per value, "
        f"{plan.base_config.run.length_m:g} m"
    )


def parameter_figure(path: Path, plan: Any, name: str, rows: list[dict]) -> None:
    """Success rate and MAE (mean ± std) against the values of one parameter."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 3.8))
    _success_panel(left, plan, name, rows)
    _mae_panel(right, plan, name, rows)
    right.legend(fontsize=8)
    fig.suptitle(f"{plan.name}: {name} ({_setting(plan)})", fontsize=10)
    save_figure(fig, path)


def envelope_figure(path: Path, plan: Any, rows: list[dict]) -> None:
    """Every parameter in one grid: its success panel with its MAE panel under it.

    MAE belongs beside success because most parameters never break a method on the shipped
    fields: what they change is how far from the centre it drives, which success alone hides."""
    names = list(plan.spec.parameters)
    cols = min(4, len(names))
    n_rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(2 * n_rows, cols, figsize=(3.6 * cols, 5.2 * n_rows), squeeze=False)
    for k, name in enumerate(names):
        block, col = divmod(k, cols)
        own = [r for r in rows if r["parameter"] == name]
        _success_panel(axes[2 * block, col], plan, name, own)
        _mae_panel(axes[2 * block + 1, col], plan, name, own)
    for k in range(len(names), n_rows * cols):
        block, col = divmod(k, cols)
        axes[2 * block, col].axis("off")
        axes[2 * block + 1, col].axis("off")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"{plan.name}: success rate and MAE per parameter ({_setting(plan)})", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
