"""One override grammar: positional KEY=VALUE on every command that takes overrides, --set as an alias."""

from __future__ import annotations

import pytest

from segmin.app.cli import build_parser
from segmin.common.cli_args import is_override, overrides_of


@pytest.fixture(scope="module")
def parser():
    return build_parser()


@pytest.mark.parametrize(
    "argv",
    [
        ["synth", "render", "--world", "w", "--frames", "2", "--out", "d", "rows.length=10", "seed=3"],
        ["synth", "preview", "--world", "w", "--out", "p.png", "rows.length=10", "seed=3"],
        ["nav-eval", "--model", "oracle", "--out", "o", "rows.length=10", "seed=3"],
        ["bench", "nav-eval", "rows.length=10", "seed=3"],
        ["train", "--config", "c.yaml", "rows.length=10", "seed=3"],
        ["pipeline", "rows.length=10", "seed=3"],
    ],
)
def test_every_command_takes_positional_overrides(parser, argv):
    assert overrides_of(parser.parse_args(argv)) == ["rows.length=10", "seed=3"]


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
