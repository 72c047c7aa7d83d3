"""Robustness sweeps (`segmin robustness`): bad specs fail before any run, a tiny sweep writes its
outputs, and a second call resumes (finished runs are not redone)."""

from __future__ import annotations

import csv

import pytest
import yaml

from segmin.app.cli import main
from segmin.common.shipped import shipped_names
from segmin.data.synth.spec import load_world_spec
from segmin.nav_eval.evaluation import evaluate
from segmin.nav_eval.sweeps.run import run_sweep
from segmin.nav_eval.sweeps.spec import load_sweep, plan_sweep

TINY = ["run.length_m=1.0", "perception.width=64", "perception.height=64", "run.time_limit_s=12"]


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
    ],
)
def test_a_bad_spec_fails_in_one_line_before_any_run(tmp_path, capsys, parameters, fields, words) -> None:
    spec = _spec(tmp_path, parameters, **fields)
    out = tmp_path / "out"
    assert main(["robustness", spec, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert spec in err, err
    for word in words:
        assert word in err, (word, err)
    assert not out.exists()  # nothing written, no run started


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
        return evaluate.RunResult(
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


@pytest.mark.parametrize("name", shipped_names("sweeps"))
def test_shipped_sweeps_validate_with_every_variant(name: str) -> None:
    spec, path = load_sweep(name)
    plan = plan_sweep(spec, str(path))
    assert plan.base_config.robot.model == "skid_steer" and plan.base_config.run.length_m == 10
    distinct = len({v.setting for v in plan.variants})
    # The budget their comments state: under 30 min on 2 workers at <= 15 s a run.
    assert distinct * len(spec.methods) * spec.runs * 15 / 2 < 30 * 60


def test_configs_list_shows_the_sweeps(capsys) -> None:
    assert shipped_names("sweeps") == ["trees", "vineyards"]
    assert main(["configs", "list"]) == 0
    assert "sweeps: robustness sweeps" in capsys.readouterr().out
