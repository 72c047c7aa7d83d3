"""Train several crop families at once, one process each: the pipeline's `parallel_training`.

Process management only: what one training does is `stages.train_stage_logged`; which stages
need training, and their records, are the runner's.
"""

from __future__ import annotations

import os
import pickle
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

from segmin.app.pipeline import stages


def train_side_by_side(todo: dict[str, tuple[Any, Path, bool]], log: Callable[[str], None]) -> dict[str, Any]:
    """Train several families at once, one process each (their configs say how many threads).

    On the 2-core demo machine two 1-thread trainings finish sooner than the same two one after
    the other with 2 threads (0.62 against 0.75 s a training step of 16 frames at 192 px):
    torch's second thread gains far less than a second process. Each process writes its own
    log to `train.log` in its stage folder; this one shows one progress bar over all epochs.
    The processes sit in process groups of their own, so a Ctrl-C reaches this process only,
    which passes exactly one on to each: they finish their step, save `last.pt` and stop.
    Returns each family's stage outputs, or the exception that ended it.
    """
    import multiprocessing

    from tqdm import tqdm

    total = sum(config.epochs for config, _, _ in todo.values())
    context = multiprocessing.get_context("spawn")  # torch's thread pools do not survive a fork
    results = context.Queue()
    processes = {
        family: context.Process(
            target=_train_family, args=(results, family, config, folder, resume), name=f"train-{family}"
        )
        for family, (config, folder, resume) in todo.items()
    }
    with tqdm(total=total, unit="epoch", desc="train") as bar:
        for process in processes.values():
            process.start()
        log(
            "train: side by side, "
            + ", ".join(
                f"{family} (pid {process.pid}, log {todo[family][1] / 'train.log'})"
                for family, process in processes.items()
            )
        )
        try:
            return _wait_for_outcomes(results, processes, todo, bar)
        except KeyboardInterrupt:
            for process in processes.values():
                if process.is_alive() and process.pid is not None:  # alive: started, so it has a pid
                    os.kill(process.pid, signal.SIGINT)
            raise
        finally:
            for process in processes.values():
                process.join()


def _wait_for_outcomes(
    results: Any, processes: dict[str, Any], todo: dict[str, tuple[Any, Path, bool]], bar
) -> dict[str, Any]:
    """Every family's outcome as it arrives; the bar follows the epochs the runs have logged."""
    import queue as queues

    outcomes: dict[str, Any] = {}
    while len(outcomes) < len(processes):
        try:
            family, outputs = results.get(timeout=5.0)
            outcomes[family] = outputs
        except queues.Empty:
            _collect_ended(results, processes, todo, outcomes)
        epochs = sum(len(stages.read_metrics_csv(folder / "metrics.csv")) for _, folder, _ in todo.values())
        bar.update(epochs - bar.n)
    return outcomes


def _collect_ended(
    results: Any, processes: dict[str, Any], todo: dict[str, tuple[Any, Path, bool]], outcomes: dict[str, Any]
) -> None:
    """After a quiet wait: the outcomes of processes that have ended, or an error naming their log."""
    import queue as queues

    ended = [f for f, p in processes.items() if f not in outcomes and p.exitcode is not None]
    while ended:  # a result sent just before the end may still be in the pipe
        try:
            family, outputs = results.get_nowait()
            outcomes[family] = outputs
        except queues.Empty:
            break
    for family in ended:  # killed, or died without a word
        outcomes.setdefault(
            family,
            RuntimeError(
                f"train/{family}: the training process ended with exit code "
                f"{processes[family].exitcode} and no result; see {todo[family][1] / 'train.log'}"
            ),
        )


def _train_family(results: Any, family: str, config: Any, folder: Path, resume: bool) -> None:
    """One family's training in its own process (and process group: Ctrl-C comes from the parent)."""
    os.setpgrp()
    try:
        outcome: Any = stages.train_stage_logged(config, folder, resume)
    except BaseException as exc:  # sent back whole: the parent raises it once the others are done
        outcome = exc
        try:
            pickle.dumps(exc)
        except Exception:
            outcome = RuntimeError(f"train/{family}: {type(exc).__name__}: {exc}")
    results.put((family, outcome))
