"""Metric functions and the robot model on hand-made inputs (no simulator)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from segmin.nav_eval.evaluation.metrics import METRIC_KEYS, compute_metrics, mean_std
from segmin.nav_eval.sim.robot import Robot, RobotConfig, footprint_distances
from segmin.nav_eval.sim.track import Trajectory, point_on_polyline, project_onto_polyline


def _straight(n: int = 81) -> np.ndarray:
    x = np.linspace(0.0, 20.0, n)
    return np.stack([x, np.zeros_like(x)], axis=1)


def _arc(radius: float = 8.0, n: int = 400) -> np.ndarray:
    a = np.linspace(0.0, 20.0 / radius, n)  # 20 m of arc turning left around (0, R)
    return np.stack([radius * np.sin(a), radius - radius * np.cos(a)], axis=1)


def _metrics(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, centreline: np.ndarray) -> dict:
    """The metric row of a trajectory through the points (x, y) with headings yaw."""
    ones = np.ones_like(x)
    traj = Trajectory(t=np.arange(x.size) * 0.1, x=x, y=y, yaw=yaw, v=ones, omega=0 * ones, plant_distance=ones)
    return compute_metrics(traj, centreline, success=True, clearance_time=1.0, collisions=0)


def test_straight_offset_gives_mae_01_mse_001() -> None:
    x = np.linspace(0.5, 19.5, 300)
    row = _metrics(x, np.full_like(x, 0.1), np.zeros_like(x), _straight())
    mae, mse = row["mae"], row["mse"]
    assert mae == pytest.approx(0.1, abs=1e-9)
    assert mse == pytest.approx(0.01, abs=1e-9)


def test_curved_offset_gives_mae_01_mse_001() -> None:
    radius = 8.0
    a = np.linspace(0.05, 20.0 / radius - 0.05, 500)
    r = radius - 0.1  # 0.1 m to the inside (left) of the arc
    x, y = r * np.sin(a), radius - r * np.cos(a)
    row = _metrics(x, y, a, _arc(radius))
    mae, mse = row["mae"], row["mse"]
    assert mae == pytest.approx(0.1, abs=2e-4)
    assert mse == pytest.approx(0.01, abs=5e-5)
    _, lat, tangent = project_onto_polyline(np.stack([x, y], 1), _arc(radius))
    assert np.all(lat > 0)  # inside of a left turn is to the left
    assert np.allclose(tangent, a, atol=0.01)
    # Heading along the arc tangent: zero heading error.
    assert row["heading_avg"] == pytest.approx(0.0, abs=0.01)


def test_projection_arc_length_and_sign() -> None:
    s, lat, tangent = project_onto_polyline(np.array([[3.0, -0.2], [-1.0, 0.5], [25.0, 0.0]]), _straight())
    assert s == pytest.approx([3.0, -1.0, 25.0])  # extended past both ends
    assert lat == pytest.approx([-0.2, 0.5, 0.0])
    assert tangent == pytest.approx([0.0, 0.0, 0.0])
    x, y, th = point_on_polyline(_arc(), 8.0 * 0.5)
    assert (x, y, th) == pytest.approx((8 * math.sin(0.5), 8 - 8 * math.cos(0.5), 0.5), abs=4e-3)


def test_compute_metrics_row() -> None:
    t = np.arange(0, 10, 0.1)
    traj = Trajectory(
        t=t,
        x=0.5 * t,
        y=np.full_like(t, -0.1),
        yaw=np.full_like(t, 0.05),
        v=np.full_like(t, 0.5),
        omega=np.where(np.arange(t.size) % 2, 0.1, -0.1),
        plant_distance=np.linspace(1.0, 0.3, t.size),
    )
    row = compute_metrics(traj, _straight(), success=True, clearance_time=9.9, collisions=0)
    assert row["mae"] == pytest.approx(0.1) and row["mse"] == pytest.approx(0.01)
    assert row["heading_avg"] == pytest.approx(0.05)
    assert row["v_avg"] == pytest.approx(0.5) and row["omega_std"] == pytest.approx(0.1)
    assert row["min_plant_distance"] == pytest.approx(0.3)
    assert row["clearance_time"] == pytest.approx(9.9)
    assert tuple(row) == METRIC_KEYS  # the results table's columns follow this order
    failed = compute_metrics(traj, _straight(), success=False, clearance_time=None, collisions=1)
    assert math.isnan(failed["clearance_time"]) and failed["collisions"] == 1
    assert mean_std([1.0, 3.0, float("nan")]) == (2.0, pytest.approx(math.sqrt(2)), 2)


def test_heading_error_wraps_across_plus_minus_pi() -> None:
    """Driving along -x the tangent is pi and the yaw flips between about +pi and -pi: the error
    is 0.05 rad either way, not 2 pi - 0.05 for every yaw on the other side of the cut."""
    centreline = _straight()[::-1]  # from (20, 0) to (0, 0): tangent pi
    t = np.arange(0, 10, 0.1)
    x = 19.5 - 0.5 * t
    yaw = np.where(np.arange(t.size) % 2, math.pi - 0.05, -math.pi + 0.05)
    traj = Trajectory(
        t=t,
        x=x,
        y=np.zeros_like(t),
        yaw=yaw,
        v=np.full_like(t, 0.5),
        omega=np.zeros_like(t),
        plant_distance=np.ones_like(t),
    )
    row = compute_metrics(traj, centreline, success=True, clearance_time=9.9, collisions=0)
    assert row["heading_avg"] == pytest.approx(0.05, abs=1e-12)


def test_footprint_distance_and_collision() -> None:
    circles = np.array([[1.0, 0.0, 0.1], [0.0, 0.5, 0.05], [0.2, 0.0, 0.05]])
    d = footprint_distances(0.0, 0.0, 0.0, circles, 0.51, 0.43)
    assert d[0] == pytest.approx(1.0 - 0.255 - 0.1)
    assert d[1] == pytest.approx(0.5 - 0.215 - 0.05)
    assert d[2] < 0  # centre inside the footprint
    # Turned 90 degrees, the long side faces +y: the second circle gets closer.
    d90 = footprint_distances(0.0, 0.0, math.pi / 2, circles[1:2], 0.51, 0.43)
    assert d90[0] == pytest.approx(0.5 - 0.255 - 0.05)


def test_robot_respects_acceleration_and_lag() -> None:
    cfg = RobotConfig(max_lin_acc=1.0, max_ang_acc=2.0, lag_tau=0.1)
    robot = Robot(cfg)
    robot.reset(0.0, 0.0, 0.0)
    robot.command(0.5, 0.0)
    dt = 1 / 60
    vs = [robot.step(dt).v for _ in range(120)]
    assert np.all(np.diff(vs) <= 1.0 * dt + 1e-12)  # never faster than the acceleration limit
    assert vs[0] < 0.5 and vs[-1] == pytest.approx(0.5, abs=1e-3)
    assert robot.state.x == pytest.approx(sum(vs) * dt, rel=0.02)
    robot.command(0.0, 1.0)
    for _ in range(120):
        robot.step(dt)
    assert robot.state.omega == pytest.approx(1.0, abs=1e-3)


def test_robot_follows_terrain_slope() -> None:
    slope = 0.1
    normal = np.array([-slope, 0.0, 1.0]) / math.hypot(slope, 1.0)
    robot = Robot(RobotConfig(), terrain_height=lambda x, y: slope * x, terrain_normal=lambda x, y: normal)
    s = robot.reset(1.0, 0.0, 0.0)
    assert s.z == pytest.approx(0.1) and s.pitch == pytest.approx(math.atan(slope)) and s.roll == pytest.approx(0.0)
    s = robot.reset(1.0, 0.0, math.pi / 2)  # facing +y: the slope rises to the right
    assert s.pitch == pytest.approx(0.0, abs=1e-9) and s.roll == pytest.approx(-math.atan(slope))


def test_a_run_with_no_ticks_has_undefined_metrics_but_its_collisions() -> None:
    empty = Trajectory.from_rows([])
    row = compute_metrics(empty, _straight(), success=False, clearance_time=None, collisions=1)
    assert tuple(row) == METRIC_KEYS
    assert row["collisions"] == 1 and row["distance"] == 0.0
    assert all(math.isnan(row[key]) for key in METRIC_KEYS if key not in ("collisions", "distance"))
