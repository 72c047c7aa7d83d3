"""Check where an output will go before any work is done, and make folders that name what is in the way.

`--out somefile/x` used to fail late (after rendering, training or a whole evaluation) with a
bare NotADirectoryError deep in a write, or not at all until the first checkpoint. The checks
run first and name the path and the offending file; they create nothing. `make_dirs` is the
`mkdir -p` for outputs: where a file stands in the way it says so ("A is a file, not a folder")
instead of the OS's bare "File exists" / "Not a directory" (every atomic write goes through it).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _named(path: Path, what: str) -> str:
    return f"{what} {path}" if what else str(path)


def _check_parents(path: Path, what: str) -> None:
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise NotADirectoryError(f"{_named(path, what)}: {parent} is a file, not a folder")
            return


def check_output_dir(path: str | Path, what: str = "--out") -> Path:
    """`path` can be (or already is) a folder: FileExistsError when it is a file,
    NotADirectoryError when a parent is a file (`what` names the argument; "" for none)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{_named(path, what)} is a file, not a folder")
    _check_parents(path, what)
    return path


def make_dirs(path: str | Path, what: str = "") -> Path:
    """`path.mkdir(parents=True, exist_ok=True)`; a file in the way is named (`check_output_dir`).

    The check runs only when mkdir fails, so the common case costs nothing more than the mkdir.
    """
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        check_output_dir(path, what)
        raise  # replaced by a file between the mkdir and the check: the OS's own error
    return path


def check_writable(path: str | Path, what: str = "--out") -> Path:
    """`path` is a folder a file can be written into, made when missing; ValueError naming it
    otherwise (read-only, or a file in the way). A probe file is written and removed: permission
    bits alone do not tell (root, read-only mounts, ACLs)."""
    path = check_output_dir(path, what)
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".segmin_probe_", dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ValueError(f"{_named(path, what)}: not writable ({exc.strerror or exc})") from exc
    return path


def check_output_file(path: str | Path, what: str = "--out") -> Path:
    """`path` can be written as a file: IsADirectoryError when it is a folder,
    NotADirectoryError when a parent is a file."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{_named(path, what)} is a folder, expected a file name")
    _check_parents(path, what)
    return path


def check_results_absent(out: str | Path, names: tuple[str, ...], force: bool, command: str) -> Path:
    """`out` is a folder (or will be) that holds none of `command`'s result files `names`, unless
    `force`: ValueError naming the files otherwise, an OSError from `check_output_dir` when a file
    is in the way. Called before any work, so a refusal wastes
    nothing and earlier results are never overwritten silently."""
    out = check_output_dir(out, "--out")
    existing = [name for name in names if (out / name).exists()]
    if existing and not force:
        raise ValueError(f"{out}: already holds {command} results ({', '.join(existing)}); use --force to overwrite")
    return out
