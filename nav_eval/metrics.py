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

import dataclasses
import math
from typing import Any

import numpy as np

from segmin.common.angles import wrap_angle


def project_onto_polyline(points: np.ndarray, polyline: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project points (N, 2) onto a polyline (K, 2).

    Returns (s, lateral, tangent): arc length of the projection from the first vertex (the
    first and last segments are extended beyond the ends, so s < 0 before the entrance),
    signed lateral offset (left of the direction of travel positive) and the tangent angle.
    """
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    line = np.asarray(polyline, dtype=float)
    if line.ndim != 2 or line.shape[0] < 2 or line.shape[1] != 2:
        raise ValueError(f"centreline must be (K>=2, 2), got {line.shape}")
    a, b = line[:-1], line[1:]
    seg = b - a
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    keep = seg_len > 1e-12
    a, seg, seg_len = a[keep], seg[keep], seg_len[keep]
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])[:-1]
    rel = pts[:, None, :] - a[None, :, :]                              # N x S x 2
    t = (rel * seg[None]).sum(-1) / (seg_len**2)[None]                 # N x S
    lo = np.zeros_like(t)
    hi = np.ones_like(t)
    lo[:, 0] = -np.inf                                                 # extend before the entrance
    hi[:, -1] = np.inf                                                 # and after the exit
    tc = np.clip(t, lo, hi)
    foot = a[None] + tc[..., None] * seg[None]
    dist2 = ((pts[:, None, :] - foot) ** 2).sum(-1)
    k = np.argmin(dist2, axis=1)
    rows = np.arange(pts.shape[0])
    s = cum[k] + tc[rows, k] * seg_len[k]
    d = seg[k] / seg_len[k, None]
    r = pts - a[k]
    lateral = d[:, 0] * r[:, 1] - d[:, 1] * r[:, 0]                    # cross(d, r): left positive
    tangent = np.arctan2(d[:, 1], d[:, 0])
    return s, lateral, tangent


def polyline_length(polyline: np.ndarray) -> float:
    line = np.asarray(polyline, dtype=float)
    return float(np.hypot(*np.diff(line, axis=0).T).sum())


@dataclasses.dataclass
class Trajectory:
    """What the simulator records at every tick (arrays of equal length)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    v: np.ndarray
    omega: np.ndarray
    plant_distance: np.ndarray   # footprint-to-nearest-trunk gap per tick (inf when no plants)

    @classmethod
    def from_rows(cls, rows: list[tuple[float, ...]]) -> "Trajectory":
        arr = np.asarray(rows, dtype=float).reshape(-1, 7)
        return cls(*(arr[:, i].copy() for i in range(7)))

    def to_dict(self, digits: int = 5) -> dict[str, list[float]]:
        """JSON-ready lists, rounded (1e-5 m is far below anything measured; keeps files small)."""
        return {f.name: [round(float(v), digits) for v in getattr(self, f.name)] for f in dataclasses.fields(self)}


def lateral_mae_mse(x: np.ndarray, y: np.ndarray, centreline: np.ndarray) -> tuple[float, float]:
    """MAE and MSE of the lateral deviation of the points (x, y) from the centreline."""
    _, lat, _ = project_onto_polyline(np.stack([x, y], axis=1), centreline)
    return float(np.mean(np.abs(lat))), float(np.mean(lat**2))


def heading_average(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, centreline: np.ndarray) -> float:
    """Cumulative heading average: mean |yaw - centreline tangent at the projection| (rad)."""
    _, _, tangent = project_onto_polyline(np.stack([x, y], axis=1), centreline)
    return float(np.mean(np.abs(wrap_angle(np.asarray(yaw) - tangent))))


def compute_metrics(
    traj: Trajectory, centreline: np.ndarray, *, success: bool, clearance_time: float | None, collisions: int
) -> dict[str, Any]:
    """The per-run metric row (plain floats, NaN where undefined)."""
    n = len(traj.t)
    if n == 0:
        nan = float("nan")
        return {"clearance_time": nan, "mae": nan, "mse": nan, "heading_avg": nan, "v_avg": nan,
                "omega_std": nan, "collisions": collisions, "min_plant_distance": nan, "distance": 0.0}
    s, lat, tangent = project_onto_polyline(np.stack([traj.x, traj.y], axis=1), centreline)
    return {
        "clearance_time": float(clearance_time) if success and clearance_time is not None else float("nan"),
        "mae": float(np.mean(np.abs(lat))),
        "mse": float(np.mean(lat**2)),
        "heading_avg": float(np.mean(np.abs(wrap_angle(traj.yaw - tangent)))),
        "v_avg": float(np.mean(traj.v)),
        "omega_std": float(np.std(traj.omega)),
        "collisions": int(collisions),
        "min_plant_distance": float(np.min(traj.plant_distance)) if np.isfinite(traj.plant_distance).any() else float("inf"),
        "distance": float(s[-1] - s[0]),
    }


def mean_std(values: list[float]) -> tuple[float, float, int]:
    """Mean and sample standard deviation (ddof=1; 0 for one value) of the finite values."""
    arr = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if arr.size == 0:
        return float("nan"), float("nan"), 0
    std = float(np.std(arr, ddof=1)) if arr.size > 1 else 0.0
    return float(np.mean(arr)), std, int(arr.size)
