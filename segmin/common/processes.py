"""Jobs run in worker processes, each process with one long-lived worker object of its own.

A closed-loop worker is worth keeping between runs: it holds built fields (a pybullet world each)
and a loaded segmenter. A process pool keeps nothing between its tasks but module globals, so
each process here runs one explicit worker instead, made inside the process by `make_worker` (a
picklable callable: a `functools.partial` of the worker's constructor), and the parent hands it
jobs one at a time over a pipe, the next as soon as it sends a result back: a long run holds one
process while the others go on.

Processes are spawned by default: pybullet and onnxruntime hold threads. A caller whose parent
holds neither (synth render) may fork instead, which saves each worker the imports. A worker turns a
run's exceptions into results; a process that dies (a crash, a kill) fails the job it was
running, and once none is left the jobs not yet given out fail too, each as `failed(job, why)`.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Sequence
from multiprocessing import get_context
from multiprocessing.connection import Connection, wait
from multiprocessing.context import ForkContext, SpawnContext
from typing import Generic, Literal, Protocol, TypeVar

from segmin.common.machine import WORKER_CORES_VARIABLE, usable_cores

J = TypeVar("J")
R = TypeVar("R")
J_contra = TypeVar("J_contra", contravariant=True)
R_co = TypeVar("R_co", covariant=True)
StartMethod = Literal["spawn", "fork"]


class JobWorker(Protocol[J_contra, R_co]):
    """What runs the jobs inside one process."""

    def run(self, job: J_contra) -> R_co:
        """The result of one job (never raises for a job that fails: the result says so)."""
        ...

    def close(self) -> None:
        """Release what the worker holds (pybullet clients) before the process exits."""
        ...


def serve(make_worker: Callable[[], JobWorker[J, R]], connection: Connection, cores: int) -> None:
    """A worker process's life: note its share of the cores (`machine.cores_for_this_process`:
    the gl renderer's threads follow it), make its worker, then run each job received until None comes."""
    os.environ[WORKER_CORES_VARIABLE] = str(cores)
    worker = make_worker()
    try:
        while (job := connection.recv()) is not None:
            connection.send(worker.run(job))
    finally:
        worker.close()
        connection.close()


class _Process(Generic[J]):
    """One worker process as the parent sees it: its end of the pipe and the job it is running."""

    def __init__(self, context: SpawnContext | ForkContext, make_worker: Callable[[], JobWorker], cores: int) -> None:
        self.connection, child = context.Pipe()
        self.process = context.Process(target=serve, args=(make_worker, child, cores), daemon=True)
        self.process.start()
        child.close()  # the child's end lives in the child: EOF here when it dies
        self.job: J | None = None

    def give(self, job: J | None) -> bool:
        """Send the next job (None: stop); False when the process is gone."""
        self.job = job
        try:
            self.connection.send(job)
        except OSError:  # a broken pipe: the process died
            return False
        return True

    def died(self) -> str:
        """Why the job it ran has no result."""
        self.process.join(timeout=5.0)
        return f"the worker process died (exit code {self.process.exitcode}) during this run"


def run_in_processes(
    jobs: Sequence[J],
    make_worker: Callable[[], JobWorker[J, R]],
    processes: int,
    done: Callable[[J, R], None],
    failed: Callable[[J, str], R],
    start_method: StartMethod = "spawn",
) -> None:
    """Run `jobs` on up to `processes` processes (spawned unless `start_method` says "fork"),
    calling `done(job, result)` in the parent as each finishes (in completion order)."""
    context = get_context("fork") if start_method == "fork" else get_context("spawn")
    pending = deque(jobs)
    started: list[_Process[J]] = []
    busy: dict[Connection, _Process[J]] = {}

    def next_job(process: _Process[J]) -> None:
        if not pending:
            process.give(None)
            return
        job = pending.popleft()
        if process.give(job):
            busy[process.connection] = process
        else:  # it died before taking the job: another process runs it
            pending.appendleft(job)

    count = min(processes, len(pending))
    cores = max(1, usable_cores() // max(1, count))  # each process's share, for its own thread pools
    try:
        for _ in range(count):
            started.append(_Process(context, make_worker, cores))
            next_job(started[-1])
        while busy:
            ready = wait(list(busy))
            for process in [busy.pop(connection) for connection in list(busy) if connection in ready]:
                job = process.job
                assert job is not None
                try:
                    result = process.connection.recv()
                except EOFError:  # it died running this job
                    done(job, failed(job, process.died()))
                    continue
                done(job, result)
                next_job(process)
        while pending:  # every process died: nothing runs these
            job = pending.popleft()
            done(job, failed(job, "no worker process left to run it (they all died)"))
    except BaseException:  # Ctrl-C or a failing `done`: stop the workers now
        for process in started:
            process.process.terminate()
        raise
    finally:
        for process in started:
            process.process.join()
            process.connection.close()
