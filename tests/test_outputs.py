"""Output locations are checked before any work: a path below a regular file fails at once,
naming the path. The CLI maps these OSErrors to one line, exit 2; the tests
call each command's function so they hold before and after that mapping."""

from __future__ import annotations

from pathlib import Path

import pytest

from segmin.common.atomic import write_text
from segmin.common.outputs import check_output_dir, check_output_file, make_dirs


@pytest.fixture()
def somefile(tmp_path: Path) -> Path:
    path = tmp_path / "somefile"
    path.write_text("not a folder")
    return path


def _run(argv: list[str]) -> int:
    from segmin.app.cli import build_parser

    args = build_parser().parse_args(argv)
    return args.func(args)


def test_make_dirs_names_the_file_in_the_way(somefile, tmp_path):
    """mkdir -p says "File exists" / "Not a directory"; make_dirs says which file is in the way."""
    with pytest.raises(FileExistsError, match=f"^{somefile} is a file, not a folder$"):
        make_dirs(somefile)
    with pytest.raises(NotADirectoryError, match=f"^--out {somefile}/x: {somefile} is a file, not a folder$"):
        make_dirs(somefile / "x", "--out")
    with pytest.raises(FileExistsError, match=f"^{somefile} is a file, not a folder$"):
        write_text(somefile / "a.txt", "")  # every atomic write makes its folder through it
    assert make_dirs(tmp_path / "a" / "b").is_dir() and make_dirs(tmp_path / "a").is_dir()


def test_the_helpers_name_the_path_and_the_file(somefile, tmp_path):
    with pytest.raises(NotADirectoryError, match=f"--out {somefile}/x/y: {somefile} is a file"):
        check_output_dir(somefile / "x" / "y")
    with pytest.raises(FileExistsError, match="is a file, not a folder"):
        check_output_dir(somefile)
    with pytest.raises(NotADirectoryError, match=str(somefile)):
        check_output_file(somefile / "p.png")
    with pytest.raises(IsADirectoryError, match="is a folder"):
        check_output_file(tmp_path)
    assert check_output_dir(tmp_path / "new" / "dir") == tmp_path / "new" / "dir"
    assert not (tmp_path / "new").exists()  # checks create nothing


@pytest.mark.parametrize(
    "argv",
    [
        ["synth", "preview", "--world", "straight_vineyard", "--out", "{f}/p.png"],
        ["synth", "render", "--world", "straight_vineyard", "--frames", "1", "--out", "{f}/ds"],
        ["export", "--checkpoint", "{f}/../missing.pt", "--out", "{f}/m.onnx"],
        ["nav-eval", "--model", "oracle", "--fields", "straight_vineyard", "--out", "{f}/eval"],
        ["train", "--config", "quick", "--out", "{f}/run", "data.root=/nonexistent"],
        ["pipeline", "--config", "micro", "--out", "{f}/run"],
        [
            "replay",
            "--model",
            "m.onnx",
            "--rgb",
            "{f}",
            "--method",
            "segmin",
            "--depth-threshold",
            "5",
            "--out",
            "{f}/r",
        ],
        ["navigate-demo", "--out", "{f}/demo"],
        ["eval-seg", "--model", "m.onnx", "--out", "{f}/eval"],
        ["configs", "copy", "straight_vineyard", "{f}/configs"],
    ],
    ids=[
        "preview",
        "render",
        "export",
        "nav-eval",
        "train",
        "pipeline",
        "replay",
        "navigate-demo",
        "eval-seg",
        "configs-copy",
    ],
)
def test_every_command_refuses_an_output_below_a_file_before_working(somefile, argv):
    argv = [a.replace("{f}", str(somefile)) for a in argv]
    with pytest.raises(NotADirectoryError, match=f"{somefile} is a file, not a folder"):
        _run(argv)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["synth", "render", "--world", "straight_vineyard", "--frames", "1", "rows.count=1"], "rows.count"),
        (["synth", "render", "--world", "straight_vineyard", "--frames", "0"], "--frames"),
        (["pipeline", "--config", "micro", "nav.overrides=[run.lenght_m=3]"], "lenght_m"),
        (["nav-eval", "--model", "oracle", "--fields", "straight_vineyard", "run.lenght_m=3"], "lenght_m"),
        (["train", "--config", "quick", "data.root=/nonexistent"], "/nonexistent"),
    ],
    ids=["render-spec", "render-frames", "pipeline", "nav-eval", "train"],
)
def test_a_refused_command_leaves_no_empty_output_folder(tmp_path, capsys, argv, message):
    """The checks run before --out is created: a typo must not leave a folder behind that the
    next, corrected run then finds (or refuses)."""
    from segmin.app.cli import main

    out = tmp_path / "out"
    assert main([*argv, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
