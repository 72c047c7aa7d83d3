"""Nav-eval: broken setups fail before the first run; runs that raise are errors, not results."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from segmin.app.cli import main

FAST = ["--fields", "straight_vineyard", "--methods", "segmin", "--runs", "1", "--no-plots", "--no-progress"]


def _foreign_onnx(path: Path) -> Path:
    """A valid ONNX graph (Identity) that is not a segmin export: no metadata, float input."""
    import onnx
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3])
    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "foreign", [x], [y])
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), str(path))
    return path


@pytest.mark.parametrize("kind", ["random", "foreign"])
def test_a_model_that_is_not_a_segmin_export_fails_before_any_run(tmp_path, capsys, kind):
    model = tmp_path / "m.onnx"
    if kind == "random":
        model.write_bytes(bytes(range(256)) * 4)
    else:
        _foreign_onnx(model)
    out = tmp_path / "out"
    assert main(["nav-eval", "--model", str(model), "--out", str(out), *FAST]) == 2
    err = capsys.readouterr().err
    assert str(model) in err and len(err.strip().splitlines()) == 1
    assert not (out / "results.json").exists()  # no run started


def test_earlier_results_are_not_overwritten_without_force(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.csv").write_text("earlier\n")
    assert main(["nav-eval", "--model", "oracle", "--out", str(out), *FAST]) == 2
    err = capsys.readouterr().err
    assert "results.csv" in err and "--force" in err and len(err.strip().splitlines()) == 1
    assert (out / "results.csv").read_text() == "earlier\n"


@pytest.mark.parametrize(
    "setting, message",
    [
        ("follower.navigator.v_max=-1", "v_max"),
        ("follower.navigator.smooth_window=4", "smooth_window"),
    ],
)
def test_bad_navigator_settings_fail_before_any_run(tmp_path, capsys, setting, message):
    out = tmp_path / "out"
    assert main(["nav-eval", "--model", "oracle", "--out", str(out), "--set", setting, *FAST]) == 2
    assert message in capsys.readouterr().err
    assert not (out / "results.json").exists()


def test_corridor_limits_that_leave_no_row_seen_fail_before_any_run(tmp_path, capsys):
    """min_points above half of max_points: each is valid, together no row is ever seen (every
    SegCorridor run would be SegMinD's fallback, reported as SegCorridor)."""
    out = tmp_path / "out"
    fast = [*FAST[:2], "--methods", "segcorridor", *FAST[4:]]
    assert (
        main(["nav-eval", "--model", "oracle", "--out", str(out), "--set", "follower.corridor.min_points=1000", *fast])
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert err.startswith("segmin: error: ") and len(err.splitlines()) == 1
    assert "corridor.min_points (1000)" in err and "corridor.max_points (600)" in err
    assert not out.exists()


@pytest.mark.parametrize(
    "setting, message",
    [
        ("follower.navigator.smooth_window=4", "navigator: smooth_window must be an odd integer"),
        ("follower.corridor.min_points=1000", "corridor.min_points (1000)"),
        ("follower.corridor.h_min=5.0", "corridor.h_min (5.0) must be below corridor.h_max"),
    ],
)
def test_navigator_sections_are_checked_when_the_config_loads(setting, message):
    """Not only when a run builds the navigator: a pipeline loads its nav config before render
    and training, and a section that only fails in the nav-eval stage fails hours in."""
    from segmin.common.config import ConfigError
    from segmin.nav_eval.sim.config import load_nav_config

    with pytest.raises(ConfigError, match=re.escape(message)):
        load_nav_config(overrides=[setting])


def test_a_non_finite_depth_threshold_is_refused_by_name():
    from segmin.nav_eval.evaluation.evaluate import preflight
    from segmin.nav_eval.sim.config import NavEvalConfig

    config = NavEvalConfig()
    config.depth_thresholds["straight_vineyard"] = float("nan")  # past the loader's checks
    with pytest.raises(ValueError, match="straight_vineyard.*depth_threshold"):
        preflight("oracle", ["straight_vineyard"], ["segmin"], config)


def _errored(field: str = "straight_vineyard"):
    from segmin.nav_eval.evaluation.records import RunResult

    return RunResult(
        field=field,
        method="segmin",
        run=0,
        seed=0,
        model="oracle",
        success=False,
        reason="error",
        error="RuntimeError: boom\ntraceback ...",
    )


def test_nav_eval_exits_non_zero_when_a_run_raised(tmp_path, capsys, monkeypatch):
    from segmin.nav_eval.evaluation import evaluate

    monkeypatch.setattr(evaluate.Worker, "run", lambda self, job: _errored())
    assert main(["nav-eval", "--model", "oracle", "--out", str(tmp_path / "out"), *FAST]) == 1
    captured = capsys.readouterr()
    assert "run raised: straight_vineyard/segmin/0: RuntimeError: boom" in captured.out
    assert "1 of 1 run(s) raised" in captured.err


def test_the_pipeline_never_caches_a_nav_stage_with_errored_runs(tmp_path, monkeypatch):
    from segmin.app.pipeline import stages
    from segmin.app.pipeline.cache import StageCache
    from segmin.app.pipeline.config import load_pipeline_config
    from segmin.app.pipeline.runner import PipelineRunner
    from segmin.nav_eval.evaluation import evaluate

    monkeypatch.setattr(evaluate, "run_evaluation", lambda *a, **k: [_errored()])
    config = load_pipeline_config("micro")
    runner = PipelineRunner(config, tmp_path, log=lambda message: None)
    with pytest.raises(evaluate.RunErrors, match="1 of 1 run"):
        runner._stage(
            "nav-eval",
            "nav-eval/oracle",
            "h",
            lambda folder, fresh: stages.nav_stage(config, "oracle", ["straight_vineyard"], folder, print),
        )
    assert not StageCache(tmp_path).record("nav-eval/oracle").finished


def _driven(job):
    """A finished run of `job` with a two-point path, as a worker returns it (no simulation)."""
    from segmin.nav_eval.evaluation.records import RunResult
    from segmin.nav_eval.sim.track import Trajectory

    path = Trajectory.from_rows([(0.0, 0.0, 0.0, 0.0, 0.5, 0.0, 1.0), (1.0, 0.5, 0.01, 0.0, 0.5, 0.0, 1.0)])
    return RunResult(job.field, job.method, job.run, job.seed, "oracle", True, "goal", mae=0.01, trajectory=path)


def test_a_nav_eval_killed_between_runs_resumes_with_its_finished_runs(tmp_path, capsys, caplog, monkeypatch):
    from segmin.nav_eval.evaluation import evaluate

    out = tmp_path / "out"
    command = ["nav-eval", "--model", "oracle", "--out", str(out), *FAST[:4], "--runs", "3", *FAST[6:]]
    ran: list[int] = []

    def killed_at_run_1(self, job):
        if job.run == 1:
            raise KeyboardInterrupt  # the process killed while the second run drives
        ran.append(job.run)
        return _driven(job)

    monkeypatch.setattr(evaluate.Worker, "run", killed_at_run_1)
    assert main(command) == 130
    assert ran == [0] and len(json.loads((out / "results.json").read_text())["rows"]) == 1
    monkeypatch.setattr(evaluate.Worker, "run", lambda self, job: ran.append(job.run) or _driven(job))
    capsys.readouterr()
    caplog.clear()
    assert main(command) == 0
    assert ran == [0, 1, 2] and "resuming, 1 of 3 runs finished before, 2 to do" in caplog.text
    assert [row["run"] for row in json.loads((out / "results.json").read_text())["rows"]] == [0, 1, 2]
    assert len(json.loads((out / "trajectories.json").read_text())) == 3  # the kept run's path too
    assert main(command) == 0 and ran == [0, 1, 2]  # finished: nothing to redo
    assert main([*command, "--force"]) == 0 and ran == [0, 1, 2, 0, 1, 2]  # --force starts over
    # A forced redo killed part-way resumes from its own runs, never from those before the force.
    monkeypatch.setattr(evaluate.Worker, "run", killed_at_run_1)
    ran.clear()
    assert main([*command, "--force"]) == 130 and ran == [0]
    monkeypatch.setattr(evaluate.Worker, "run", lambda self, job: ran.append(job.run) or _driven(job))
    assert main(command) == 0 and ran == [0, 1, 2]
    capsys.readouterr()
    # Another evaluation's results are not overwritten (its seed differs) without --force.
    assert main([*command, "--seed", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "already holds nav-eval results" in err and "its seed differs" in err and "\n" not in err


@pytest.mark.parametrize("obstacle", ["file", "symlink", "bags_file", "read_only"])
def test_what_is_in_the_way_of_a_bag_is_named_before_any_run(tmp_path, capsys, monkeypatch, obstacle):
    from segmin.common import outputs
    from segmin.nav_eval.evaluation import evaluate

    out = tmp_path / "out"
    bags, bag = out / "bags", out / "bags" / "straight_vineyard_segmin"
    bags.parent.mkdir()
    if obstacle == "bags_file":
        bags.write_text("not a folder")
    else:
        bags.mkdir()
    if obstacle == "file":
        bag.write_text("not a bag")
    elif obstacle == "symlink":
        (tmp_path / "elsewhere").mkdir()
        bag.symlink_to(tmp_path / "elsewhere")
    elif obstacle == "read_only":  # the tests run as root, whom chmod does not stop: the OS's refusal
        mkstemp = outputs.tempfile.mkstemp

        def refused(*args, **kwargs):
            if Path(kwargs.get("dir", "")) == bags:
                raise PermissionError(13, "Permission denied")
            return mkstemp(*args, **kwargs)

        monkeypatch.setattr(outputs.tempfile, "mkstemp", refused)
    ran: list[int] = []
    monkeypatch.setattr(evaluate.Worker, "run", lambda self, job: ran.append(job.run) or _driven(job))
    assert main(["nav-eval", "--model", "oracle", "--out", str(out), "--bag", *FAST]) == 2
    err = capsys.readouterr().err.strip()
    expected = {
        "file": f"{bag}: a file where a run's bag goes",
        "symlink": f"{bag}: a symbolic link where a run's bag goes",
        "bags_file": f"bag folder {bags} is a file, not a folder",
        "read_only": f"bag folder {bags}: not writable (Permission denied)",
    }[obstacle]
    assert expected in err and "\n" not in err
    assert ran == [] and not (out / "results.json").exists()


def test_a_resumed_nav_eval_redoes_the_runs_of_a_model_replaced_at_the_same_path(tmp_path, caplog, monkeypatch):
    """The run store knows a model by its file's sha256, not its path: a new export written over
    the old one redoes every run, and the log says why, once; the same file again redoes none."""
    from segmin.nav_eval.evaluation import evaluate

    model, out = tmp_path / "model.onnx", tmp_path / "out"
    model.write_bytes(b"the first export")
    monkeypatch.setattr(evaluate, "preflight", lambda *args: None)  # no real graph: the runs are stand-ins
    ran: list[int] = []
    monkeypatch.setattr(evaluate.Worker, "run", lambda self, job: ran.append(job.run) or _driven(job))
    command = ["nav-eval", "--model", str(model), "--out", str(out), *FAST[:4], "--runs", "2", *FAST[6:]]
    assert main(command) == 0 and ran == [0, 1]
    caplog.clear()
    assert main(command) == 0 and ran == [0, 1]  # same file: both runs kept
    assert "changed" not in caplog.text
    model.write_bytes(b"a new export at the same path")
    assert main(command) == 0 and ran == [0, 1, 0, 1]
    why = [record.getMessage() for record in caplog.records if "changed since the kept runs" in record.getMessage()]
    assert len(why) == 1 and str(model) in why[0] and "the 2 finished run(s) of the old file are redone" in why[0]
