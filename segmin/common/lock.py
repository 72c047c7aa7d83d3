"""One writer per output: an exclusive lock file that names its holder (pid and host).

Two processes writing the same dataset step on each other: the second one's start-up clean-up
removes the first one's staging folders. `writer_lock` takes an `flock` on a lock file, so the
kernel releases it when the holder dies (even by kill -9): a lock file left by a dead process
is stale and is taken over, while a live holder makes the second writer fail at once with a
message naming the holder. A clean exit removes the file.

A forked child (the render's worker pool) inherits the locked descriptor, and an flock lives
until every copy is closed: a writer killed with its workers would keep the lock until the last
orphan finished dying, and a rerun started at once was refused. Forked children therefore close
their copies at once (the parent's copy still holds the lock): the lock dies with its holder.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

from segmin.common.outputs import make_dirs

_HELD: set[int] = set()  # descriptors this process holds locks on, closed in forked children


def _close_inherited() -> None:
    for fd in _HELD:
        with contextlib.suppress(OSError):
            os.close(fd)
    _HELD.clear()


os.register_at_fork(after_in_child=_close_inherited)


class LockHeldError(FileExistsError):
    """Another live process holds the lock; the message names it and the lock file."""


def _holder(fd: int) -> dict:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        return json.loads(os.read(fd, 4096).decode("utf-8") or "{}")
    except (OSError, ValueError):
        return {}


def _open_locked(path: Path, what: str) -> int:
    """An fd of `path` holding its flock; retried when the file was replaced meanwhile."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            who = f"pid {holder.get('pid', '?')} on {holder.get('host', '?')}" if holder else "another process"
            since = (
                time.strftime(" since %Y-%m-%d %H:%M:%S", time.localtime(holder["started"]))
                if isinstance(holder.get("started"), (int, float))
                else ""
            )
            raise LockHeldError(
                f"{path}: {what} is being written by {who}{since}; "
                "wait for it to finish or stop it (one writer at a time)"
            ) from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # the holder released and removed it between our open and flock: try again


@contextlib.contextmanager
def writer_lock(path: str | Path, what: str) -> Iterator[dict]:
    """Hold `path` exclusively for the block; yields the previous holder's record ({} if none).

    A non-empty record means the previous writer died without releasing (a stale lock taken
    over). LockHeldError when a live process holds it. The file is removed on release (while
    still locked; a process that opened it meanwhile notices the swap and retries).
    """
    path = Path(path)
    make_dirs(path.parent)
    fd = _open_locked(path, what)
    _HELD.add(fd)
    try:
        previous = _holder(fd)
        record = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time(), "what": what}
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, json.dumps(record).encode("utf-8"))
        try:
            yield previous
        finally:
            path.unlink(missing_ok=True)
    finally:
        _HELD.discard(fd)
        os.close(fd)  # releases the flock
