"""Closed-loop runs in the real synth test fields, tiny: 64 x 64 camera, a few metres of row."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from segmin.data.synth.spec import TEST_FIELDS
from segmin.nav_eval.evaluation.evaluate import Worker, run_evaluation, run_seed
from segmin.nav_eval.evaluation.metrics import compute_metrics
from segmin.nav_eval.evaluation.records import Job
from segmin.nav_eval.evaluation.rollout import run_episode
from segmin.nav_eval.runtime.follower import RowFollower
from segmin.nav_eval.runtime.navigator import Command, Navigator, NavigatorConfig
from segmin.nav_eval.sim.config import load_nav_config
from segmin.nav_eval.sim.factories import FieldContext, make_follower, make_simulator
from segmin.nav_eval.sim.oracle import OracleSegmenter

TINY = ["perception.width=64", "perception.height=64", "run.length_m=2.0", "run.time_limit_s=12"]


@pytest.fixture(scope="module")
def worker():
    w = Worker("oracle", load_nav_config(overrides=TINY))
    yield w
    w.close()


@pytest.mark.parametrize("field", TEST_FIELDS)
def test_short_oracle_run_per_field_has_finite_metrics(worker, field: str) -> None:
    result = worker.run(Job(field, "segmind", 0, run_seed(0, field, 0)))
    assert result.reason != "error", result.error
    for key in ("mae", "mse", "heading_avg", "v_avg", "omega_std", "min_plant_distance", "sim_time"):
        assert math.isfinite(getattr(result, key)), (key, result)
    assert result.distance > 0.5 and result.v_avg > 0.05 and result.success
    assert result.mae < 0.5


WORLDS = Path(__file__).resolve().parents[1] / "configs" / "worlds"
# SegCorridor as the sloped rows want it: the skid-steer robot, centre_hold with the slope feedforward.
SLOPED = [
    "robot.model=skid_steer",
    "follower.corridor.controller=centre_hold",
    "follower.corridor.hold_slope_drift=0.5",
]


@pytest.mark.parametrize(("world", "cross_slope"), [("slope_vineyard_s8.yaml", -0.08), ("slope_pear_s8.yaml", 0.08)])
def test_a_short_run_through_a_sloped_s_curve_world(world: str, cross_slope: float) -> None:
    """The sloped S-curve worlds load as fields (by their file), the robot rolls with their cross slope
    (REP 103: left side up is a positive roll), SegCorridor gets that roll from the IMU, and it
    follows the bend of the first 3 m."""
    config = load_nav_config(overrides=[*TINY, "run.length_m=3.0", *SLOPED])
    ctx = FieldContext(str(WORLDS / world), config)  # built and closed here: the worker's cache stays as it is
    try:
        simulator = make_simulator(ctx, config)
        follower = make_follower("segcorridor", config.depth_threshold(ctx.spec.name, ctx.spec.family), config)
        rolls: list[float] = []
        command = follower.navigator.command

        def seen(fused, depth_m, attitude=None, rgb=None):
            rolls.append(attitude[0])
            return command(fused, depth_m, attitude, rgb)

        follower.navigator.command = seen
        episode = run_episode(simulator, follower, OracleSegmenter(), seed=run_seed(0, world, 0))
    finally:
        ctx.close()
    assert episode.reason == "success", episode.reason
    # The cross slope's roll, give or take the ground's roughness (0.04 rad under these runs).
    assert 0.5 < np.median(rolls) / math.atan(cross_slope) < 2.0
    line = simulator.centreline
    driven = line[(line[:, 0] >= episode.trajectory.x[0]) & (line[:, 0] <= episode.trajectory.x[-1])]
    assert np.ptp(driven[:, 1]) > 0.15  # the row bends within the run
    metrics = compute_metrics(
        episode.trajectory, line, success=True, clearance_time=episode.clearance_time, collisions=0
    )
    assert metrics["mae"] < 0.15


class _Fixed(Navigator):
    """A navigator that ignores the camera and drives straight at speed v."""

    def __init__(self, v: float) -> None:
        super().__init__(NavigatorConfig(method="segmin", depth_threshold=5.0))
        self.v = v

    def command(self, fused, depth, attitude=None, rgb=None) -> Command:
        return Command(v=self.v, omega=0.0, target_column=None, histogram=np.zeros(0), valid=True)


def test_run_aimed_into_a_plant_row_is_a_collision(worker) -> None:
    ctx: FieldContext = worker.field("straight_vineyard")
    config = dataclasses.replace(worker.config, run=dataclasses.replace(worker.config.run, length_m=20.0))
    simulator = make_simulator(ctx, config)
    simulator.half_width = math.inf  # the hedge line would end it as "left_row" first
    x0, y0 = simulator.centreline[4]
    # Aim at the nearest trunk at least 1.5 m ahead along the row.
    plants = simulator.plants
    ahead = plants[(plants[:, 0] - x0 > 1.5)]
    target = ahead[np.argmin(np.hypot(ahead[:, 0] - x0, ahead[:, 1] - y0))]
    yaw = math.atan2(target[1] - y0, target[0] - x0)
    episode = run_episode(simulator, RowFollower(None, _Fixed(0.4)), OracleSegmenter(), seed=0, pose=(x0, y0, yaw))
    assert episode.reason == "collision", episode.reason
    assert episode.collisions == 1 and not episode.success
    last = episode.trajectory
    assert math.hypot(last.x[-1] - target[0], last.y[-1] - target[1]) < 0.6


def test_same_seed_same_trajectory_in_a_real_field(worker) -> None:
    config = dataclasses.replace(worker.config, run=dataclasses.replace(worker.config.run, length_m=1.0))
    w = Worker("oracle", config)
    w._fields = worker._fields  # share the built worlds (same config apart from the run length)
    a = w.run(Job("curved_vineyard", "segmin", 0, 5))
    b = w.run(Job("curved_vineyard", "segmin", 0, 5))
    assert a.reason == b.reason != "error"
    assert np.array_equal(a.trajectory.x, b.trajectory.x) and np.array_equal(a.trajectory.yaw, b.trajectory.yaw)


def test_run_evaluation_writes_outputs_and_reports_failed_runs(tmp_path) -> None:
    config = load_nav_config(overrides=TINY + ["run.length_m=1.0"])
    results = run_evaluation(
        "oracle", "straight_vineyard", "segmin", 1, tmp_path, 1, config, progress=False, video=True
    )
    assert len(results) == 1 and results[0].reason != "error"
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["rows"][0]["seed"] == results[0].seed and data["rows"][0]["config"]["run"]["length_m"] == 1.0
    assert (tmp_path / "results.csv").read_text().count("\n") == 2
    assert "straight_vineyard" in (tmp_path / "report.md").read_text()
    assert (tmp_path / "straight_vineyard_trajectories.png").stat().st_size > 1000
    assert (tmp_path / "straight_vineyard_histograms.png").stat().st_size > 1000
    videos = list((tmp_path / "videos").iterdir())
    assert len(videos) == 1 and videos[0].suffix in (".mp4", ".gif") and videos[0].stat().st_size > 1000
    assert not list(tmp_path.rglob("*.tmp"))  # atomic writes leave no temporaries
    # An invalid navigator value set past the loader is refused before the first run (it used
    # to make every run raise); at load time the errors tests refuse it.
    bad = load_nav_config(overrides=TINY)
    bad.follower.navigator["smooth_window"] = 4
    with pytest.raises(ValueError, match="smooth_window"):
        run_evaluation(
            "oracle", "straight_vineyard", "segmin,segmind", 1, tmp_path / "bad", 1, bad, progress=False, plots=False
        )
    assert not (tmp_path / "bad" / "results.json").exists()


def test_cli_refuses_training_worlds_bad_methods_and_missing_models(tmp_path, capsys) -> None:
    from segmin.app.cli import main

    assert main(["nav-eval", "--model", "oracle", "--fields", "train_vineyard_a", "--out", str(tmp_path)]) == 2
    assert "training world" in capsys.readouterr().err
    assert main(["nav-eval", "--model", "oracle", "--methods", "segmax", "--out", str(tmp_path)]) == 2
    assert "--methods: unknown ['segmax']" in capsys.readouterr().err
    assert main(["nav-eval", "--model", str(tmp_path / "none.onnx"), "--out", str(tmp_path)]) == 2
    assert "none.onnx: ONNX model not found" in capsys.readouterr().err
    assert main(["nav-eval", "--model", "oracle", "--set", "run.speed=3", "--out", str(tmp_path)]) == 2
    assert "run: unknown key(s) ['speed']" in capsys.readouterr().err
    assert not (tmp_path / "results.csv").exists()
