"""Where fanned-out jobs run: the local process pool (the default) or a Ray cluster.

`synth render`, `nav-eval`, `robustness` and the pipeline's render and nav-eval stages all hand
their jobs to `Executor.run`: a list of picklable jobs, a picklable `make_worker` that builds one
long-lived worker (a built field, a loaded segmenter) wherever it runs, and `done(job, result)`
called in this process as each job finishes, in completion order. The caller keeps everything
that makes a run resumable and reproducible (which jobs are left, where results are written, the
progress bar) on its side of `done`; the executor only decides where `worker.run(job)` happens:

- `local`: `processes` processes of this machine (`segmin.common.processes`);
- `ray`: as many Ray actors, each with one CPU and a worker of its own, on the cluster at
  `ray_address` (else `RAY_ADDRESS`, else a Ray instance started here for the run). Ray is
  imported only then; without it the command says which extra installs it.

A job whose worker dies (or raises) becomes `failed(job, why)`, on either executor.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from segmin.common.processes import JobWorker, StartMethod, run_in_processes

J = TypeVar("J")
R = TypeVar("R")

EXECUTORS = ("local", "ray")
"""The values of `--executor` and of the pipeline's `executor` key."""


@dataclasses.dataclass(frozen=True)
class Executor:
    """An executor choice, as the command line and the pipeline config give it."""

    kind: str = "local"
    ray_address: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in EXECUTORS:
            raise ValueError(f"executor: {self.kind!r} is not one of {list(EXECUTORS)}")
        if self.ray_address is not None and self.kind != "ray":
            raise ValueError(
                f"ray address {self.ray_address!r} given with executor {self.kind!r}: an address is for the ray executor"
            )

    def run(
        self,
        jobs: Sequence[J],
        make_worker: Callable[[], JobWorker[J, R]],
        processes: int,
        done: Callable[[J, R], None],
        failed: Callable[[J, str], R],
        start_method: StartMethod = "spawn",
    ) -> None:
        """Run `jobs` on `processes` workers (local processes, started by `start_method`, or Ray
        actors), calling `done(job, result)` here as each finishes."""
        if self.kind == "local":
            run_in_processes(jobs, make_worker, processes, done, failed, start_method)
        else:
            run_on_ray(jobs, make_worker, processes, done, failed, self.ray_address)


LOCAL = Executor()
"""The default: this machine's processes."""


class RayHost:
    """What one Ray actor holds: one worker, made on the node, kept for every job it is given."""

    def __init__(self, make_worker: Callable[[], JobWorker[Any, Any]]) -> None:
        self.worker = make_worker()

    def run(self, job: Any) -> Any:
        return self.worker.run(job)

    def close(self) -> None:
        self.worker.close()


def import_ray() -> Any:
    """The ray module, or a ModuleNotFoundError the command line turns into the [cluster] advice."""
    try:
        import ray
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError(
            "--executor ray needs Ray, the [cluster] extra: pip install 'segmin[cluster]'", name="ray"
        ) from exc
    return ray


def connect_ray(address: str | None) -> bool:
    """Connect this process to Ray unless it already is: `address`, else `RAY_ADDRESS` (Ray reads
    it), else a local instance. True when this call connected (so the caller disconnects)."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    ray.init(address=address, configure_logging=False, log_to_driver=True)
    return True


def run_on_ray(
    jobs: Sequence[J],
    make_worker: Callable[[], JobWorker[J, R]],
    actors: int,
    done: Callable[[J, R], None],
    failed: Callable[[J, str], R],
    address: str | None,
) -> None:
    """`run_in_processes` on Ray actors: each actor takes the next job as soon as it returns one."""
    ray = import_ray()
    connected = connect_ray(address)
    host = ray.remote(num_cpus=1)(RayHost)
    pending = deque(jobs)
    started = [host.remote(make_worker) for _ in range(min(actors, len(pending)))]
    running: dict[Any, tuple[Any, J]] = {}  # result ref -> (actor, job)
    dead: list[Any] = []

    def next_job(actor: Any) -> None:
        if pending:
            job = pending.popleft()
            running[actor.run.remote(job)] = (actor, job)

    try:
        for actor in started:
            next_job(actor)
        while running:
            [ref], _ = ray.wait(list(running), num_returns=1)
            actor, job = running.pop(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayActorError as exc:  # the actor (its process or node) died
                dead.append(actor)
                done(job, failed(job, f"the Ray actor died during this run: {_cause_line(exc)}"))
                continue
            except ray.exceptions.RayTaskError as exc:  # the worker raised: the actor lives on
                done(job, failed(job, f"the worker raised: {_cause_line(exc)}"))
            else:
                done(job, result)
            next_job(actor)
        while pending:  # every actor died: nothing runs these
            job = pending.popleft()
            done(job, failed(job, "no Ray actor left to run it (they all died)"))
        ray.get([actor.close.remote() for actor in started if actor not in dead], timeout=60)
    finally:
        for actor in started:
            ray.kill(actor)
        if connected:
            ray.shutdown()


def _cause_line(exc: BaseException) -> str:
    """The last non-empty line of a Ray error (its cause), for a one-line failure reason."""
    lines = [line for line in str(exc).splitlines() if line.strip()]
    return lines[-1].strip() if lines else type(exc).__name__
