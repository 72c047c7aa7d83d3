"""The records of nav-eval's matrix: a `Job` (one run to drive) and its `RunResult` (one row of
results.csv / results.json), shared by the evaluation, the sweeps and the pipeline's report."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from segmin.nav_eval.runtime.methods import STATISTIC_COLUMNS
from segmin.nav_eval.sim.track import Trajectory


@dataclasses.dataclass
class RunResult:
    """One row of results.csv / results.json (the trajectory is kept aside for the plots)."""

    field: str
    method: str
    run: int
    seed: int
    model: str
    success: bool
    reason: str
    error: str = ""
    clearance_time: float = math.nan
    mae: float = math.nan
    mse: float = math.nan
    heading_avg: float = math.nan
    v_avg: float = math.nan
    omega_std: float = math.nan
    collisions: int = 0
    min_plant_distance: float = math.nan
    distance: float = math.nan
    goal_m: float = math.nan
    sim_time: float = math.nan
    wall_time: float = math.nan
    depth_threshold: float = math.nan
    gap: int = -1
    start_x: float = math.nan
    start_y: float = math.nan
    start_yaw: float = math.nan
    # The configured sensor faults' worst (sim.faults.fault_metrics): NaN without faults.
    fault_stop_s: float = math.nan
    fault_blind_m: float = math.nan
    fault_resume_s: float = math.nan
    # The navigator's per-run statistics (`statistics()`, e.g. SegCorridor's mode shares), by column
    # name: a row has every method's columns (methods.STATISTIC_COLUMNS), NaN where its navigator
    # reported none.
    statistics: dict[str, float] = dataclasses.field(default_factory=dict)
    trajectory: Trajectory | None = dataclasses.field(default=None, repr=False)
    commands: list = dataclasses.field(default_factory=list, repr=False)

    def row(self) -> dict[str, Any]:
        """Plain row without the trajectory (for CSV and JSON), the statistics flattened in place:
        first every method's columns in their order, then any the methods do not declare."""
        row: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if f.name == "statistics":
                row.update({column: self.statistics.get(column, math.nan) for column in STATISTIC_COLUMNS})
                row.update({k: v for k, v in self.statistics.items() if k not in STATISTIC_COLUMNS})
            elif f.name not in ("trajectory", "commands"):
                row[f.name] = getattr(self, f.name)
        return row

    @classmethod
    def from_row(cls, row: dict[str, Any]) -> RunResult:
        """A RunResult from a `row()` read back (results.json, a sweep's stored run); keys that are
        neither a field nor a statistic column (e.g. the config) are left out, and so are the
        statistics a row holds as NaN or None (the navigator reported none)."""
        names = {f.name for f in dataclasses.fields(cls)} - {"statistics", "trajectory", "commands"}
        statistics = {
            k: v
            for k, v in row.items()
            if k in STATISTIC_COLUMNS and v is not None and not (isinstance(v, float) and math.isnan(v))
        }
        return cls(**{k: v for k, v in row.items() if k in names}, statistics=statistics)

    @classmethod
    def from_stored(cls, entry: dict[str, Any]) -> RunResult:
        """A run kept by `run_store.store_run`, with its trajectory when it was kept."""
        result = cls.from_row(entry["result"])
        if entry.get("trajectory") is not None:
            result.trajectory = Trajectory(**{k: np.asarray(v, dtype=float) for k, v in entry["trajectory"].items()})
        return result


@dataclasses.dataclass
class Job:
    field: str
    method: str
    run: int
    seed: int
    video_path: str = ""
    bag_path: str = ""  # write the run as a rosbag2 (MCAP) folder here (sim.bag_recorder)
    live_port: int = 0  # stream the run to a live view on this port (nav_eval.live; 0: not)
    # The run's own NavEvalConfig as plain data (`to_dict`), when it is not the worker's: a sweep
    # runs many configs on one pool. None: the worker's config.
    config: dict | None = None
