"""One override grammar: positional KEY=VALUE on every command that takes overrides, --set as an alias."""

from __future__ import annotations

import argparse

import pytest

from segmin.app.cli import build_parser
from segmin.common.cli_args import add_overrides, in_line_order, is_override, overrides_of
from segmin.data.frames import DatasetError


@pytest.fixture(scope="module")
def parser():
    return build_parser()


@pytest.mark.parametrize(
    "argv",
    [
        ["synth", "render", "--world", "w", "--frames", "2", "--out", "d", "rows.length=10", "seed=3"],
        ["synth", "preview", "--world", "w", "--out", "p.png", "rows.length=10", "seed=3"],
        ["nav-eval", "--model", "oracle", "--out", "o", "rows.length=10", "seed=3"],
        ["train", "--config", "c.yaml", "rows.length=10", "seed=3"],
        ["pipeline", "rows.length=10", "seed=3"],
    ],
)
def test_every_command_takes_positional_overrides(parser, argv):
    assert overrides_of(parser.parse_args(argv)) == ["rows.length=10", "seed=3"]


@pytest.mark.parametrize(
    "argv",
    [
        ["synth", "render", "rows.length=10", "--world", "w", "--frames", "2", "seed=3", "--out", "d"],
        ["synth", "preview", "--out", "p.png", "rows.length=10", "--size", "64", "seed=3", "--world", "w"],
        ["nav-eval", "--model", "oracle", "--out", "o", "rows.length=10", "--runs", "1", "seed=3"],
        ["train", "--config", "c.yaml", "rows.length=10", "--resume", "seed=3"],
        ["pipeline", "rows.length=10", "--config", "quick", "seed=3", "--out", "o"],
        ["robustness", "vineyards", "rows.length=10", "--out", "o", "--runs", "1", "seed=3"],
    ],
    ids=["render", "preview", "nav-eval", "train", "pipeline", "robustness"],
)
@pytest.mark.filterwarnings("error")  # intermixed parsing warns on an empty override list
def test_overrides_work_wherever_they_stand_on_the_line(parser, argv):
    args = parser.parse_args(argv)
    assert overrides_of(args) == ["rows.length=10", "seed=3"]
    if argv[0] == "robustness":
        assert args.spec == "vineyards"  # the command's own positional keeps its place


@pytest.mark.parametrize(
    "argv",
    [["nav-eval", "rows.length=10", "seed=3"], ["nav-eval", "rows.length=10", "--seed", "2", "seed=3"]],
)
@pytest.mark.filterwarnings("error")
def test_the_benchmark_runner_takes_overrides_anywhere_too(argv):
    from benchmarks.cli import build_parser as benchmarks_parser

    assert overrides_of(benchmarks_parser().parse_args(argv)) == ["rows.length=10", "seed=3"]


def test_the_torchrun_entry_takes_overrides_anywhere_too(tmp_path):
    from segmin.train.cli import main

    with pytest.raises(DatasetError, match="/no_such_root: dataset root does not exist"):
        main(["--config", "quick", "epochs=1", "--out", str(tmp_path / "run"), "--force", "data.root=/no_such_root"])


def test_a_later_value_wins_whichever_spelling_came_first(parser):
    args = parser.parse_args(
        ["nav-eval", "x=1", "--model", "oracle", "--set", "x=2", "--out", "o", "x=3", "--set=x=4", "x=5"]
    )
    assert overrides_of(args) == ["x=1", "x=2", "x=3", "x=4", "x=5"]
    args = parser.parse_args(["synth", "preview", "y=1", "--world", "a", "y=2", "--out", "p.png", "--set", "y=3"])
    assert args.world == ["a"] and overrides_of(args) == ["y=1", "y=2", "y=3"]
    assert in_line_order(["b=2", "a=1"], ["a=1", "--set", "b=2"]) == ["a=1", "b=2"]


def test_overrides_need_the_command_parser():
    with pytest.raises(TypeError, match="CommandParser"):
        add_overrides(argparse.ArgumentParser())  # it would take overrides only before the first option


def test_set_is_an_alias_and_the_command_line_order_is_kept(parser):
    args = parser.parse_args(
        ["nav-eval", "--model", "oracle", "--set", "run.length_m=5", "--out", "o", "run.length_m=7"]
    )
    assert overrides_of(args) == ["run.length_m=5", "run.length_m=7"]  # the later one wins when applied
    args = parser.parse_args(["synth", "render", "--world", "w", "--set", "a=1", "--frames", "1", "--out", "d"])
    assert overrides_of(args) == ["a=1"]


def test_preview_worlds_do_not_swallow_overrides(parser):
    args = parser.parse_args(
        [
            "synth",
            "preview",
            "--world",
            "a",
            "configs/worlds/b.yaml",
            "rows.length=10",
            "--out",
            "p.png",
            "--set",
            "seed=2",
        ]
    )
    assert args.world == ["a", "configs/worlds/b.yaml"]
    assert overrides_of(args) == ["rows.length=10", "seed=2"]


def test_preview_needs_a_world_before_the_overrides(parser, capsys):
    with pytest.raises(SystemExit):
        parser.parse_args(["synth", "preview", "--world", "rows.length=10", "--out", "p.png"])
    assert "at least one name" in capsys.readouterr().err


def test_no_overrides_is_an_empty_list(parser):
    assert overrides_of(parser.parse_args(["pipeline"])) == []


@pytest.mark.parametrize(
    "token,expected",
    [
        ("rows.length=10", True),
        ("a_b-c.d=x=y", True),
        ("straight_vineyard", False),
        ("configs/worlds/a=b.yaml", False),
        ("=3", False),
    ],
)
def test_is_override(token, expected):
    assert is_override(token) is expected
