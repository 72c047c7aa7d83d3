"""Per-run navigation metrics (the paper's Table 3 columns, plus a few that explain failures).

Definitions (all on the robot's trajectory sampled at every simulation tick, uniform in time):
- lateral deviation e_i: signed distance from the robot centre to the ground-truth centreline
  of the row gap (positive to the left of the driving direction). The centreline is a polyline
  from the row entrance to the exit; a point is projected onto its nearest segment, so curved
  rows are handled exactly as straight ones ("interpolated at the robot's position along the row").
- MAE = mean |e_i|, MSE = mean e_i^2 (m, m^2).
- cumulative heading average = mean over the run of |wrap(yaw_i - tangent_i)|, where tangent_i is
  the direction of the centreline at the robot's projection (rad). We use the centreline tangent
  rather than the bearing to the goal: the goal bearing tends to 0 error only far from the goal
  and is undefined on curves once the goal is behind the bend.
- clearance time: simulated seconds from the start to covering the run length; NaN on failure.
- v_avg: mean executed linear velocity (m/s); omega_std: standard deviation of the executed
  angular velocity (rad/s), both over the whole run.
- collisions: number of footprint-vs-trunk/post contacts (a run stops at the first one).
- min_plant_distance: smallest gap between the footprint rectangle and a trunk circle (m).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from segmin.common.angles import wrap_angle
from segmin.nav_eval.sim.track import Trajectory, project_onto_polyline

# The per-run metric keys, in the order of the results table's columns (report.CSV_COLUMNS).
METRIC_KEYS = (
    "clearance_time",
    "mae",
    "mse",
    "heading_avg",
    "v_avg",
    "omega_std",
    "collisions",
    "min_plant_distance",
    "distance",
)


def compute_metrics(
    traj: Trajectory, centreline: np.ndarray, *, success: bool, clearance_time: float | None, collisions: int
) -> dict[str, Any]:
    """The per-run metric row (plain floats, NaN where undefined)."""
    n = len(traj.t)
    if n == 0:
        return {**dict.fromkeys(METRIC_KEYS, float("nan")), "collisions": collisions, "distance": 0.0}
    s, lat, tangent = project_onto_polyline(np.stack([traj.x, traj.y], axis=1), centreline)
    return {
        "clearance_time": float(clearance_time) if success and clearance_time is not None else float("nan"),
        "mae": float(np.mean(np.abs(lat))),
        "mse": float(np.mean(lat**2)),
        "heading_avg": float(np.mean(np.abs(wrap_angle(traj.yaw - tangent)))),
        "v_avg": float(np.mean(traj.v)),
        "omega_std": float(np.std(traj.omega)),
        "collisions": int(collisions),
        "min_plant_distance": float(np.min(traj.plant_distance))
        if np.isfinite(traj.plant_distance).any()
        else float("inf"),
        "distance": float(s[-1] - s[0]),
    }


def mean_std(values: list[float]) -> tuple[float, float, int]:
    """Mean and sample standard deviation (ddof=1; 0 for one value) of the finite values."""
    arr = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if arr.size == 0:
        return float("nan"), float("nan"), 0
    std = float(np.std(arr, ddof=1)) if arr.size > 1 else 0.0
    return float(np.mean(arr)), std, int(arr.size)
