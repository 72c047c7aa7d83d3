"""YAML configs into validated dataclasses.

Every number a user may change lives in a YAML file under `configs/`. Loading is strict on
purpose: an unknown key is almost always a typo, and a typo silently ignored means a run with
the wrong settings. Overrides from the command line use dotted `key=value` pairs whose values
are parsed as YAML, so `train.epochs=5` and `augment.flip=false` have their natural types.

Both are read with `ConfigLoader`: PyYAML follows YAML 1.1, where a float needs a dot, so the
`1e-3` and `5e-1` everyone writes for a learning rate would be text; the loader reads them (and
`1E+3`, `-2.5e-4`) as floats, as YAML 1.2 and JSON do. Integers stay integers.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import yaml

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")  # configs are dataclasses


class ConfigError(ValueError):
    """A config file or override is invalid; the message names the file and the key."""


class ConfigLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that also reads the exponent floats YAML 1.1 misses (`1e-3`, `5e-1`, `1.5e3`).

    YAML 1.1's float pattern needs a dot and a signed exponent, so PyYAML reads `1e-3` as the string '1e-3' and a
    config's float field then refuses it. The extra pattern below is tried after the usual ones
    (which still resolve ints, dotted floats, .inf and .nan), so only the dotless exponent form
    changes; the SafeLoader itself is left alone for other users of PyYAML.
    """


ConfigLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def parse_yaml(text: str) -> Any:
    """`text` parsed as a config value or file (`ConfigLoader`: exponent floats are floats)."""
    return yaml.load(text, Loader=ConfigLoader)


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping, with errors that name the file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        content = parse_yaml(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    except UnicodeDecodeError as exc:  # a binary file: the bare codec error names no file
        raise ConfigError(f"{path}: not a text (UTF-8) YAML file ({exc.reason} at byte {exc.start})") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config ({exc.strerror or exc})") from exc
    if content is None:
        return {}
    if not isinstance(content, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(content).__name__}")
    return content


def apply_overrides(raw: dict[str, Any], overrides: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """Return a copy of `raw` with dotted `key=value` overrides applied (values parsed as YAML)."""
    result = _deep_copy(raw)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"override {item!r}: expected key=value")
        key, _, text = item.partition("=")
        parts = [p for p in key.strip().split(".") if p]
        if not parts:
            raise ConfigError(f"override {item!r}: empty key")
        try:
            value = parse_yaml(text)
        except yaml.YAMLError as exc:
            raise ConfigError(f"override {item!r}: value is not valid YAML: {exc}") from exc
        node = result
        for part in parts[:-1]:
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ConfigError(f"override {item!r}: {part!r} is not a section")
            node = child
        node[parts[-1]] = value
    return result


def from_dict(cls: type[T], raw: dict[str, Any], *, where: str = "config") -> T:
    """Build dataclass `cls` from a mapping; unknown keys and wrong types raise ConfigError.

    Nested dataclass fields are built recursively, so a whole config tree is checked at once.
    Validation beyond types belongs in each dataclass's `__post_init__` (raise ValueError there;
    it is re-raised here with the location).
    """
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(raw).__name__}")
    check_removed_keys(cls, raw, where)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(fields)}")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for name, value in raw.items():
        kwargs[name] = _coerce(hints[name], value, f"{where}.{name}")
    missing = [
        n
        for n, f in fields.items()
        if n not in kwargs and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ConfigError(f"{where}: missing required key(s) {missing}")
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def check_removed_keys(cls: type, raw: dict[str, Any], where: str) -> None:
    """ConfigError naming the first key of `raw` that `cls` once had and dropped.

    A dataclass lists such keys in a `REMOVED_KEYS` class attribute (key -> why it went). An old
    config file that still sets one then gets one line that says the key was removed and why,
    instead of "unknown key" and a list of the allowed ones that no longer holds it."""
    removed: dict[str, str] = getattr(cls, "REMOVED_KEYS", {})
    for key in sorted(set(raw) & set(removed)):
        raise ConfigError(f"{where}.{key} was removed ({removed[key]}): delete it from the config")


def load_config(cls: type[T], path: str | Path | None, overrides: list[str] | tuple[str, ...] = ()) -> T:
    """Load `cls` from a YAML file (or defaults when `path` is None) plus dotted overrides."""
    raw = read_yaml(path) if path is not None else {}
    raw = apply_overrides(raw, overrides)
    return from_dict(cls, raw, where=str(path) if path is not None else "config")


def to_dict(obj: Any) -> Any:
    """Plain-data view of a config (dataclasses, tuples and paths), suitable for YAML or JSON."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): to_dict(v) for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _deep_copy(raw: dict[str, Any]) -> dict[str, Any]:
    return {k: _deep_copy(v) if isinstance(v, dict) else v for k, v in raw.items()}


def _coerce(hint: Any, value: Any, where: str) -> Any:
    """Check `value` against a type hint, converting only where the conversion is lossless.

    One branch per kind of hint (Optional, Literal, tuple, list, dict, dataclass, scalars) kept in
    one place on purpose: the rules of what a config accepts read as one table."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(arg, value, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if len(errors) == 1 else f"{where}: {value!r} matches none of {hint}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}: {value!r} is not one of {list(args)}")
        return value
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return from_dict(hint, value if value is not None else {}, where=where)
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
            return tuple(_coerce(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
        item = args[0] if args else Any
        items = [_coerce(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        key_t, val_t = args if args else (Any, Any)
        return {_coerce(key_t, k, where): _coerce(val_t, v, f"{where}.{k}") for k, v in value.items()}
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        # YAML reads .nan and .inf as floats; every comparison with NaN is false, so it would slip
        # through each `__post_init__` range check and fail far away (or never). Checked once here.
        if not math.isfinite(value):
            raise ConfigError(f"{where}: {value!r} is not a finite number")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if hint is Path:
        if not isinstance(value, (str, Path)):
            raise ConfigError(f"{where}: expected a path, got {value!r}")
        return Path(value)
    return value
