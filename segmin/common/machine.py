"""One line about the machine a run or benchmark used: shared machines are noisy, so figures say where they came from."""

from __future__ import annotations

import os
import platform
import sys

WORKER_CORES_VARIABLE = "SEGMIN_WORKER_CORES"
"""Set by a process pool in each worker it starts: the cores that worker may count on as its own."""


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the platform says, else all)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def cores_for_this_process() -> int:
    """The cores this process may keep busy: its share where a pool started it among others
    (`WORKER_CORES_VARIABLE`), else every core it may run on."""
    share = os.environ.get(WORKER_CORES_VARIABLE, "")
    return max(1, int(share)) if share.isdigit() else usable_cores()


def load_average_1min() -> float | None:
    """The 1-minute load average as a number (None where the platform has none), for benchmark JSON."""
    try:
        return float(os.getloadavg()[0])
    except (OSError, AttributeError):
        return None


def load_average() -> str:
    """The 1-minute load average against the core count, e.g. "load 0.4 on 2 cores"."""
    return f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"


def machine_summary() -> str:
    """One line about where this ran (for the report)."""
    import torch

    device = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU"
    return (
        f"{platform.platform(terse=True)}, Python {sys.version.split()[0]}, {os.cpu_count()} CPU cores, "
        f"{device}, torch {torch.__version__}"
    )
