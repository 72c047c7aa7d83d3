"""Robustness sweeps, the outputs: sweep.csv, summary.md and the figures (all written atomically).

One row per (parameter, value, method): runs, successes, success rate, and mean ± sample std of
MAE over all runs (failed ones up to where they ended, as in nav-eval's table), clearance time
over the successful ones, v_avg, and the failure reasons. A parameter "breaks" a method at the
first value, in the spec's order, where fewer than all runs succeed.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from pathlib import Path
from typing import Any

from segmin.common.atomic import write_text
from segmin.common.figures import format_mean_std
from segmin.nav_eval.evaluation.report import summarise
from segmin.nav_eval.sweeps.spec import PARAMETERS, SweepPlan

CSV_COLUMNS = (
    "parameter",
    "value",
    "unit",
    "method",
    "runs",
    "successes",
    "success_rate",
    "mae_mean",
    "mae_std",
    "clearance_mean",
    "clearance_std",
    "v_avg_mean",
    "failures",
    "field",
)
HOLDS = "holds"  # the break-point cell of a method that succeeds at every value


def summarise_sweep(plan: SweepPlan, keys: list[list[tuple[str, str]]], results: dict[str, Any]) -> list[dict]:
    """The rows of sweep.csv, in spec order (parameters, values, methods)."""
    rows = []
    for variant, pairs in zip(plan.variants, keys):
        for method in plan.spec.methods:
            done = [
                dataclasses.replace(results[key], field=variant.label)
                for m, key in pairs
                if m == method and key in results
            ]
            row = {
                "parameter": variant.parameter,
                "value": variant.label,
                "unit": PARAMETERS[variant.parameter].unit,
                "method": method,
                "runs": len(done),
                "successes": 0,
                "success_rate": math.nan,
                "mae_mean": math.nan,
                "mae_std": math.nan,
                "clearance_mean": math.nan,
                "clearance_std": math.nan,
                "v_avg_mean": math.nan,
                "failures": "",
                "field": _field_name(results, pairs),
            }
            if done:  # runs that raised are missing; none left: the row stays empty
                entry = summarise(done)[0]
                row.update(
                    successes=entry["successes"],
                    success_rate=entry["successes"] / entry["runs"],
                    mae_mean=entry["mae"][0],
                    mae_std=entry["mae"][1],
                    clearance_mean=entry["clearance_time"][0],
                    clearance_std=entry["clearance_time"][1],
                    v_avg_mean=entry["v_avg"][0],
                    failures=", ".join(f"{k} x{v}" for k, v in sorted(entry["reasons"].items())),
                )
            rows.append(row)
    return rows


def _field_name(results: dict[str, Any], pairs: list[tuple[str, str]]) -> str:
    """The field the variant's runs drove (the base, or the variant's world file stem)."""
    return next((results[key].field for _, key in pairs if key in results), "")


def breaks(plan: SweepPlan, rows: list[dict]) -> dict[str, dict[str, str]]:
    """parameter -> method -> the first value (spec order) with success < 100 %, or HOLDS."""
    table: dict[str, dict[str, str]] = {}
    for name in plan.spec.parameters:
        table[name] = {}
        for method in plan.spec.methods:
            failing = [
                r["value"]
                for r in rows
                if r["parameter"] == name and r["method"] == method and r["runs"] and r["successes"] < r["runs"]
            ]
            table[name][method] = failing[0] if failing else HOLDS
    return table


def sweep_csv(rows: list[dict]) -> str:
    return rows_csv(rows, CSV_COLUMNS)


def rows_csv(rows: list[dict], columns: tuple[str, ...]) -> str:
    """`rows` as CSV with `columns`, NaN as an empty cell (a figure no run gave)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()})
    return buffer.getvalue()


def summary_markdown(
    plan: SweepPlan, rows: list[dict], figures: dict[str, str], *, executed: int, reused: int, errored: int
) -> str:
    """summary.md: the break points first (what a user reads before deploying), then each parameter."""
    spec, config = plan.spec, plan.base_config
    methods = spec.methods
    lines = [
        f"# Robustness sweep `{plan.name}`",
        "",
        f"Base field `{plan.base_label}`, model `{spec.model}`, robot `{config.robot.model}`, methods "
        f"{', '.join(methods)}; {spec.runs} seeded run(s) per value and method (the same seeds for every value), "
        f"{config.run.length_m:g} m per run, time limit {config.run.time_limit_s:g} s. Runs this call: "
        f"{executed} executed, {reused} reused from earlier calls"
        + (f", {errored} raised (not counted)" if errored else "")
        + ".",
        "",
        "## Where each parameter breaks",
        "",
        "First value, in the order swept, at which a method fails at least one run (`holds`: never).",
        "",
        "| parameter | unit | values | " + " | ".join(methods) + " |",
        "|---" * (3 + len(methods)) + "|",
    ]
    table = breaks(plan, rows)
    for name, _values in spec.parameters.items():
        labels = ", ".join(str(r["value"]) for r in rows if r["parameter"] == name and r["method"] == methods[0])
        lines.append(
            f"| {name} | {PARAMETERS[name].unit or '–'} | {labels} | "
            + " | ".join(table[name][m] for m in methods)
            + " |"
        )
    lines.append("")
    for name in spec.parameters:
        p = PARAMETERS[name]
        lines += [
            f"## {name}",
            "",
            f"{p.meaning} (`{p.key}`{', ' + p.unit if p.unit else ''}).",
            "",
            "| value | " + " | ".join(f"{m} success | {m} MAE m" for m in methods) + " |",
            "|---" * (1 + 2 * len(methods)) + "|",
        ]
        by_value: dict[str, dict[str, dict]] = {}
        for r in rows:
            if r["parameter"] == name:
                by_value.setdefault(r["value"], {})[r["method"]] = r
        for value, per_method in by_value.items():
            cells = []
            for m in methods:
                r = per_method[m]
                fails = f" ({r['failures']})" if r["failures"] else ""
                cells += [f"{r['successes']}/{r['runs']}{fails}", format_mean_std(r["mae_mean"], r["mae_std"])]
            lines.append(f"| {value} | " + " | ".join(cells) + " |")
        if name in figures:
            lines += ["", f"![{name}]({figures[name]})"]
        lines.append("")
    return "\n".join(lines).rstrip("\n") + "\n"


def write_sweep_outputs(
    out: Path, plan: SweepPlan, rows: list[dict], *, plots: bool, executed: int, reused: int, errored: int
) -> None:
    """sweep.csv, one figure per parameter plus envelope.png, and summary.md."""
    write_text(out / "sweep.csv", sweep_csv(rows))
    figures: dict[str, str] = {}
    if plots:
        from segmin.nav_eval.sweeps.plots import envelope_figure, parameter_figure

        for name in plan.spec.parameters:
            figures[name] = f"sweep_{name}.png"
            parameter_figure(out / figures[name], plan, name, [r for r in rows if r["parameter"] == name])
        envelope_figure(out / "envelope.png", plan, rows)
    write_text(
        out / "summary.md", summary_markdown(plan, rows, figures, executed=executed, reused=reused, errored=errored)
    )
