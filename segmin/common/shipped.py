"""The configs shipped inside the package (`segmin.configs`), found by name.

Configs are package data read with `importlib.resources`, so a wheel installed anywhere has the
named worlds, training recipes, nav settings, pipeline profiles and sweeps. Everywhere a shipped name is
accepted, a path to the user's own YAML file is accepted too: a value with a slash or a `.yaml`
suffix is a path, a bare word is a shipped name.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from segmin.common.atomic import write_bytes
from segmin.common.config import ConfigError

# Kind of config -> what it holds (for `segmin configs list`).
KINDS: dict[str, str] = {
    "worlds": "world specs for `segmin synth` and `segmin nav-eval`",
    "train": "training recipes for `segmin train`",
    "nav": "closed-loop settings for `segmin nav-eval`",
    "pipeline": "profiles for `segmin pipeline`",
    "sweeps": "robustness sweeps and families of worlds for `segmin robustness`",
    "ros2": "parameter files for `segmin ros2 follow`",
}
# What one config of each kind is called in error messages.
_SINGULAR = {
    "worlds": "world",
    "train": "training config",
    "nav": "nav config",
    "pipeline": "pipeline profile",
    "sweeps": "sweep",
    "ros2": "ROS 2 parameter file",
}


# Kinds kept outside configs/ in the repository: the ROS 2 parameter files are the ROS 2 package's
# (ros/segmin_ros/config, which colcon installs for the launch file), one copy that the wheel also
# installs as segmin/configs/ros2 (pyproject's package-dir). An editable install has no such
# folder: it reads them in the checkout, beside configs/.
_CHECKOUT_FOLDERS = {"ros2": Path("ros", "segmin_ros", "config")}


def shipped_dir(kind: str) -> Path:
    """The folder of one kind of shipped config (a real folder: segmin installs unzipped)."""
    if kind not in KINDS:
        raise ConfigError(f"unknown config kind {kind!r} (kinds: {', '.join(KINDS)})")
    configs = Path(str(files("segmin.configs")))
    if not (configs / kind).is_dir() and kind in _CHECKOUT_FOLDERS:
        return configs.parent / _CHECKOUT_FOLDERS[kind]
    return configs / kind


def shipped_names(kind: str) -> list[str]:
    """The names of the shipped configs of one kind, sorted."""
    return sorted(path.stem for path in shipped_dir(kind).glob("*.yaml"))


def is_config_path(name_or_path: str | Path) -> bool:
    """True when the value names a file (slash or YAML suffix) rather than a shipped config."""
    text = str(name_or_path)
    return "/" in text or "\\" in text or text.endswith((".yaml", ".yml"))


def resolve_config(kind: str, name_or_path: str | Path) -> Path:
    """A shipped name to its file, or the user's path as given; unknown names list the shipped ones."""
    if is_config_path(name_or_path):
        path = Path(name_or_path)
        if not path.is_file():
            raise ConfigError(f"{path}: config file not found")
        return path
    path = shipped_dir(kind) / f"{name_or_path}.yaml"
    if not path.is_file():
        raise ConfigError(
            f"{_SINGULAR[kind]} {str(name_or_path)!r} not found (shipped: {', '.join(shipped_names(kind))}; "
            "or give a path to a YAML file)"
        )
    return path


def find_shipped(name: str) -> tuple[str, Path]:
    """Find a shipped config by bare name across kinds (`kind/name` picks one kind); errors list them all."""
    kind, _, stem = name.rpartition("/")
    kinds = [kind] if kind else list(KINDS)
    matches = [(k, shipped_dir(k) / f"{stem}.yaml") for k in kinds if (shipped_dir(k) / f"{stem}.yaml").is_file()]
    if not matches:
        raise ConfigError(f"no shipped config named {name!r}; `segmin configs list` shows them")
    if len(matches) > 1:
        options = ", ".join(f"{k}/{stem}" for k, _ in matches)
        raise ConfigError(f"{name!r} is shipped as more than one kind of config: name one of {options}")
    return matches[0]


def copy_shipped(name: str, out_dir: str | Path, *, force: bool = False) -> Path:
    """Write a shipped config to `out_dir/<name>.yaml` for editing; never overwrites without `force`."""
    _, source = find_shipped(name)
    out_dir = Path(out_dir)
    target = out_dir / source.name
    if target.exists() and not force:
        raise FileExistsError(f"{target}: already exists (use --force to overwrite)")
    write_bytes(target, source.read_bytes())
    return target
