"""Ctrl-C lands between training steps, never inside one.

A SIGINT that arrives while the optimizer is updating the weights would leave the saved state
inconsistent: weights after step k+1 recorded as "k steps done", so `--resume` runs step k+1
again and the weights differ from an uninterrupted run. `StepGuard` defers the interrupt while
a step (forward, backward, optimizer update, bookkeeping) is in flight and raises it as soon as
the step is finished; outside a step (waiting for the data loader) Ctrl-C is immediate.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


class StepGuard:
    """Install with `with StepGuard() as guard:`, wrap each step in `with guard.step():`.

    Only the main thread can own signal handlers, and only Python's default Ctrl-C handler is
    replaced (a process that ignores SIGINT, e.g. a loader worker, keeps ignoring it).
    """

    def __init__(self) -> None:
        self._in_step = False
        self._pending = False
        self._installed = False

    def __enter__(self) -> StepGuard:
        if (
            threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler
        ):
            signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(self, *exc: object) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, signal.default_int_handler)  # the only handler __enter__ replaces
            self._installed = False

    def _handle(self, signum: int, frame: object) -> None:
        if self._in_step:
            self._pending = True  # finish the step first; raised in step()'s exit
        else:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def step(self) -> Iterator[None]:
        """The body runs to its end even when Ctrl-C arrives; the interrupt is raised right after."""
        self._in_step = True
        try:
            yield
        finally:
            self._in_step = False
        if self._pending:
            self._pending = False
            raise KeyboardInterrupt
