"""Sensor faults injected into simulated runs (`faults:` of the nav-eval config, sim.faults): the
config's checks, the spoilt frames, the fault metrics, and a closed-loop run that stops in time."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_nav_eval_sim import FakeRenderer, FakeWorld, _config

from segmin.common.config import ConfigError
from segmin.nav_eval.evaluation.rollout import run_episode
from segmin.nav_eval.sim.config import SimFault, load_nav_config
from segmin.nav_eval.sim.factories import make_follower
from segmin.nav_eval.sim.faults import FaultInjector, fault_metrics, faults_read_colour
from segmin.nav_eval.sim.oracle import OracleSegmenter
from segmin.nav_eval.sim.row_env import CameraFrame, RowEnv
from segmin.nav_eval.sim.track import Trajectory


@pytest.mark.parametrize(
    ("fault", "message"),
    [
        ("{kind: fog, start_s: 1, duration_s: 1}", r"faults\[0\]: kind 'fog' is not one of depth_dropout"),
        ("{kind: zero_depth, start_s: -1, duration_s: 1}", r"faults\[0\]: start_s must be a number of seconds >= 0"),
        ("{kind: zero_depth, start_s: 1, duration_s: 0}", r"faults\[0\]: duration_s must be a number of seconds > 0"),
        ("{kind: zero_depth, start_s: 1, duration_s: 1, region: top}", r"faults\[0\]: region 'top' is not one of"),
        ("{kind: black_frame, start_s: 1, duration_s: 1, region: left}", "region 'left' applies to depth faults only"),
        ("{kind: depth_dropout, start_s: 1, duration_s: 1, share: 0}", r"faults\[0\]: share must be within \(0, 1\]"),
        ("{kind: zero_depth, start_s: 1, duration_s: 1, share: 0.5}", "share applies to depth_dropout only"),
        ("{kind: black_frame, start_s: 1}", r"faults\[0\]: missing required key\(s\) \['duration_s'\]"),
        (
            "{kind: black_frame, start_s: 1, duration_s: 2}, {kind: zero_depth, start_s: 2, duration_s: 1}",
            "faults: black_frame at 1-3 s overlaps zero_depth at 2-3 s",
        ),
    ],
)
def test_bad_faults_are_named_when_the_config_loads(fault: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_nav_config(None, [f"faults=[{fault}]"])


def test_the_default_config_injects_no_fault() -> None:
    config = load_nav_config(None, ["faults=[{kind: frozen_frame, start_s: 4, duration_s: 2}]"])
    assert config.faults == [SimFault(kind="frozen_frame", start_s=4.0, duration_s=2.0)]
    assert load_nav_config().faults == [] and not faults_read_colour([])
    assert faults_read_colour(config.faults)


def _frame(value: int) -> CameraFrame:
    return CameraFrame(
        rgb=np.full((4, 6, 3), value, np.uint8),
        depth=np.full((4, 6), 2.0 + value, np.float32),
        mask=np.ones((4, 6), dtype=bool),
    )


def test_each_fault_spoils_the_frames_of_its_window_only() -> None:
    faults = [
        SimFault("depth_dropout", 1.0, 1.0, region="left"),
        SimFault("zero_depth", 2.0, 1.0),
        SimFault("black_frame", 3.0, 1.0),
        SimFault("frozen_frame", 4.5, 1.0),
        SimFault("frozen_depth", 6.0, 1.0),
    ]
    spoil = FaultInjector(faults, seed=0)
    clean = spoil(_frame(0), 0.5)
    assert clean.depth[0, 0] == 2.0
    dropped = spoil(_frame(1), 1.0)
    assert np.isnan(dropped.depth[:, :3]).all() and (dropped.depth[:, 3:] == 3.0).all()
    assert (spoil(_frame(2), 2.5).depth == 0.0).all()
    black = spoil(_frame(3), 3.0)
    assert (black.rgb == 0).all() and not black.mask.any() and (black.depth == 5.0).all()
    assert spoil(_frame(7), 3.99).rgb.max() == 0  # still black
    assert spoil(_frame(8), 4.2).rgb[0, 0, 0] == 8
    frozen = spoil(_frame(9), 4.5)
    assert (frozen.rgb == 8).all() and (frozen.depth == 10.0).all()  # the frame delivered before
    assert spoil(_frame(5), 5.5).rgb[0, 0, 0] == 5  # the window ends at start + duration
    stale = spoil(_frame(6), 6.2)  # frozen depth: the image and the mask live, the depth before
    assert (stale.rgb == 6).all() and (stale.depth == 7.0).all() and spoil(_frame(4), 6.9).depth[0, 0] == 7.0
    assert spoil(_frame(2), 7.0).depth[0, 0] == 4.0
    half = FaultInjector([SimFault("depth_dropout", 0.0, 1.0, share=0.5)], seed=1)(_frame(0), 0.0)
    assert 0.3 < np.isnan(half.depth).mean() < 0.7


def test_fault_metrics_measure_the_stop_the_blind_distance_and_the_restart() -> None:
    t = np.arange(0, 6.0, 0.1)
    v = np.where((t >= 2.3) & (t < 3.5), 0.0, 0.5)  # stops at 2.3 s, drives again at 3.5 s
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * 0.1)])
    zeros = np.zeros_like(t)
    trajectory = Trajectory(t=t, x=x, y=zeros, yaw=zeros, v=v, omega=zeros, plant_distance=zeros + 1)
    driving = [(float(s), not 2.2 <= s < 3.4) for s in t]  # stop command at 2.2 s, drive at 3.4 s
    metrics = fault_metrics([SimFault("zero_depth", 2.0, 1.2)], trajectory, driving)
    assert metrics["fault_stop_s"] == pytest.approx(0.2)
    assert metrics["fault_blind_m"] == pytest.approx(0.15)  # 2.0 to 2.3 s at 0.5 m/s
    assert metrics["fault_resume_s"] == pytest.approx(0.2)  # the fault ends at 3.2 s
    never = fault_metrics([SimFault("black_frame", 0.5, 1.0)], trajectory, driving)  # no stop while it lasted
    assert math.isnan(never["fault_stop_s"]) and never["fault_blind_m"] == pytest.approx(0.5)
    assert all(math.isnan(value) for value in fault_metrics([], trajectory, driving).values())
    # A fault the run never reached neither fails nor hides the one it did reach.
    later = SimFault("black_frame", 20.0, 1.0)
    assert fault_metrics([SimFault("zero_depth", 2.0, 1.2), later], trajectory, driving) == metrics


@pytest.mark.parametrize(("kind", "stop_s"), [("black_frame", 0.2), ("zero_depth", 0.2), ("frozen_depth", 0.3)])
def test_a_simulated_fault_stops_the_robot_within_0_3_m_and_it_drives_on(kind: str, stop_s: float) -> None:
    """Within a command (0.2 s), or for a frozen stream within frozen_s (0.25 s) and a frame."""
    world = FakeWorld()
    config = dataclasses.replace(_config(length_m=3.0), faults=[SimFault(kind, 2.0, 1.0)])
    simulator = RowEnv(world, FakeRenderer(world), config)
    episode = run_episode(simulator, make_follower("segmind", 5.0, config), OracleSegmenter(), seed=3)
    assert episode.reason == "success", episode.reason
    metrics = fault_metrics(config.faults, episode.trajectory, episode.driving)
    assert metrics["fault_stop_s"] <= stop_s and metrics["fault_blind_m"] < 0.3 and metrics["fault_resume_s"] <= 0.5
    stopped = [t for t, driving in episode.driving if not driving and t > 0.5]
    assert stopped and min(stopped) >= 2.0 and max(stopped) < 3.5


def test_the_report_gives_the_worst_fault_metrics_per_field_and_method() -> None:
    from segmin.nav_eval.evaluation.records import RunResult
    from segmin.nav_eval.evaluation.report import faults_markdown

    def result(run: int, stop: float, blind: float, resume: float) -> RunResult:
        return RunResult(
            field="pear_field", method="segmind", run=run, seed=run, model="oracle", success=True, reason="success",
            fault_stop_s=stop, fault_blind_m=blind, fault_resume_s=resume,
        )  # fmt: skip

    faults = [SimFault("black_frame", 4.0, 2.0), SimFault("depth_dropout", 8.0, 1.0, region="left", share=0.5)]
    text = faults_markdown([result(0, 0.1, 0.18, 0.1), result(1, 0.2, 0.25, math.nan)], faults)
    assert "Injected in every run: black_frame 4-6 s; depth_dropout 8-9 s, left half, share 0.5." in text
    assert "| pear_field | segmind | 0.20 | 0.25 | never |" in text
