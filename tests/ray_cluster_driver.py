"""A two-node Ray cluster on loopback running segmin's fan-outs; run by test_ray_cluster.py.

Usage (inside a network namespace holding only loopback): `python tests/ray_cluster_driver.py WORK OUT.json`

Starts a head (`ray start --head`) and a worker node joining it, one CPU each, both on 127.0.0.1,
with token authentication (`RAY_AUTH_MODE=token`, one `RAY_AUTH_TOKEN` for the nodes and every
driver), then runs `segmin synth render`, `nav-eval` and `robustness` with `--executor ray
--ray-address` and with the local pool, and a Ray nav-eval and render during each of which a worker
node is killed (its `ray start --block` process and every process under it: raylet, actors) once the first result is
written. Writes which outputs equal the local pool's as JSON; the test asserts on it.
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PORT = 6390
ADDRESS = f"127.0.0.1:{PORT}"
RAY = [sys.executable, "-m", "ray.scripts.scripts"]
NODE = ["--node-ip-address=127.0.0.1", "--num-cpus=1", "--object-store-memory=80000000", "--disable-usage-stats"]
# 40 frames: 4 jobs of 10 (a render job is one appearance block), so each node holds one when it is lost.
RENDER = ["synth", "render", "--world", "straight_vineyard", "--size", "48", "--frames", "40", "--workers", "2"]
NAV_EVAL = ["nav-eval", "--model", "oracle", "--fields", "straight_vineyard", "--methods", "segmin", "--runs", "4"]
NAV = ["perception.width=32", "perception.height=32", "run.length_m=1.0", "run.time_limit_s=8"]
# The head declares a lost node dead after about 1.5 s (Ray's default is about 15 s).
HEALTH = {
    "RAY_health_check_initial_delay_ms": "0",
    "RAY_health_check_period_ms": "500",
    "RAY_health_check_timeout_ms": "500",
    "RAY_health_check_failure_threshold": "3",
}


def segmin(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "segmin.app.cli", *args, "--no-progress"], check=True)


def tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def table(path: Path) -> list[dict[str, str]]:
    """A results table without each run's wall-clock time."""
    with open(path, newline="") as handle:
        return [{k: v for k, v in row.items() if k != "wall_time"} for row in csv.DictReader(handle)]


def start_head(temp: Path) -> None:
    """The head node (daemons in the background, its files under `temp`)."""
    subprocess.run(
        [*RAY, "start", "--head", f"--port={PORT}", "--include-dashboard=false", f"--temp-dir={temp}", *NODE],
        check=True,
        stdout=subprocess.DEVNULL,
    )


def start_worker() -> subprocess.Popen:
    """A worker node joining the head (`--block`: its processes live under this one, to kill),
    once the cluster counts two live nodes."""
    worker = subprocess.Popen(
        [*RAY, "start", f"--address={ADDRESS}", "--block", *NODE], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    import ray

    ray.init(address=ADDRESS, configure_logging=False, log_to_driver=False)
    try:
        deadline = time.monotonic() + 60
        while sum(node["Alive"] for node in ray.nodes()) < 2:
            if time.monotonic() > deadline:
                raise RuntimeError("the worker node did not join the head within 60 s")
            time.sleep(0.5)
    finally:
        ray.shutdown()
    return worker


def descendants(root: int) -> list[int]:
    """The processes started under `root`: a node's raylet, its agents and its actors (which run in
    process groups of their own, so killing the node's group would leave them running their job)."""
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            pid, rest = stat.read_text().split(" (", 1)
        except OSError:
            continue  # ended meanwhile
        parents[int(pid)] = int(rest.rsplit(") ", 1)[1].split()[1])
    found, frontier = [], [root]
    while frontier:
        children = [pid for pid, parent in parents.items() if parent in frontier]
        found += children
        frontier = children
    return found


def kill_node_when(worker: subprocess.Popen, results: Path, pattern: str, command: list[str]) -> int:
    """Run `segmin COMMAND` and kill the worker node once a first result (`pattern`) is in the
    folder `results`; the command's exit status."""
    job = subprocess.Popen([sys.executable, "-m", "segmin.app.cli", *command, "--no-progress"])
    while not any(results.glob(pattern)):
        if job.poll() is not None:
            raise RuntimeError(f"{command[0]} ended before its first result was written")
        time.sleep(0.05)
    for pid in [*descendants(worker.pid), worker.pid]:
        with contextlib.suppress(ProcessLookupError):  # ended meanwhile
            os.kill(pid, signal.SIGKILL)
    worker.wait()
    return job.wait(timeout=120)


def main() -> None:
    work, out = Path(sys.argv[1]), Path(sys.argv[2])
    os.environ.update(HEALTH, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32))
    os.environ.pop("RAY_ADDRESS", None)
    on_ray = ["--executor", "ray", "--ray-address", ADDRESS]
    seen: dict[str, object] = {}
    temp = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: Ray's socket paths live under it
    workers: list[subprocess.Popen] = []
    try:
        start_head(temp)
        workers.append(start_worker())
        seen["nodes"] = 2
        segmin(*RENDER, "--out", str(work / "render_local"))
        segmin(*RENDER, "--out", str(work / "render_ray"), *on_ray)
        local_frames = tree(work / "render_local")
        seen["frames"] = sum(name.endswith(".png") for name in local_frames)
        seen["render_equal"] = tree(work / "render_ray") == local_frames

        nav_args = [*NAV_EVAL, "--workers", "2", "--no-plots", *NAV]
        segmin(*nav_args, "--out", str(work / "nav_local"))
        segmin(*nav_args, "--out", str(work / "nav_ray"), *on_ray)
        local_results = table(work / "nav_local" / "results.csv")
        seen["runs"] = len(local_results)
        seen["nav_errors"] = sum(row["reason"] == "error" for row in local_results)
        seen["nav_equal"] = table(work / "nav_ray" / "results.csv") == local_results

        sweep = work / "sweep.yaml"
        sweep.write_text(
            json.dumps(
                {
                    "base": "straight_vineyard",
                    "methods": ["segmin"],
                    "runs": 1,
                    "robot": "kinematic",
                    "overrides": NAV,
                    "parameters": {"row_spacing": [1.8, 2.2]},
                }
            )
        )
        segmin("robustness", str(sweep), "--workers", "2", "--no-plots", "--out", str(work / "sweep_local"))
        segmin("robustness", str(sweep), "--workers", "2", "--no-plots", "--out", str(work / "sweep_ray"), *on_ray)
        seen["sweep_rows"] = len(table(work / "sweep_local" / "sweep.csv"))
        seen["sweep_equal"] = table(work / "sweep_ray" / "sweep.csv") == table(work / "sweep_local" / "sweep.csv")

        lost = work / "nav_lost"
        seen["exit_after_loss"] = kill_node_when(workers[-1], lost, "runs/*", [*nav_args, "--out", str(lost), *on_ray])
        seen["nav_equal_after_loss"] = table(lost / "results.csv") == local_results

        workers.append(start_worker())
        lost = work / "render_lost"
        seen["render_exit_after_loss"] = kill_node_when(
            workers[-1], lost, "**/*.png", [*RENDER, "--out", str(lost), *on_ray]
        )
        seen["render_equal_after_loss"] = tree(lost) == local_frames
    finally:
        subprocess.run([*RAY, "stop", "--force"], check=False, capture_output=True)
        for worker in workers:
            worker.wait(timeout=30)
        shutil.rmtree(temp, ignore_errors=True)
    out.write_text(json.dumps(seen))


if __name__ == "__main__":
    main()
