"""Jobs in worker processes (segmin.common.processes): one worker per process, crashes contained."""

from __future__ import annotations

import functools
import os

from segmin.common.machine import cores_for_this_process, usable_cores
from segmin.common.processes import run_in_processes


class SquareWorker:
    """Squares its jobs; job 13 kills its process (a crash, not an exception)."""

    def __init__(self, offset: int) -> None:
        self.offset = offset
        self.pid = os.getpid()

    def run(self, job: int) -> tuple[int, int]:
        if job == 13:
            os._exit(3)
        return job * job + self.offset, self.pid

    def close(self) -> None:
        pass


def test_each_process_keeps_one_worker_and_a_crash_fails_only_its_job() -> None:
    results: dict[int, object] = {}
    run_in_processes(
        [1, 2, 13, 4, 5, 6],
        functools.partial(SquareWorker, 100),
        2,
        results.__setitem__,
        lambda job, why: why,
    )
    assert sorted(results) == [1, 2, 4, 5, 6, 13]
    assert "died (exit code 3)" in results[13]
    values = {job: value for job, (value, _) in ((j, r) for j, r in results.items() if j != 13)}
    assert values == {1: 101, 2: 104, 4: 116, 5: 125, 6: 136}
    pids = {pid for j, (_, pid) in ((j, r) for j, r in results.items() if j != 13)}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2  # run in (at most two) worker processes


class CoresWorker:
    """Says which share of the cores its process was given."""

    def run(self, job: int) -> int:
        return cores_for_this_process()

    def close(self) -> None:
        pass


def test_each_process_is_told_its_share_of_the_cores() -> None:
    results: dict[int, int] = {}
    run_in_processes([1, 2, 3], CoresWorker, 2, results.__setitem__, lambda job, why: -1)
    assert set(results.values()) == {max(1, usable_cores() // 2)}
    results.clear()
    run_in_processes([1], CoresWorker, 2, results.__setitem__, lambda job, why: -1)  # one job: one process
    assert results == {1: usable_cores()}
