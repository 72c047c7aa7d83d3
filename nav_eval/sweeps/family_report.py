"""Families of worlds, the outputs: each family's mean MAE with its 95 % interval, the verdicts, the choice.

The unit of a family is the world, not the run: runs in one world share its plants, gaps and
terrain, so they are averaged first, and the family's mean is the mean of its world means. The
interval is Student's t over those world means (mean ± t_{0.975, n-1} s / sqrt(n), n worlds):
with 6 worlds a percentile bootstrap resamples only 6 values and gives intervals too narrow,
while t widens with the few worlds there are (it assumes the world means roughly normal; a
skewed family shows it as a mean far from its median world). Failed runs count with their MAE up
to where they ended, as in nav-eval's table, and are listed apart: a setting that loses a run is
not chosen whatever its mean.

A setting meets the targets when, for every method it drives, every family's mean is below its
target: the paper's `paper_method` MAE where the paper has the field, else `sloped_within` times
the same setting's `flat_reference` family mean; and no run was lost. Per robot, the choice is
the setting that meets them with the most margin in its tightest family (the smallest largest
mean / target).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.atomic import write_text
from segmin.nav_eval.evaluation.metrics import mean_std
from segmin.nav_eval.sweeps.family_spec import WORLD_SEED_STRIDE, FamilyPlan, paper_mae
from segmin.nav_eval.sweeps.keyed_runs import KeyedOutcome
from segmin.nav_eval.sweeps.report import rows_csv

# Two-sided 95 % critical values of Student's t, t_{0.975, df}, for df = 1..30 (standard tables).
T_975 = (
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
    2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
    2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
)  # fmt: skip
Z_975 = 1.959964

CSV_COLUMNS = (
    "setting",
    "robot",
    "method",
    "family",
    "worlds",
    "runs",
    "successes",
    "mae_mean",
    "mae_low",
    "mae_high",
    "target",
    "target_from",
    "below_target",
    "failures",
)


def t_critical(df: int) -> float:
    """t_{0.975, df}: the table up to 30, then the Cornish-Fisher expansion (error < 1e-4 there)."""
    if df < 1:
        raise ValueError(f"a t interval needs df >= 1, got {df}")
    if df <= len(T_975):
        return T_975[df - 1]
    z = Z_975
    return z + (z**3 + z) / (4 * df) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * df**2)


def t_interval(values: Iterable[float]) -> tuple[float, float, float]:
    """(mean, low, high): the 95 % t interval of the mean of the finite `values`; low and high are
    NaN with fewer than two values (no spread to measure)."""
    mean, std, n = mean_std(list(values))
    if n < 2:
        return mean, math.nan, math.nan
    half = t_critical(n - 1) * std / math.sqrt(n)
    return mean, mean - half, mean + half


@dataclasses.dataclass
class FamilyRun:
    """One run of a family comparison: which setting, family and world drove it, and its result."""

    setting: str
    family: str
    world_seed: int
    result: Any  # RunResult: method, success, reason, mae


def summarise_families(runs: list[FamilyRun], robots: dict[str, str]) -> list[dict[str, Any]]:
    """One row per (setting, method, family), in the order the runs first name them: worlds,
    runs, successes, the mean of the world means of MAE and its 95 % t interval, the failures."""
    groups: dict[tuple[str, str, str], dict[int, list[Any]]] = {}
    for run in runs:
        worlds = groups.setdefault((run.setting, run.result.method, run.family), {})
        worlds.setdefault(run.world_seed, []).append(run.result)
    rows = []
    for (setting, method, family), worlds in groups.items():
        results = [r for rs in worlds.values() for r in rs]
        world_means = [float(np.mean([r.mae for r in rs])) for rs in worlds.values()]
        mean, low, high = t_interval(world_means)
        failures: dict[str, int] = {}
        for r in results:
            if not r.success:
                failures[r.reason] = failures.get(r.reason, 0) + 1
        rows.append(
            {
                "setting": setting,
                "robot": robots[setting],
                "method": method,
                "family": family,
                "worlds": len(worlds),
                "runs": len(results),
                "successes": sum(bool(r.success) for r in results),
                "mae_mean": mean,
                "mae_low": low,
                "mae_high": high,
                "failures": ", ".join(f"{k} x{v}" for k, v in sorted(failures.items())),
            }
        )
    return rows


@dataclasses.dataclass
class Verdict:
    """Whether a (setting, method) meets every target, why not, and its tightest mean / target."""

    meets: bool
    misses: list[str]
    worst_ratio: float


def judge(
    rows: list[dict[str, Any]], paper_method: str, flat_reference: str, sloped_within: float
) -> dict[tuple[str, str], Verdict]:
    """Add each row's target and whether its mean is below it; return each (setting, method)'s
    verdict. A family without a paper figure is held to `sloped_within` x the same setting's and
    method's `flat_reference` mean."""
    reference = {(r["setting"], r["method"]): r["mae_mean"] for r in rows if r["family"] == flat_reference}
    verdicts: dict[tuple[str, str], Verdict] = {}
    for row in rows:
        paper = paper_mae(paper_method, row["family"])
        if paper is not None:
            row["target"], row["target_from"] = paper, f"paper {paper_method}"
        else:
            flat = reference.get((row["setting"], row["method"]), math.nan)
            row["target"], row["target_from"] = sloped_within * flat, f"{sloped_within:g}x {flat_reference}"
        row["below_target"] = bool(row["mae_mean"] < row["target"])
        verdict = verdicts.setdefault((row["setting"], row["method"]), Verdict(True, [], 0.0))
        if not row["below_target"]:
            verdict.misses.append(f"{row['family']} {_mm(row['mae_mean'])} >= {_mm(row['target'])} mm")
        if row["successes"] < row["runs"]:
            verdict.misses.append(f"{row['family']} lost {row['runs'] - row['successes']} run(s)")
        ratio = row["mae_mean"] / row["target"] if row["target"] > 0 else math.inf
        verdict.worst_ratio = max(verdict.worst_ratio, ratio if math.isfinite(ratio) else math.inf)
        verdict.meets = not verdict.misses
    return verdicts


def choose(rows: list[dict[str, Any]], verdicts: dict[tuple[str, str], Verdict], method: str) -> dict[str, str | None]:
    """Per robot, the setting whose `method` meets every target with the smallest worst ratio
    (None: no setting of that robot meets them)."""
    robots = {r["setting"]: r["robot"] for r in rows}
    choice: dict[str, str | None] = {}
    for robot in dict.fromkeys(robots.values()):
        meeting = [
            (verdicts[(s, method)].worst_ratio, s)
            for s, rb in robots.items()
            if rb == robot and (s, method) in verdicts and verdicts[(s, method)].meets
        ]
        choice[robot] = min(meeting)[1] if meeting else None
    return choice


def _mm(value: float) -> str:
    return "n/a" if math.isnan(value) else f"{1000 * value:.1f}"


def families_markdown(
    plan: FamilyPlan, rows: list[dict[str, Any]], verdicts: dict[tuple[str, str], Verdict], ran: KeyedOutcome
) -> str:
    """summary.md: per method, a table of families x settings (mean [95 % interval] mm, runs
    won), the targets beside, then each setting's verdict and the choice per robot."""
    spec, config = plan.spec, plan.base_config
    lines = [
        f"# Families of worlds `{plan.name}`",
        "",
        f"Families {', '.join(dict.fromkeys(m.family for m in plan.members))}, {spec.world_seeds} worlds each "
        f"(the recipe's seed + k x {WORLD_SEED_STRIDE}); {spec.runs} seeded run(s) per world, setting and "
        f"method; model `{spec.model}`, {config.run.length_m:g} m per run. Runs this call: {ran.executed} executed, "
        f"{ran.reused} reused" + (f", {len(ran.errored)} raised (not counted)" if ran.errored else "") + ".",
        "",
        "MAE in mm: the mean of the world means [95 % t interval over the worlds], then runs that "
        f"succeeded. Target: the paper's {spec.paper_method} MAE (Table 3, Gazebo) where the paper has the "
        f"field, else {spec.sloped_within:g}x the same setting's {spec.flat_reference} mean.",
        "",
    ]
    settings = list(spec.settings)
    for method in spec.methods:
        lines += [
            f"## {method}",
            "",
            "| family | target mm | " + " | ".join(f"{s} ({spec.settings[s].robot})" for s in settings) + " |",
            "|---" * (2 + len(settings)) + "|",
        ]
        by_key = {(r["setting"], r["family"]): r for r in rows if r["method"] == method}
        for family in dict.fromkeys(r["family"] for r in rows):
            paper = paper_mae(spec.paper_method, family)
            target = f"{_mm(paper)} (paper)" if paper is not None else f"{spec.sloped_within:g}x {spec.flat_reference}"
            cells = [_cell(by_key.get((s, family))) for s in settings]
            lines.append(f"| {family} | {target} | " + " | ".join(cells) + " |")
        lines += ["", "| setting | robot | meets the targets | misses |", "|---|---|---|---|"]
        for s in settings:
            verdict = verdicts.get((s, method))
            if verdict is not None:
                misses = "; ".join(verdict.misses) or "–"
                lines.append(f"| {s} | {spec.settings[s].robot} | {'yes' if verdict.meets else 'no'} | {misses} |")
        choice = choose(rows, verdicts, method)
        lines += [""] + [
            f"- {robot}: " + (f"**{s}**" if s else "no setting meets every target") for robot, s in choice.items()
        ]
        lines.append("")
    return "\n".join(lines).rstrip("\n") + "\n"


def _cell(row: dict[str, Any] | None) -> str:
    if row is None:
        return "–"
    mark = "" if row["below_target"] else " ✗"
    return (
        f"{_mm(row['mae_mean'])} [{_mm(row['mae_low'])}, {_mm(row['mae_high'])}] {row['successes']}/{row['runs']}{mark}"
    )


def write_family_outputs(
    out: Path,
    plan: FamilyPlan,
    rows: list[dict[str, Any]],
    verdicts: dict[tuple[str, str], Verdict],
    ran: KeyedOutcome,
) -> None:
    """families.csv and summary.md."""
    write_text(out / "families.csv", rows_csv(rows, CSV_COLUMNS))
    write_text(out / "summary.md", families_markdown(plan, rows, verdicts, ran))
