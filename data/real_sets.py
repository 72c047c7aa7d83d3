"""The real labelled photos shipped with segmin (`data/real/<set>/`), and the guard that keeps them a test set.

They are package data of `segmin.data`, found with `importlib.resources`, so `segmin eval-seg`
and the pipeline's real-eval stage work from any install. A model tuned or trained on its own
test photos would report a figure that means nothing, so every place that chooses training or
validation data (training configs, pipeline profiles) asks `check_not_real_data` first, and the
frames training selects are checked once more (`check_frames_not_real`): a config field assigned
after the config was built escapes the first check, never the second.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from importlib.resources import files
from pathlib import Path

from segmin.common.config import ConfigError
from segmin.data.frames import Frame

REAL_SETS: tuple[str, ...] = ("vineyard_rows",)
DEFAULT_REAL_SET = "vineyard_rows"


def real_data_root() -> Path:
    """The folder holding every shipped real set (a real folder: segmin installs unzipped)."""
    return Path(str(files("segmin.data") / "real"))


def shipped_real_data(name: str = DEFAULT_REAL_SET) -> Path:
    """One shipped real set (flat images/ + masks/); errors name what is missing."""
    if name not in REAL_SETS:
        raise ValueError(f"unknown shipped real set {name!r} (shipped: {', '.join(REAL_SETS)})")
    path = real_data_root() / name
    if not (path / "images").is_dir() or not (path / "masks").is_dir():
        raise FileNotFoundError(f"{path}: shipped real photos missing from this install (reinstall segmin)")
    return path


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.resolve().relative_to(folder.resolve())
        return True
    except (ValueError, OSError):
        return False


def points_to_real_data(value: object, extra: Iterable[str | Path] = (), *, is_path: bool = True) -> bool:
    """True when `value` (a path or name, or a list of them) is real test data or would read it.

    Real data is the shipped `data/real` folder (however it is spelled: a relative `data/real/...`
    counts whatever the working folder), a shipped set's name (as a domain or world name), and
    every folder in `extra` (e.g. the pipeline's `real_eval.data`). A path also counts when it
    holds real data below it, since the loader scans a root recursively. `is_path=False` checks a
    name (domain, world) without resolving it as a folder.
    """
    if value is None:
        return False
    if isinstance(value, (list, tuple, set)):
        return any(points_to_real_data(v, extra, is_path=is_path) for v in value)
    text = str(value).strip()
    if not text:
        return False
    parts = Path(text).parts
    if text in REAL_SETS or any(parts[i : i + 2] == ("data", "real") for i in range(len(parts) - 1)):
        return True
    if not is_path:
        return False
    path = Path(text)
    folders = [real_data_root(), *(Path(e) for e in extra)]
    return any(_inside(path, folder) or _inside(folder, path) for folder in folders)


def check_not_real_data(
    source: str,
    paths: Mapping[str, object],
    names: Mapping[str, object] | None = None,
    extra: Iterable[str | Path] = (),
) -> None:
    """ConfigError naming the first field (path or name) that points at real test photos."""
    extra = list(extra)
    checks = [(k, v, True) for k, v in paths.items()] + [(k, v, False) for k, v in (names or {}).items()]
    for name, value, is_path in checks:
        if points_to_real_data(value, extra, is_path=is_path):
            raise ConfigError(
                f"{source}: {name}={value} points at the real test photos (data/real or real_eval.data); "
                "they are a test set only, never training or validation data"
            )


def check_frames_not_real(frames_by_use: Mapping[str, Sequence[Frame]]) -> None:
    """ConfigError naming the first frame (image or mask) that lies in the shipped real sets, and
    what it was selected for ({"training": [...], "validation": [...]}).

    This checks what will actually be read, however it was chosen: a config field set after
    `DataConfig` checked its fields, a split file, a folder holding the photos. Each folder is
    resolved once, so a large dataset costs one lookup per folder, not per file.
    """
    real = real_data_root()
    inside: dict[Path, bool] = {}
    for use, frames in frames_by_use.items():
        for frame in frames:
            for path in (frame.image_path, frame.mask_path):
                if path.parent not in inside:
                    inside[path.parent] = _inside(path.parent, real)
                if inside[path.parent]:
                    raise ConfigError(
                        f"{use} frame {path} is one of the real test photos (data/real); they are a test set "
                        "only, never training or validation data"
                    )
