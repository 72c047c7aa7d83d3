"""Processes in a network namespace that holds only loopback: how the tests run anything that
opens sockets to peers (DDS, a Ray cluster), so that nothing leaves the machine."""

from __future__ import annotations

import subprocess

import pytest

LOOPBACK_UP = 'ip link set lo up && exec "$@"'


def in_loopback_namespace(
    argv: list[str], timeout: float, *, script: str = LOOPBACK_UP, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess:
    """argv run by `script` (which brings lo up, then execs "$@") in a new network namespace with
    only loopback; fails the test where none can be made or it holds more than lo."""
    probe = subprocess.run(
        ["unshare", "-n", "bash", "-c", "ip link set lo up && ip -o link show"],
        capture_output=True,
        text=True,
        check=False,
    )
    if probe.returncode != 0:
        pytest.fail(f"cannot make a loopback-only network namespace (unshare -n, needs root): {probe.stderr.strip()}")
    links = [line.split(":")[1].strip() for line in probe.stdout.splitlines()]
    if links != ["lo"]:
        pytest.fail(f"the network namespace holds {links}, not only lo")
    return subprocess.run(
        ["unshare", "-n", "bash", "-c", script, "bash", *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        check=False,
    )
