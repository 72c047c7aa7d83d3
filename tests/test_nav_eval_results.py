"""Result rows of the closed-loop evaluation: the navigators' statistics as columns."""

from __future__ import annotations

import csv
import json
import math

from segmin.nav_eval.evaluation.records import RunResult
from segmin.nav_eval.evaluation.report import write_results
from segmin.nav_eval.runtime.methods import STATISTIC_COLUMNS

# results.json's row keys before the statistics became a mapping: reports and sweeps read these.
ROW_KEYS = [
    "field",
    "method",
    "run",
    "seed",
    "model",
    "success",
    "reason",
    "error",
    "clearance_time",
    "mae",
    "mse",
    "heading_avg",
    "v_avg",
    "omega_std",
    "collisions",
    "min_plant_distance",
    "distance",
    "goal_m",
    "sim_time",
    "wall_time",
    "depth_threshold",
    "gap",
    "start_x",
    "start_y",
    "start_yaw",
    "fault_stop_s",
    "fault_blind_m",
    "fault_resume_s",
    "one_side_share",
    "trunk_share",
    "fallback_share",
]


def _result(method: str, **statistics: float) -> RunResult:
    return RunResult(
        field="pear_field", method=method, run=0, seed=1, model="oracle", success=True, reason="success", mae=0.1,
        statistics=statistics,
    )  # fmt: skip


def test_statistics_flatten_into_the_same_columns_for_every_method(tmp_path) -> None:
    corridor = _result("segcorridor", one_side_share=0.25, trunk_share=0.0, fallback_share=0.125)
    paper = _result("segmin")
    assert list(corridor.row()) == ROW_KEYS == list(paper.row())
    assert [corridor.row()[k] for k in STATISTIC_COLUMNS] == [0.25, 0.0, 0.125]
    assert all(math.isnan(paper.row()[k]) for k in STATISTIC_COLUMNS)
    write_results(tmp_path, [corridor, paper], {"model": "oracle", "config": {}})
    rows = json.loads((tmp_path / "results.json").read_text())["rows"]
    assert [sorted(r) for r in rows] == [sorted([*ROW_KEYS, "config"])] * 2  # (written with sorted keys)
    assert (rows[0]["fallback_share"], rows[1]["fallback_share"]) == (0.125, None)
    with (tmp_path / "results.csv").open() as f:
        header = next(csv.reader(f))
    assert "fallback_share" not in header and header[:3] == ["field", "method", "run"]


def test_a_row_read_back_is_the_same_result() -> None:
    corridor = _result("segcorridor", one_side_share=0.25, trunk_share=0.0, fallback_share=0.125)
    again = RunResult.from_row({**corridor.row(), "config": {"run": {}}})
    assert again.statistics == corridor.statistics and again.row() == corridor.row()
    paper = RunResult.from_row({**_result("segmin").row(), "one_side_share": None})
    assert paper.statistics == {} and paper.mae == 0.1


def test_a_statistic_no_method_declares_is_kept_after_the_declared_ones() -> None:
    row = _result("segfuture", lanes_seen=3.0).row()
    assert list(row)[-1] == "lanes_seen" and row["lanes_seen"] == 3.0
    assert list(row)[:-1] == ROW_KEYS
