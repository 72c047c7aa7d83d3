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
  imported only then; without it the command says which extra installs it. A cluster address
  that does not answer within `RAY_CONNECT_TIMEOUT_S` is one line naming it (Ray itself retries
  for minutes, printing only its own retry lines).

A job whose worker raises becomes `failed(job, why)`, on either executor; so does a job whose
local worker process dies. On Ray, a job whose actor dies (its node lost) is run again on another
actor (`MAX_ATTEMPTS`), and the dead actor is replaced, so losing a node loses no job.
"""

from __future__ import annotations

import dataclasses
import os
import socket
from collections import Counter, deque
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from segmin.common.machine import WORKER_CORES_VARIABLE
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
    address_source: str = "--ray-address"  # where the address came from, for the error that names it

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
            run_on_ray(jobs, make_worker, processes, done, failed, self.ray_address, self.address_source)


LOCAL = Executor()
"""The default: this machine's processes."""


class RayHost:
    """What one Ray actor holds: one worker, made on the node, kept for every job it is given."""

    def __init__(self, make_worker: Callable[[], JobWorker[Any, Any]]) -> None:
        os.environ[WORKER_CORES_VARIABLE] = "1"  # the one CPU Ray gives each actor (`_RayPool`)
        self.worker = make_worker()

    def ready(self) -> None:
        """Returns once the worker is made: a replacement actor takes jobs only then."""

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


RAY_CONNECT_TIMEOUT_S = 5.0
"""How long a Ray cluster's address has to accept a connection before the command stops, naming
it: a cluster's head answers in milliseconds, and a wrong address should not cost minutes."""

_NO_CLUSTER_ADDRESSES = ("", "auto", "local")  # a local instance (started, or found by Ray): nothing to probe


def _host_and_port(address: str) -> tuple[str, int] | None:
    """(host, port) of `head:6379` or `ray://head:10001`; None for what Ray resolves itself."""
    if address.strip().lower() in _NO_CLUSTER_ADDRESSES:
        return None
    host, _, port = address.strip().removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return None  # not host:port: Ray says what is wrong with it
    return host.strip("[]"), int(port)


def check_ray_address(
    address: str | None, timeout_s: float = RAY_CONNECT_TIMEOUT_S, source: str = "--ray-address"
) -> None:
    """ConnectionError naming the address and where it came from (`source`: the flag or config
    key) when nothing accepts a connection there within `timeout_s` (`address`, else
    `RAY_ADDRESS`, as Ray reads them); before `ray.init`, which would retry an unreachable cluster
    for minutes."""
    given = address if address is not None else os.environ.get("RAY_ADDRESS")
    target = None if given is None else _host_and_port(given)
    if target is None:
        return
    origin = source if address is not None else "RAY_ADDRESS"
    try:
        with socket.create_connection(target, timeout=timeout_s):
            pass
    except TimeoutError:
        reason = f"no answer within {timeout_s:g} s"
    except OSError as exc:
        reason = exc.strerror or str(exc) or type(exc).__name__
    else:
        return
    raise ConnectionError(
        f"Ray cluster {given} ({origin}): cannot connect ({reason}); check the address and that the cluster "
        "runs (`ray status` on its head)"
    )


def connect_ray(address: str | None, timeout_s: float = RAY_CONNECT_TIMEOUT_S, source: str = "--ray-address") -> bool:
    """Connect this process to Ray unless it already is: `address`, else `RAY_ADDRESS` (Ray reads
    it), else a local instance. True when this call connected (so the caller disconnects). A
    cluster that does not answer within `timeout_s` is a ConnectionError naming its address."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    check_ray_address(address, timeout_s, source)
    ray.init(address=address, configure_logging=False, log_to_driver=True)
    return True


MAX_ATTEMPTS = 3
"""How many times a job is started when the Ray actors running it die (their node lost, killed):
it goes back to the queue for another actor until then, so a lost node loses no job, while a job
that itself kills its worker (a crash, every time) fails after that many tries."""

ACTOR_START_TIMEOUT_S = 60.0
"""How long jobs left with no actor running wait for a replacement actor to start (a lost node's
actors start again wherever a CPU is free) before they fail."""


class _RayPool:
    """The driver's side of a Ray run: the job queue, the actors and what each one runs."""

    def __init__(self, ray: Any, jobs: Sequence[Any], make_worker: Callable[[], JobWorker[Any, Any]]) -> None:
        self.ray = ray
        self.host = ray.remote(num_cpus=1)(RayHost)
        self.make_worker = make_worker
        self.pending: deque[tuple[int, Any]] = deque(enumerate(jobs))
        self.losses: Counter[int] = Counter()  # job index -> how many actors died running it
        self.started: list[Any] = []  # every actor, to kill at the end
        self.starting: dict[Any, Any] = {}  # ready ref -> a replacement actor not yet known to run
        self.running: dict[Any, tuple[Any, int, Any]] = {}  # result ref -> (actor, job index, job)
        self.idle: list[Any] = []  # live actors with no job (the queue was empty when they asked)

    def start_actor(self) -> Any:
        actor = self.host.remote(self.make_worker)
        self.started.append(actor)
        return actor

    def next_job(self, actor: Any) -> None:
        """Give `actor` the next job, or keep it idle."""
        if self.pending:
            index, job = self.pending.popleft()
            self.running[actor.run.remote(job)] = (actor, index, job)
        else:
            self.idle.append(actor)

    def lost(self, index: int, job: Any) -> bool:
        """The actor running `job` died: queue the job again (True) unless it has had its
        `MAX_ATTEMPTS`, and start a replacement actor."""
        self.losses[index] += 1
        again = self.losses[index] < MAX_ATTEMPTS
        if again:
            self.pending.appendleft((index, job))
        replacement = self.start_actor()
        self.starting[replacement.ready.remote()] = replacement
        while self.idle and self.pending:
            self.next_job(self.idle.pop())
        return again

    def wait(self) -> Any | None:
        """The next finished job or started replacement; None when none comes (every actor died,
        and no replacement found a CPU within `ACTOR_START_TIMEOUT_S`) or nothing is left to do."""
        if not self.running and not (self.pending and self.starting):
            return None
        timeout = None if self.running else ACTOR_START_TIMEOUT_S
        ready, _ = self.ray.wait([*self.running, *self.starting], num_returns=1, timeout=timeout)
        return ready[0] if ready else None

    def close(self) -> None:
        """Close the workers of the live actors, then kill every actor."""
        closing = [actor.close.remote() for actor in self.idle]
        self.ray.wait(closing, num_returns=len(closing), timeout=60)
        for actor in self.started:
            self.ray.kill(actor)


def run_on_ray(
    jobs: Sequence[J],
    make_worker: Callable[[], JobWorker[J, R]],
    actors: int,
    done: Callable[[J, R], None],
    failed: Callable[[J, str], R],
    address: str | None,
    source: str = "--ray-address",
) -> None:
    """`run_in_processes` on Ray actors: each actor takes the next job as soon as it returns one.

    A job whose actor dies under it (its node lost) goes back to the front of the queue, for the
    next free actor, up to `MAX_ATTEMPTS` starts; each dead actor is replaced by a new one, which
    Ray places wherever a CPU is free, so the outputs equal a run without the failure."""
    ray = import_ray()
    connected = connect_ray(address, source=source)
    lost_errors = (ray.exceptions.RayActorError, ray.exceptions.ObjectLostError)
    pool = _RayPool(ray, jobs, make_worker)
    try:
        for _ in range(min(actors, len(jobs))):
            pool.next_job(pool.start_actor())
        while (ref := pool.wait()) is not None:
            if ref in pool.starting:  # a replacement actor is up, or died starting
                actor = pool.starting.pop(ref)
                try:
                    ray.get(ref)
                except lost_errors:
                    continue
                pool.next_job(actor)
                continue
            actor, index, job = pool.running.pop(ref)
            try:
                result = ray.get(ref)
            except lost_errors as exc:  # the actor (its process or node) died, or its result went with its node
                if not pool.lost(index, job):
                    done(
                        job,
                        failed(job, f"the Ray actor died during this run ({MAX_ATTEMPTS} times): {_cause_line(exc)}"),
                    )
                continue
            except ray.exceptions.RayTaskError as exc:  # the worker raised: the actor lives on
                done(job, failed(job, f"the worker raised: {_cause_line(exc)}"))
            else:
                done(job, result)
            pool.next_job(actor)
        while pool.pending:  # no actor left to run these
            _, job = pool.pending.popleft()
            done(job, failed(job, "no Ray actor left to run it (they all died, and none could start again)"))
    finally:
        pool.close()
        if connected:
            ray.shutdown()


def _cause_line(exc: BaseException) -> str:
    """The last non-empty line of a Ray error (its cause), for a one-line failure reason."""
    lines = [line for line in str(exc).splitlines() if line.strip()]
    return lines[-1].strip() if lines else type(exc).__name__
