"""Families of worlds (`segmin robustness` with a `families:` spec): the family numbers (means of
world means, the t interval), the targets and the choice on hand-made runs; bad specs fail in one
line before any run; the shipped comparison validates; a tiny one runs end to end and resumes."""

from __future__ import annotations

import csv
import dataclasses
import math

import pytest
import yaml
from sweep_helpers import TINY, assert_refused_before_any_run

from segmin.app.cli import main
from segmin.data.synth.spec import load_world_spec
from segmin.nav_eval.evaluation import evaluate
from segmin.nav_eval.evaluation.records import RunResult
from segmin.nav_eval.runtime.corridor.config import CorridorConfig
from segmin.nav_eval.sweeps.families import run_families
from segmin.nav_eval.sweeps.family_report import FamilyRun, choose, judge, summarise_families, t_critical, t_interval
from segmin.nav_eval.sweeps.family_spec import WORLD_SEED_STRIDE, load_family_spec, plan_families


def _run(setting: str, family: str, world_seed: int, mae: float, success: bool = True) -> FamilyRun:
    result = RunResult(
        field=family,
        method="segcorridor",
        run=0,
        seed=0,
        model="oracle",
        success=success,
        reason="success" if success else "left_row",
        mae=mae,
    )
    return FamilyRun(setting, family, world_seed, result)


def test_the_t_interval_is_students_over_the_values() -> None:
    values = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    mean, low, high = t_interval(values)
    half = 2.571 * math.sqrt(17.5 / 5) / math.sqrt(6)  # t_{0.975,5}, sample variance 17.5 / 5
    assert mean == pytest.approx(3.5) and (low, high) == pytest.approx((3.5 - half, 3.5 + half))
    assert math.isnan(t_interval([0.2])[1])  # one world: no spread to measure
    assert t_critical(40) == pytest.approx(2.021, abs=1e-3)  # past the table: the expansion
    assert t_critical(10_000) == pytest.approx(1.960, abs=1e-3)


def test_a_family_is_the_mean_of_its_world_means() -> None:
    runs = [
        _run("a", "straight_vineyard", 1001, 0.02),
        _run("a", "straight_vineyard", 1001, 0.04),  # world 1001: 0.03
        _run("a", "straight_vineyard", 11001, 0.05, success=False),  # world 11001: 0.05
    ]
    (row,) = summarise_families(runs, {"a": "kinematic"})
    assert (row["worlds"], row["runs"], row["successes"], row["failures"]) == (2, 3, 2, "left_row x1")
    assert row["mae_mean"] == pytest.approx(0.04)  # not the mean of the runs, 0.0367
    half = 12.706 * math.sqrt(2 * 0.01**2) / math.sqrt(2)
    assert (row["mae_low"], row["mae_high"]) == pytest.approx((0.04 - half, 0.04 + half))


def test_targets_verdicts_and_the_choice_per_robot() -> None:
    robots = {"pursuit": "kinematic", "hold": "skid_steer", "slope": "skid_steer", "lossy": "skid_steer"}
    runs = []
    for setting, straight, pear, sloped in [
        ("pursuit", 0.05, 0.020, 0.09),  # sloped 0.09 < 2 x 0.05: meets
        ("hold", 0.03, 0.028, 0.07),  # sloped 0.07 > 2 x 0.03: misses
        ("slope", 0.04, 0.025, 0.07),  # meets: worst ratio pear 0.025 / 0.031 = 0.81
        ("lossy", 0.02, 0.010, 0.03),  # best means, but a run lost
    ]:
        for seed in (1, 2):
            runs += [
                _run(setting, "straight_vineyard", seed, straight),
                _run(setting, "pear_field", seed, pear, success=not (setting == "lossy" and seed == 2)),
                _run(setting, "slope_pear_2", seed, sloped),
            ]
    rows = summarise_families(runs, robots)
    verdicts = judge(rows, "segmind", "straight_vineyard", 2.0)
    targets = {(r["setting"], r["family"]): r["target"] for r in rows}
    assert targets[("hold", "pear_field")] == pytest.approx(0.031)  # the paper's SegMinD
    assert targets[("hold", "slope_pear_2")] == pytest.approx(0.06)  # 2 x its own straight mean
    assert {s: v.meets for (s, _), v in verdicts.items()} == {
        "pursuit": True,
        "hold": False,
        "slope": True,
        "lossy": False,
    }
    assert verdicts[("hold", "segcorridor")].misses == ["slope_pear_2 70.0 >= 60.0 mm"]
    assert verdicts[("lossy", "segcorridor")].misses == ["pear_field lost 1 run(s)"]
    assert choose(rows, verdicts, "segcorridor") == {"kinematic": "pursuit", "skid_steer": "slope"}
    del robots["pursuit"]
    only_skid = [r for r in rows if r["setting"] != "pursuit"]
    assert choose(only_skid, judge(only_skid, "segmind", "straight_vineyard", 2.0), "segcorridor")["skid_steer"] == (
        "slope"
    )


def _spec(tmp_path, **fields) -> str:
    raw = {
        "families": ["straight_vineyard"],
        "world_seeds": 2,
        "runs": 1,
        "overrides": TINY,
        "settings": {
            "pursuit": {"robot": "kinematic"},
            "hold": {"robot": "skid_steer", "overrides": ["follower.corridor.controller=centre_hold"]},
        },
        **fields,
    }
    path = tmp_path / "families.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))  # the settings in the order written
    return str(path)


@pytest.mark.parametrize(
    "fields, words",
    [
        ({"world_seeds": 1}, ["world_seeds", "must be >= 2"]),
        ({"families": ["straight_vineyard", "no_such_field"]}, ["families", "no_such_field"]),
        ({"families": ["train_vineyard_a"]}, ["families", "training world"]),
        ({"families": ["slope_pear_2"]}, ["slope_pear_2", "no paper figure", "flat_reference"]),
        ({"settings": {}}, ["settings", "at least one"]),
        ({"settings": {"x": {"robot": "tank"}}}, ["settings.x.robot", "tank"]),
        (
            {"settings": {"x": {"robot": "skid_steer", "overrides": ["follower.corridor.trim=-1"]}}},
            ["settings.x", "trim"],
        ),
        ({"methods": ["segmax"]}, ["methods", "segmax"]),
        ({"paper_method": "segcorridor"}, ["paper_method", "segcorridor"]),
    ],
)
def test_a_bad_family_spec_fails_in_one_line_before_any_run(tmp_path, capsys, fields, words) -> None:
    assert_refused_before_any_run(_spec(tmp_path, **fields), tmp_path / "out", capsys, words)


def test_the_shipped_comparison_loads_and_validates() -> None:
    spec, path = load_family_spec("families")
    plan = plan_families(spec, str(path))
    families = list(dict.fromkeys(m.family for m in plan.members))
    assert families[:5] == ["straight_vineyard", "curved_vineyard", "pergola_vineyard", "pear_field", "high_trees"]
    assert all(f.startswith("slope_") for f in families[5:]) and len(families) == 10
    assert spec.world_seeds >= 6 and len(plan.members) == 10 * spec.world_seeds
    assert len({m.world_seed for m in plan.members}) == len(plan.members)  # no world twice
    robots = {plan.configs[s]["robot"]["model"] for s in spec.settings}
    assert robots == {"kinematic", "skid_steer"}
    default = next(f.default for f in dataclasses.fields(CorridorConfig) if f.name == "hold_slope_drift")
    drifts = {
        plan.configs[s]["follower"]["corridor"].get("hold_slope_drift", default)
        for s in spec.settings
        if plan.configs[s]["robot"]["model"] == "skid_steer"
    }
    assert drifts == {0.0, 0.25, 0.5}


def test_a_tiny_comparison_runs_every_world_and_resumes(tmp_path, capsys, monkeypatch) -> None:
    spec = _spec(tmp_path)
    out = tmp_path / "out"
    assert main(["robustness", spec, "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "runs: 4 executed, 0 reused" in printed and "segcorridor, kinematic:" in printed
    world = load_world_spec(out / "worlds" / f"straight_vineyard-seed{1001 + WORLD_SEED_STRIDE}.yaml")
    assert world.seed == 1001 + WORLD_SEED_STRIDE and world.name == "straight_vineyard"
    rows = list(csv.DictReader((out / "families.csv").open()))
    assert [(r["setting"], r["robot"], r["worlds"], r["runs"]) for r in rows] == [
        ("pursuit", "kinematic", "2", "2"),
        ("hold", "skid_steer", "2", "2"),
    ]
    assert all(r["target"] == "0.11" and r["mae_low"] < r["mae_mean"] < r["mae_high"] for r in rows)
    summary = (out / "summary.md").read_text()
    assert "110.0 (paper)" in summary and "| hold | skid_steer |" in summary

    calls = []
    real_run = evaluate.Worker.run
    monkeypatch.setattr(evaluate.Worker, "run", lambda self, job: calls.append(job) or real_run(self, job))
    again = run_families(spec, out, progress=False)
    assert (again.executed, again.reused, calls) == (0, 4, [])
    assert list(csv.DictReader((out / "families.csv").open())) == rows
