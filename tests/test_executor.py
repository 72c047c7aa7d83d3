"""The executor choice: the local pool and Ray give the same outputs (frames byte for byte,
results tables), a Ray render resumes like a local one, and a bad or unavailable choice is one
line. The Ray tests share one local Ray instance (2 CPUs, no dashboard, loopback only)."""

from __future__ import annotations

import csv
import functools
import socket
import sys
import time
from pathlib import Path

import pytest
from synth_helpers import tiny

from segmin.app.cli import main as segmin_main
from segmin.common.executor import Executor, connect_ray
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.spec import spec_from_dict
from segmin.data.synth.writer import RenderJob, render_dataset
from segmin.nav_eval.evaluation.evaluate import run_evaluation
from segmin.nav_eval.sim.config import load_nav_config

RAY = Executor("ray")
NAV = ["perception.width=32", "perception.height=32", "run.length_m=0.6", "run.time_limit_s=4"]


@pytest.fixture(scope="module")
def ray_instance():
    import ray  # the [test] extra installs it: the Ray executor is tested in CI

    ray.init(
        address="local",  # a new instance for the tests, whatever RAY_ADDRESS says
        num_cpus=2,
        include_dashboard=False,
        _node_ip_address="127.0.0.1",
        object_store_memory=100 * 1024 * 1024,
        configure_logging=False,
        log_to_driver=False,
    )
    yield ray
    ray.shutdown()


def _render(out: Path, executor: Executor, frames: int = 4) -> dict:
    job = RenderJob(
        spec=spec_from_dict(tiny()),
        out=out,
        frames=frames,
        camera=CameraModel(width=32, height=32),
        workers=2,
        progress=False,
        executor=executor,
        appearance_every=2,
    )
    return render_dataset(job)


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_ray_renders_the_local_pools_frames_and_resumes_like_it(ray_instance, tmp_path) -> None:
    _render(tmp_path / "local", Executor())
    assert _render(tmp_path / "ray", RAY)["written"] == 4
    local, on_ray = _tree(tmp_path / "local"), _tree(tmp_path / "ray")
    assert len([name for name in local if name.endswith(".png")]) == 12 and on_ray == local
    # A run killed after three frames leaves the fourth missing: the rerun renders only it.
    frame = next((tmp_path / "ray").rglob("Image3"))
    for folder in (frame, frame.parents[1] / "masks" / "Image3", frame.parents[1] / "depths" / "Image3"):
        for file in folder.iterdir():
            file.unlink()
        folder.rmdir()
    summary = _render(tmp_path / "ray", RAY)
    assert (summary["written"], summary["skipped"]) == (1, 3) and _tree(tmp_path / "ray") == local


def test_ray_nav_eval_writes_the_local_pools_results(ray_instance, tmp_path) -> None:
    config = load_nav_config(overrides=NAV)
    tables = {}
    for name, executor in (("local", Executor()), ("ray", RAY)):
        out = tmp_path / name
        results = run_evaluation(
            "oracle", "straight_vineyard", "segmin", 2, out, 2, config, progress=False, plots=False, executor=executor
        )
        assert len(results) == 2 and all(r.reason != "error" for r in results)
        with open(out / "results.csv", newline="") as handle:  # all but the wall-clock time of a run
            tables[name] = [{k: v for k, v in row.items() if k != "wall_time"} for row in csv.DictReader(handle)]
    assert len(tables["local"][0]) > 20 and tables["ray"] == tables["local"]


def test_a_bad_executor_choice_is_one_line(tmp_path, capsys, monkeypatch) -> None:
    with pytest.raises(ValueError, match="executor: 'dask'"):
        Executor("dask")
    args = ["nav-eval", "--model", "oracle", "--out", str(tmp_path / "a"), "--ray-address", "auto"]
    assert segmin_main(args) == 2 and "for the ray executor" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "ray", None)  # what an install without [cluster] looks like
    assert segmin_main(["nav-eval", "--model", "oracle", "--out", str(tmp_path / "b"), "--executor", "ray"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'segmin[cluster]'" in err[0]
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


@pytest.fixture
def ray_must_not_start(monkeypatch):
    """Ray unconnected, and `ray.init` a failure: an unreachable address must stop before it (Ray
    itself retries such an address for minutes)."""
    import ray

    def init(*_, **__):
        raise AssertionError("ray.init was reached with an unreachable address")

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", init)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)


def _closed_loopback_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_an_unreachable_ray_address_is_one_line_naming_it(ray_must_not_start, tmp_path, capsys, monkeypatch) -> None:
    address = f"127.0.0.1:{_closed_loopback_port()}"  # nothing listens there: refused at once
    args = ["nav-eval", "--model", "oracle", "--out", str(tmp_path / "a"), "--executor", "ray"]
    assert segmin_main([*args, "--ray-address", address]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"Ray cluster {address} (--ray-address): cannot connect" in err[0], err
    monkeypatch.setenv("RAY_ADDRESS", f"ray://{address}")  # Ray Client form, from the environment
    assert segmin_main(args) == 2
    assert f"Ray cluster ray://{address} (RAY_ADDRESS): cannot connect" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()


def test_a_profile_s_unreachable_ray_address_names_its_config_key(ray_must_not_start) -> None:
    from segmin.app.pipeline.config import load_pipeline_config

    address = f"127.0.0.1:{_closed_loopback_port()}"
    executor = load_pipeline_config("micro", ["executor=ray", f"ray_address={address}"]).fan_out()
    with pytest.raises(ConnectionError, match=rf"^Ray cluster {address} \(ray_address\): cannot connect"):
        executor.run([1], lambda: None, 1, lambda job, result: None, lambda job, error: None)


def test_a_ray_address_that_never_answers_times_out_in_the_time_given(ray_must_not_start) -> None:
    with socket.socket() as server:  # a full accept queue: the kernel drops further connections unanswered
        server.bind(("127.0.0.1", 0))
        server.listen(0)
        address = f"127.0.0.1:{server.getsockname()[1]}"
        with socket.create_connection(server.getsockname(), timeout=1.0):
            start = time.monotonic()
            with pytest.raises(ConnectionError, match=rf"^Ray cluster {address} \(--ray-address\): .*within 0.3 s"):
                connect_ray(address, timeout_s=0.3)
            assert time.monotonic() - start < 3.0


def test_bench_executor_times_both_executors(ray_instance, capsys) -> None:
    from benchmarks.executor import ExecutorBenchOptions, bench_executor

    options = ExecutorBenchOptions(frames=2, size=32, runs=3, rounds=1, nav_overrides=tuple(NAV))
    ratios = bench_executor(options)
    assert set(ratios) == {"render", "nav-eval"} and all(0 < r < 100 for r in ratios.values())
    assert "ray / local time: render 2 frames" in capsys.readouterr().out


def test_a_ray_actor_that_dies_fails_only_its_job(ray_instance) -> None:
    import test_processes
    from test_processes import SquareWorker

    ray_instance.cloudpickle.register_pickle_by_value(test_processes)  # the actors cannot import tests/

    results: dict[int, object] = {}
    RAY.run([1, 2, 13, 4, 5], functools.partial(SquareWorker, 100), 2, results.__setitem__, lambda job, why: why)
    assert sorted(results) == [1, 2, 4, 5, 13] and "died during this run (3 times)" in str(results[13]), results
    assert {job: value for job, (value, _) in ((j, r) for j, r in results.items() if j != 13)} == {
        1: 101,
        2: 104,
        4: 116,
        5: 125,
    }
