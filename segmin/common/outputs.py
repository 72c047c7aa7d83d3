"""Check where an output will go before any work is done.

`--out somefile/x` used to fail late (after rendering, training or a whole evaluation) with a
bare NotADirectoryError deep in a write, or not at all until the first checkpoint. These checks
run first and name the path and the offending file; they create nothing.
"""

from __future__ import annotations

from pathlib import Path


def _check_parents(path: Path, what: str) -> None:
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise NotADirectoryError(f"{what} {path}: {parent} is a file, not a folder")
            return


def check_output_dir(path: str | Path, what: str = "--out") -> Path:
    """`path` can be (or already is) a folder: FileExistsError when it is a file,
    NotADirectoryError when a parent is a file."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{what} {path}: is a file, not a folder")
    _check_parents(path, what)
    return path


def check_output_file(path: str | Path, what: str = "--out") -> Path:
    """`path` can be written as a file: IsADirectoryError when it is a folder,
    NotADirectoryError when a parent is a file."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{what} {path}: is a folder, expected a file name")
    _check_parents(path, what)
    return path


def check_results_absent(out: str | Path, names: tuple[str, ...], force: bool, command: str) -> Path:
    """`out` is a folder (or will be) that holds none of `command`'s result files `names`, unless
    `force`: ValueError naming the files otherwise. Called before any work, so a refusal wastes
    nothing and earlier results are never overwritten silently."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: --out exists and is not a folder")
    existing = [name for name in names if (out / name).exists()]
    if existing and not force:
        raise ValueError(f"{out}: already holds {command} results ({', '.join(existing)}); use --force to overwrite")
    return out
