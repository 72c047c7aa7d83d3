"""Evaluation outputs: results.csv / results.json (one row per run) and report.md (Table 3 style).

All files are written atomically (segmin.common.atomic). The report puts the paper's Table 3 numbers
(Gazebo, 3 runs, 20 m) beside ours so the comparison is one glance; mean +- std are over runs
(sample std, ddof = 1); clearance time is averaged over successful runs only, every other metric
over all runs (failed runs included, up to where they ended).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.atomic import write_bytes, write_json, write_text
from segmin.common.figures import format_mean_std
from segmin.nav_eval.evaluation.metrics import METRIC_KEYS, mean_std
from segmin.nav_eval.sim.faults import FAULT_METRIC_KEYS

# What one evaluation writes to its --out (the figures and videos beside them are named per field).
RESULT_FILES: tuple[str, ...] = ("results.csv", "results.json", "trajectories.json", "report.md")

# Paper Table 3 (reference-facts section 2): clearance s, MAE m, MSE m^2, heading rad, v_avg, omega std.
PAPER_TABLE3: dict[tuple[str, str], tuple[float, ...]] = {
    ("high_trees", "segmin"): (40.41, 0.265, 0.084, 0.079, 0.487, 0.054),
    ("high_trees", "segmind"): (40.44, 0.174, 0.036, 0.048, 0.484, 0.063),
    ("pear_field", "segmin"): (42.06, 0.034, 0.002, 0.013, 0.483, 0.108),
    ("pear_field", "segmind"): (42.26, 0.031, 0.002, 0.016, 0.477, 0.026),
    ("pergola_vineyard", "segmin"): (40.86, 0.077, 0.011, 0.030, 0.479, 0.174),
    ("pergola_vineyard", "segmind"): (41.14, 0.097, 0.015, 0.029, 0.475, 0.204),
    ("straight_vineyard", "segmin"): (50.51, 0.105, 0.014, 0.033, 0.487, 0.079),
    ("straight_vineyard", "segmind"): (50.63, 0.110, 0.018, 0.026, 0.486, 0.088),
    ("straight_vineyard", "segzeros"): (53.70, 0.138, 0.024, 0.027, 0.457, 0.089),
    ("curved_vineyard", "segmin"): (53.32, 0.115, 0.017, 0.036, 0.487, 0.088),
    ("curved_vineyard", "segmind"): (51.44, 0.093, 0.012, 0.015, 0.484, 0.065),
    ("curved_vineyard", "segzeros"): (71.05, 0.108, 0.019, 0.045, 0.395, 0.114),
}
TABLE_METRICS = ("clearance_time", "mae", "mse", "heading_avg", "v_avg", "omega_std")
TABLE_HEADERS = ("clearance s", "MAE m", "MSE m²", "cum. heading rad", "v_avg m/s", "ω std rad/s")
CSV_COLUMNS = (
    "field",
    "method",
    "run",
    "seed",
    "model",
    "success",
    "reason",
    *METRIC_KEYS,
    "goal_m",
    "sim_time",
    "wall_time",
    "depth_threshold",
    "gap",
    "start_x",
    "start_y",
    "start_yaw",
    *FAULT_METRIC_KEYS,
    "error",
    "config",
)


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return _clean(value.item())
    return value


def write_results(out: str | Path, results: list[Any], meta: dict[str, Any]) -> None:
    """results.json (meta + rows, each with its seed and the config) and results.csv."""
    out = Path(out)
    config_json = json.dumps(meta.get("config", {}), sort_keys=True)
    rows = [{k: _clean(v) for k, v in r.row().items()} for r in results]
    write_json(
        out / "results.json",
        {**dict(meta.items()), "rows": [{**row, "config": meta.get("config", {})} for row in rows]},
    )
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_COLUMNS, extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow(
            {
                **{k: ("" if v is None else v) for k, v in row.items()},
                "config": config_json,
                "error": (row.get("error") or "").splitlines()[0] if row.get("error") else "",
            }
        )
    write_text(out / "results.csv", buffer.getvalue())


def summarise(results: list[Any]) -> list[dict[str, Any]]:
    """One entry per (field, method): success count, failure reasons, mean/std of each metric."""
    groups: dict[tuple[str, str], list[Any]] = {}
    for r in results:
        groups.setdefault((r.field, r.method), []).append(r)
    summary = []
    for (field, method), rs in groups.items():
        entry: dict[str, Any] = {
            "field": field,
            "method": method,
            "runs": len(rs),
            "successes": sum(bool(r.success) for r in rs),
            "reasons": dict(Counter(r.reason for r in rs if not r.success)),
        }
        for key in TABLE_METRICS + ("min_plant_distance", "collisions"):
            values = [getattr(r, key) for r in rs if key != "clearance_time" or r.success]
            entry[key] = mean_std([float(v) for v in values])
        entry["paper"] = PAPER_TABLE3.get((field, method))
        summary.append(entry)
    return summary


def table3_markdown(results: list[Any]) -> str:
    """Markdown table: per field and method, ours (mean ± std) with the paper's value in brackets."""
    digits = {"clearance_time": 2, "mae": 3, "mse": 3, "heading_avg": 3, "v_avg": 3, "omega_std": 3}
    lines = [
        "| field | method | success | " + " | ".join(TABLE_HEADERS) + " | min plant dist m | failures |",
        "|---" * (len(TABLE_HEADERS) + 5) + "|",
    ]
    for e in summarise(results):
        cells = []
        for i, key in enumerate(TABLE_METRICS):
            ours = format_mean_std(e[key][0], e[key][1], digits[key])
            paper = f" ({e['paper'][i]:.{digits[key]}f})" if e["paper"] else ""
            cells.append(ours + paper)
        reasons = ", ".join(f"{k} x{v}" for k, v in sorted(e["reasons"].items())) or "–"
        lines.append(
            f"| {e['field']} | {e['method']} | {e['successes']}/{e['runs']} | "
            + " | ".join(cells)
            + f" | {format_mean_std(e['min_plant_distance'][0], e['min_plant_distance'][1])} | {reasons} |"
        )
    return "\n".join(lines) + "\n"


def faults_markdown(results: list[Any], faults: list[Any]) -> str:
    """The injected faults (`config.faults`) and, per field and method, the worst of each fault
    metric over the runs ("never": a run in which the runtime did not stop, or did not drive again)."""
    injected = "; ".join(
        f"{f.kind} {f.start_s:g}-{f.end_s:g} s"
        + ("" if f.region == "all" else f", {f.region} half")
        + (f", share {f.share:g}" if f.kind == "depth_dropout" else "")
        for f in faults
    )
    lines = [
        "## Sensor faults",
        "",
        f"Injected in every run: {injected}. Worst over the runs: seconds from a fault's start to the stop, "
        "metres driven blind, seconds from its end to driving again.",
        "",
        "| field | method | stop s | blind m | resume s |",
        "|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str], list[Any]] = {}
    for r in results:
        groups.setdefault((r.field, r.method), []).append(r)
    for (field, method), rs in groups.items():
        cells = []
        for key in FAULT_METRIC_KEYS:
            values = [float(getattr(r, key)) for r in rs]
            cells.append("never" if any(math.isnan(v) for v in values) else f"{max(values):.2f}")
        lines.append(f"| {field} | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_report(
    out: str | Path, results: list[Any], meta: dict[str, Any], fields: list[str], config: Any, *, plots: bool = True
) -> None:
    """report.md (table, failures, figure links), the trajectories, and the figures."""
    out = Path(out)
    write_results(out, results, meta)
    trajectories = {
        f"{r.field}/{r.method}/{r.run}": r.trajectory.to_dict() for r in results if r.trajectory is not None
    }
    write_bytes(out / "trajectories.json", json.dumps(trajectories).encode())
    figures: list[str] = []
    if plots:
        from segmin.nav_eval.evaluation.plots import make_field_figures

        figures = make_field_figures(out, results, fields, config, meta["model"])
    errors = [r for r in results if r.reason == "error"]
    lines = [
        "# Closed-loop navigation evaluation",
        "",
        f"Model: `{meta['model']}`; fields: {', '.join(meta['fields'])}; methods: {', '.join(meta['methods'])}; "
        f"runs per field and method: {meta['runs']}; base seed {meta['seed']}.",
        "",
        "Ours: mean ± std over runs (clearance over successful runs only); the paper's Table 3 value "
        "(Gazebo) in brackets.",
        "",
        table3_markdown(results),
    ]
    if config.faults:
        lines += [faults_markdown(results, config.faults)]
    if errors:
        lines += ["## Runs that raised", ""]
        lines += [
            f"- {r.field} / {r.method} / run {r.run}: `{r.error.splitlines()[0] if r.error else '?'}`" for r in errors
        ]
        lines.append("")
    if figures:
        lines += ["## Figures", ""] + [f"![{Path(f).stem}]({f})" for f in figures] + [""]
    write_text(out / "report.md", "\n".join(lines))
