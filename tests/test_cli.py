"""The `segmin` command: every subcommand has help, the navigator demo and benchmark run."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys

import cv2
import pytest

from segmin.app.cli import build_parser, main


def _all_subparsers(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield prefix + (name,), sub
                yield from _all_subparsers(sub, prefix + (name,))


def test_top_level_help_lists_the_subcommands() -> None:
    out = subprocess.run([sys.executable, "-m", "segmin.app.cli", "--help"], capture_output=True, text=True, check=True)
    for name in ("navigate-demo", "bench"):
        assert name in out.stdout


def test_every_subcommand_has_help(capsys: pytest.CaptureFixture[str]) -> None:
    paths = [path for path, _ in _all_subparsers(build_parser())]
    assert ("navigate-demo",) in paths and ("bench", "navigator") in paths
    for path in paths:
        with pytest.raises(SystemExit) as exit_info:
            build_parser().parse_args([*path, "--help"])
        assert exit_info.value.code == 0
        assert "usage: segmin " + " ".join(path) in capsys.readouterr().out


def _leaves(parser: argparse.ArgumentParser) -> list[tuple[str, ...]]:
    """The commands a user can run: every parser path with no subcommands under it."""
    subparsers = list(_all_subparsers(parser))
    parents = {path[:-1] for path, _ in subparsers}
    return [path for path, _ in subparsers if path not in parents]


def test_the_cli_keeps_the_users_commands_and_only_their_benches() -> None:
    leaves = _leaves(build_parser())
    benches = sorted(path[1] for path in leaves if path[0] == "bench")
    assert benches == ["model-speed", "navigator", "ros2"]
    assert len(leaves) <= 22, leaves


def test_the_benchmark_runner_has_every_developer_bench_with_help(capsys: pytest.CaptureFixture[str]) -> None:
    from benchmarks.cli import build_parser as benchmarks_parser

    targets = sorted(path[0] for path in _leaves(benchmarks_parser()))
    assert targets == sorted(
        [
            "synth",
            "render-agreement",
            "train",
            "iou-bound",
            "export",
            "architectures",
            "litert",
            "nav-eval",
            "replay-bag",
            "live-view",
            "gym",
            "executor",
        ]
    )
    for target in targets:
        with pytest.raises(SystemExit) as exit_info:
            benchmarks_parser().parse_args([target, "--help"])
        assert exit_info.value.code == 0
        assert f"usage: python -m benchmarks {target}" in capsys.readouterr().out
    out = subprocess.run([sys.executable, "-m", "benchmarks", "--help"], capture_output=True, text=True, check=True)
    assert "iou-bound" in out.stdout


def test_navigate_demo_writes_the_figure_and_summary(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["navigate-demo", "--out", str(tmp_path), "--size", "64"]) == 0
    figure = cv2.imread(str(tmp_path / "navigator_demo.png"))
    assert figure is not None and figure.shape[0] > 300 and figure.shape[1] > 600
    summary = (tmp_path / "summary.txt").read_text()
    for method in ("segmin", "segmind", "segzeros"):
        assert summary.count(method) >= 4
    assert "no free corridor: stop" in summary  # SegZeros under the closed canopy
    assert "figure:" in capsys.readouterr().out


def test_navigate_demo_rejects_a_tiny_size(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["navigate-demo", "--out", "unused", "--size", "8"]) == 2
    assert "--size must be at least 32" in capsys.readouterr().err


def test_bench_navigator_prints_every_method(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "navigator", "--size", "64", "--steps", "20"]) == 0
    out = capsys.readouterr().out
    for method in (
        "segmin",
        "segmind",
        "segzeros",
        "segmind, mask_closing 8",
        "segcorridor",
        "segcorridor, trunk mode",
        "segcorridor, centre hold",
    ):
        assert re.search(rf"^  {method} +median [0-9.]+ ms  p95 [0-9.]+ ms", out, re.M), out


def test_configs_list_shows_every_shipped_kind(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["configs", "list"]) == 0
    out = capsys.readouterr().out
    for kind, name in (
        ("worlds", "straight_vineyard"),
        ("train", "vineyards"),
        ("nav", "default"),
        ("pipeline", "quick"),
    ):
        assert re.search(rf"^{kind}:.*\n  .*\b{name}\b", out, re.M), out


def test_configs_copy_writes_an_editable_file_that_works_as_a_path(tmp_path, capsys) -> None:
    from segmin.data.synth.spec import load_world_spec

    assert main(["configs", "copy", "straight_vineyard", str(tmp_path)]) == 0
    copied = tmp_path / "straight_vineyard.yaml"
    assert load_world_spec(copied) == load_world_spec("straight_vineyard")
    assert main(["configs", "copy", "straight_vineyard", str(tmp_path)]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["configs", "copy", "quick", str(tmp_path)]) == 2  # both a train and a pipeline config
    assert "pipeline/quick" in capsys.readouterr().err
    assert main(["configs", "copy", "pipeline/quick", str(tmp_path)]) == 0


def test_configs_copy_into_a_file_says_it_is_a_file(tmp_path, capsys) -> None:
    blocker = tmp_path / "A"
    blocker.write_text("")
    assert main(["configs", "copy", "straight_vineyard", str(blocker)]) == 2
    assert capsys.readouterr().err == f"segmin: error: {blocker} is a file, not a folder\n"


def test_unknown_names_list_the_shipped_ones(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["synth", "preview", "--world", "no_such_world", "--out", "x.png"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "straight_vineyard" in err and "no_such_world" in err


def test_an_os_error_is_one_line_and_debug_shows_the_traceback(tmp_path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    args = ["configs", "copy", "straight_vineyard", str(blocker / "sub")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("segmin: error: ") and err.count("\n") == 1 and str(blocker) in err
    assert main(["--debug", *args]) == 2
    assert "Traceback" in capsys.readouterr().err
