"""Robustness sweeps (`segmin robustness`): bad specs fail before any run, a tiny sweep writes its
outputs, and a second call resumes (finished runs are not redone); the slip parameters change the
skid-steer robot they name, and the envelope figure draws MAE beside success."""

from __future__ import annotations

import csv

import pytest
import yaml
from sweep_helpers import TINY, assert_refused_before_any_run

from segmin.app.cli import main
from segmin.common.config import to_dict
from segmin.common.shipped import shipped_names
from segmin.data.synth.spec import load_world_spec
from segmin.nav_eval.evaluation import evaluate
from segmin.nav_eval.evaluation.records import RunResult
from segmin.nav_eval.sim.robot import SkidSteerConfig
from segmin.nav_eval.sweeps import plots
from segmin.nav_eval.sweeps.family_spec import is_family_spec
from segmin.nav_eval.sweeps.report import summary_markdown
from segmin.nav_eval.sweeps.run import run_sweep
from segmin.nav_eval.sweeps.spec import SLIP_COEFFICIENTS, load_sweep, plan_sweep


def _spec(tmp_path, parameters: dict, **fields) -> str:
    raw = {
        "base": "straight_vineyard",
        "methods": ["segmind"],
        "runs": 1,
        "robot": "skid_steer",
        "overrides": TINY,
        "parameters": parameters,
        **fields,
    }
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump(raw))
    return str(path)


@pytest.mark.parametrize(
    "parameters, fields, words",
    [
        ({"curvature": [1, 2]}, {}, ["parameters", "curvature", "known: curve_radius"]),
        ({"row_spacing": []}, {}, ["parameters.row_spacing", "empty value list"]),
        ({"row_spacing": [1.8, 0.9]}, {}, ["parameters.row_spacing", "value 0.9", "rows.spacing", "free gap"]),
        ({"curve_radius": ["straight", 3]}, {}, ["parameters.curve_radius", "value 3", "rows.curve_radius"]),
        ({"seg_dropout": [0.5, 2]}, {}, ["parameters.seg_dropout", "perception.mask_dropout"]),
        ({"row_spacing": [1.8]}, {"methods": ["segmax"]}, ["methods", "segmax"]),
        ({"row_spacing": [1.8]}, {"overrides": ["run.speed=3"]}, ["overrides", "speed"]),
        ({"row_spacing": [1.8]}, {"base": "train_vineyard_a"}, ["base", "training world"]),
        ({"grip": [1, 2]}, {}, ["parameters", "grip", "slip", "cross_slope_drift", "latency"]),
        ({"slip": [1, "wet"]}, {}, ["parameters.slip", "value wet", "factor >= 0"]),
        ({"slip": [1, -0.5]}, {}, ["parameters.slip", "value -0.5", "factor >= 0"]),
        ({"slip": [1, 40]}, {}, ["parameters.slip", "value 40", "longitudinal_slip must be within [0, 1)"]),
        ({"cross_slope_drift": [0.5, 1.0]}, {}, ["parameters.cross_slope_drift", "no cross slope"]),
        ({"cross_slope_drift": [0.5, -1]}, {"base": "CROSS"}, ["parameters.cross_slope_drift", "must be >= 0"]),
        ({"latency": [6, 30]}, {"robot": "kinematic"}, ["parameters.latency", "skid-steer robot only"]),
    ],
)
def test_a_bad_spec_fails_in_one_line_before_any_run(tmp_path, capsys, parameters, fields, words) -> None:
    if fields.get("base") == "CROSS":
        fields = {**fields, "base": _cross_sloped_vineyard(tmp_path)}
    assert_refused_before_any_run(_spec(tmp_path, parameters, **fields), tmp_path / "out", capsys, words)


def _cross_sloped_vineyard(tmp_path, cross: float = 0.1) -> str:
    """The straight vineyard on a cross slope, as a world spec file (a base the creep acts on)."""
    world = to_dict(load_world_spec("straight_vineyard"))
    world["terrain"]["slope"] = [world["terrain"]["slope"][0], cross]
    path = tmp_path / "cross_sloped_vineyard.yaml"
    path.write_text(yaml.safe_dump(world))
    return str(path)


def test_a_spec_without_robot_sweeps_the_skid_steer_robot(tmp_path) -> None:
    raw = {"base": "straight_vineyard", "methods": ["segmind"], "parameters": {"row_spacing": [1.8, 2.2]}}
    path = tmp_path / "plain.yaml"
    path.write_text(yaml.safe_dump(raw))
    spec, _ = load_sweep(path)
    plan = plan_sweep(spec, str(path))
    assert spec.robot == "skid_steer"
    assert {v.config["robot"]["model"] for v in plan.variants} == {"skid_steer"}
    assert plan.base_config.robot.model == "skid_steer"


def test_slip_scales_every_slip_coefficient_and_nothing_else(tmp_path) -> None:
    spec, where = load_sweep(_spec(tmp_path, {"slip": [0, 1, 2.5]}))
    plan = plan_sweep(spec, str(where))
    base = to_dict(SkidSteerConfig())
    zero, one, more = (v.config["robot"]["skid"] for v in plan.variants)
    assert one == base  # 1 is the configured robot: its runs are the base's
    assert plan.variants[1].setting != plan.variants[2].setting
    for key, value in base.items():
        if key in SLIP_COEFFICIENTS:
            assert (zero[key], more[key]) == (0.0, pytest.approx(2.5 * value)), key
        else:  # the drive's calibration, latency and noise belong to the robot, not the ground
            assert zero[key] == more[key] == value, key


def test_cross_slope_drift_sets_the_creep_on_a_cross_sloped_base(tmp_path) -> None:
    spec, where = load_sweep(
        _spec(tmp_path, {"cross_slope_drift": [0.5, 0.0, 1.5]}, base=_cross_sloped_vineyard(tmp_path))
    )
    plan = plan_sweep(spec, str(where))
    assert [v.config["robot"]["skid"]["cross_slope_drift"] for v in plan.variants] == [0.5, 0.0, 1.5]
    assert len({v.setting for v in plan.variants}) == 3


def test_the_envelope_draws_mae_under_success_for_every_parameter(tmp_path, monkeypatch) -> None:
    spec, where = load_sweep(
        _spec(
            tmp_path,
            {"cross_slope": [0.0, 0.1], "slip": [1, 3], "latency": [6, 30]},
            methods=["segmind", "segcorridor"],
        )
    )
    plan = plan_sweep(spec, str(where))
    rows = [
        {
            "parameter": v.parameter,
            "value": v.label,
            "method": m,
            "runs": 2,
            "successes": 2 - k % 2,
            "success_rate": 1 - 0.5 * (k % 2),
            "mae_mean": 0.05 + 0.01 * k,
            "mae_std": 0.002 * k,
            "failures": "" if k % 2 == 0 else "left_row x1",
        }
        for k, (v, m) in enumerate((v, m) for v in plan.variants for m in spec.methods)
    ]
    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig))
    plots.envelope_figure(tmp_path / "envelope.png", plan, rows)
    axes = [ax for ax in drawn[0].axes if ax.axison]
    labels = [ax.get_ylabel() for ax in axes]
    assert labels.count("success %") == labels.count("MAE m (mean ± std)") == 3
    for ax in axes:  # each panel's lines carry its parameter's values, method by method
        name = ax.get_xlabel().split(" ")[0]
        mae = ax.get_ylabel().startswith("MAE")
        key, scale = ("mae_mean", 1.0) if mae else ("success_rate", 100.0)
        lines = [bars.lines[0] for bars in ax.containers] if mae else ax.get_lines()
        assert len(lines) == len(spec.methods)
        for line, method in zip(lines, spec.methods):
            expected = [scale * r[key] for r in rows if r["parameter"] == name and r["method"] == method]
            assert list(line.get_ydata()) == pytest.approx(expected), (name, key, method)
    summary = summary_markdown(plan, rows, {}, executed=0, reused=0, errored=0)
    assert "| 3 | 2/2 | 0.150 ± 0.020 | 1/2 (left_row x1) | 0.160 ± 0.022 |" in summary  # MAE per value (slip 3)


def test_a_tiny_sweep_writes_its_tables_and_figures_and_resumes(tmp_path, monkeypatch) -> None:
    spec = _spec(
        tmp_path,
        {"row_spacing": [1.8, 2.2], "seg_dropout": [0.0, 1.0]},
        overrides=TINY + ["perception.mask_dropout_mode=drop"],
    )
    out = tmp_path / "out"
    first = run_sweep(spec, out, progress=False)
    # 1.8 m and no dropout are both the base itself: 3 distinct runs for 4 (parameter, value) pairs.
    assert (first.executed, first.reused, first.errored) == (3, 0, [])
    assert len(list((out / "runs").glob("*.json"))) == 3
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert [(r["parameter"], r["value"]) for r in rows] == [
        ("row_spacing", "1.8"),
        ("row_spacing", "2.2"),
        ("seg_dropout", "0"),
        ("seg_dropout", "1"),
    ]
    assert all(r["runs"] == "1" and r["method"] == "segmind" for r in rows)
    assert rows[0]["mae_mean"] == rows[2]["mae_mean"]  # the shared base run
    assert rows[3]["mae_mean"] != rows[2]["mae_mean"]  # every mask empty: it drives blind
    world = load_world_spec(out / "worlds" / "straight_vineyard-row_spacing-2.2.yaml")
    assert world.rows.spacing == 2.2 and world.name == "straight_vineyard"  # the name keeps its depth threshold
    for figure in ("sweep_row_spacing.png", "sweep_seg_dropout.png", "envelope.png"):
        assert (out / figure).stat().st_size > 1000
    summary = (out / "summary.md").read_text()
    assert "Where each parameter breaks" in summary and "skid_steer" in summary
    assert not list(out.rglob("*.tmp")) and not (out / ".sweep.lock").exists()

    calls = []
    real_run = evaluate.Worker.run
    monkeypatch.setattr(evaluate.Worker, "run", lambda self, job: calls.append(job) or real_run(self, job))
    again = run_sweep(spec, out, progress=False, plots=False)
    assert (again.executed, again.reused, calls) == (0, 3, [])  # finished runs are not redone
    assert list(csv.DictReader((out / "sweep.csv").open())) == rows
    grown = _spec(
        tmp_path,
        {"row_spacing": [1.8, 2.2, 2.6], "seg_dropout": [0.0, 1.0]},
        overrides=TINY + ["perception.mask_dropout_mode=drop"],
    )
    more = run_sweep(grown, out, progress=False, plots=False)
    assert (more.executed, more.reused) == (1, 3) and len(calls) == 1  # only the new value runs


def test_runs_that_raise_are_reported_and_not_stored(tmp_path, capsys, monkeypatch) -> None:
    def broken(self, job):
        return RunResult(
            field=job.field,
            method=job.method,
            run=job.run,
            seed=job.seed,
            model="oracle",
            success=False,
            reason="error",
            error="RuntimeError: broken",
        )

    monkeypatch.setattr(evaluate.Worker, "run", broken)
    spec = _spec(tmp_path, {"row_spacing": [1.8]})
    assert main(["robustness", spec, "--out", str(tmp_path / "out"), "--no-progress", "--no-plots"]) == 1
    assert "1 run(s) raised" in capsys.readouterr().err
    assert not list((tmp_path / "out" / "runs").glob("*.json"))


# Seconds of one 10 m run on one core at 224 x 224 (docs/results/history/sweeps.md): the budget's unit.
RUN_SECONDS = {"straight_vineyard": {"segcorridor": 14.0}, "high_trees": {"segcorridor": 17.0}}
PAPER_RUN_SECONDS = {"straight_vineyard": 10.0, "high_trees": 15.0}


@pytest.mark.parametrize("name", [n for n in shipped_names("sweeps") if not is_family_spec(n)])
def test_shipped_sweeps_validate_with_every_variant(name: str) -> None:
    spec, path = load_sweep(name)
    plan = plan_sweep(spec, str(path))
    assert plan.base_config.robot.model == "skid_steer" and plan.base_config.run.length_m == 10
    assert "segcorridor" in spec.methods and {"slip", "cross_slope", "roughness", "latency"} <= set(spec.parameters)
    distinct = len({v.setting for v in plan.variants})
    per_variant = sum(RUN_SECONDS[spec.base].get(m, PAPER_RUN_SECONDS[spec.base]) for m in spec.methods) * spec.runs
    # The budget their comments state: within 25 min on 2 workers.
    assert distinct * per_variant / 2 < 25 * 60


def test_configs_list_shows_the_sweeps(capsys) -> None:
    assert shipped_names("sweeps") == ["families", "trees", "vineyards"]
    assert main(["configs", "list"]) == 0
    assert "sweeps: robustness sweeps" in capsys.readouterr().out
