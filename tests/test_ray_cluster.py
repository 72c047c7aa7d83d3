"""`--executor ray` on a real cluster: a head and a worker node started with `ray start` on
loopback, token authentication on, inside a network namespace holding only `lo` (root:
`unshare -n`), so nothing reaches past the machine. The render, nav-eval and robustness outputs
equal the local pool's, and losing the worker node in the middle of a nav-eval or a render loses no run and no frame
(`tests/ray_cluster_driver.py` does the work; this checks what it saw)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from loopback import in_loopback_namespace

DRIVER = Path(__file__).with_name("ray_cluster_driver.py")


@pytest.fixture(scope="module")
def cluster_run(tmp_path_factory) -> dict:
    work = tmp_path_factory.mktemp("ray_cluster")
    seen = work / "seen.json"
    done = in_loopback_namespace([sys.executable, str(DRIVER), str(work), str(seen)], timeout=400)
    assert done.returncode == 0 and seen.is_file(), done.stderr[-3000:]
    return json.loads(seen.read_text())


def test_a_two_node_cluster_gives_the_local_pools_outputs(cluster_run) -> None:
    assert cluster_run["nodes"] == 2
    assert cluster_run["frames"] == 120 and cluster_run["render_equal"], cluster_run
    assert cluster_run["runs"] == 4 and cluster_run["nav_errors"] == 0 and cluster_run["nav_equal"], cluster_run
    assert cluster_run["sweep_rows"] == 2 and cluster_run["sweep_equal"], cluster_run


def test_losing_the_worker_node_mid_job_loses_no_run_and_no_frame(cluster_run) -> None:
    assert cluster_run["exit_after_loss"] == 0 and cluster_run["nav_equal_after_loss"], cluster_run
    assert cluster_run["render_exit_after_loss"] == 0 and cluster_run["render_equal_after_loss"], cluster_run
