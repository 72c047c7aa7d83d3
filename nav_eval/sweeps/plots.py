"""Figures of a robustness sweep (matplotlib, Agg backend).

- `sweep_<parameter>.png`: success rate (left) and MAE mean ± sample std over runs (right)
  against the parameter's values, one line per method;
- `envelope.png`: the success-rate panel of every parameter in one grid, the overview a user
  reads before deploying.

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


def _success_panel(ax: Any, plan: Any, name: str, rows: list[dict]) -> None:
    labels = list(dict.fromkeys(r["value"] for r in rows))
    x = np.arange(len(labels))
    methods = plan.spec.methods
    for i, method in enumerate(methods):
        nudge = (i - (len(methods) - 1) / 2) * 0.04
        ax.plot(
            x + nudge, 100 * _series(rows, method, "success_rate"), "o-", color=COLOURS.get(method, "k"), label=method
        )
    ax.set_xticks(x, labels)
    ax.set_ylim(-5, 105)
    ax.set_xlabel(_axis_label(name))
    ax.set_ylabel("success %")
    ax.grid(alpha=0.3)


def parameter_figure(path: Path, plan: Any, name: str, rows: list[dict]) -> None:
    """Success rate and MAE (mean ± std) against the values of one parameter."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 3.8))
    _success_panel(left, plan, name, rows)
    labels = list(dict.fromkeys(r["value"] for r in rows))
    x = np.arange(len(labels))
    methods = plan.spec.methods
    for i, method in enumerate(methods):
        nudge = (i - (len(methods) - 1) / 2) * 0.08
        right.errorbar(
            x + nudge,
            _series(rows, method, "mae_mean"),
            yerr=_series(rows, method, "mae_std"),
            fmt="o-",
            capsize=3,
            color=COLOURS.get(method, "k"),
            label=method,
        )
    right.set_xticks(x, labels)
    right.set_xlabel(_axis_label(name))
    right.set_ylabel("MAE m (mean ± std over runs)")
    right.set_ylim(bottom=0)
    right.grid(alpha=0.3)
    right.legend(fontsize=8)
    runs = plan.spec.runs
    fig.suptitle(
        f"{plan.name}: {plan.base_label}, {name} ({plan.base_config.robot.model} robot, "
        f"{runs} run{'s' if runs > 1 else ''} per value)",
        fontsize=10,
    )
    save_figure(fig, path)


def envelope_figure(path: Path, plan: Any, rows: list[dict]) -> None:
    """The success-rate panel of every parameter, in one grid."""
    names = list(plan.spec.parameters)
    cols = min(4, len(names))
    n_rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(n_rows, cols, figsize=(3.6 * cols, 2.9 * n_rows), squeeze=False)
    for ax, name in zip(axes.flat, names):
        _success_panel(ax, plan, name, [r for r in rows if r["parameter"] == name])
    for ax in list(axes.flat)[len(names) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(
        f"{plan.name}: success rate per parameter ({plan.base_label}, {plan.base_config.robot.model} "
        f"robot, {plan.spec.runs} run(s) per value, {plan.base_config.run.length_m:g} m)",
        fontsize=10,
    )
    fig.tight_layout()
    save_figure(fig, path)
