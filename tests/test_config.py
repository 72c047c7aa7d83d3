"""segmin.common.config: strict YAML configs with typed overrides; segmin.common.atomic: no partial files."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from segmin.common.atomic import atomic_path, write_json
from segmin.common.config import ConfigError, load_config, to_dict


@dataclass
class Inner:
    rate: float = 1.0
    names: list[str] = field(default_factory=list)


@dataclass
class Outer:
    title: str
    epochs: int = 3
    flag: bool = False
    inner: Inner = field(default_factory=Inner)

    def __post_init__(self) -> None:
        if self.epochs < 1:
            raise ValueError(f"epochs must be >= 1, got {self.epochs}")


def write(tmp_path, text: str):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    return path


def test_loads_nested_values_and_overrides(tmp_path) -> None:
    path = write(tmp_path, "title: a\nepochs: 5\ninner:\n  rate: 2\n  names: [x, y]\n")
    config = load_config(Outer, path, ["inner.rate=0.5", "flag=true", "epochs=7"])
    assert config == Outer(title="a", epochs=7, flag=True, inner=Inner(rate=0.5, names=["x", "y"]))
    assert isinstance(config.inner.rate, float)
    assert to_dict(config)["inner"] == {"rate": 0.5, "names": ["x", "y"]}


@pytest.mark.parametrize(
    ("text", "overrides", "message"),
    [
        ("title: a\nepoch: 5\n", [], r"unknown key\(s\) \['epoch'\]"),
        ("title: a\ninner:\n  rte: 1\n", [], r"inner: unknown key"),
        ("epochs: 2\n", [], r"missing required key\(s\) \['title'\]"),
        ("title: a\nepochs: two\n", [], "epochs: expected an integer"),
        ("title: a\n", ["flag=maybe"], "flag: expected true or false"),
        ("title: a\n", ["epochs=0"], "epochs must be >= 1"),
        ("title: a\n", ["nonsense"], "expected key=value"),
        ("- a\n- b\n", [], "expected a mapping"),
        ("title: [unclosed\n", [], "not valid YAML"),
    ],
)
def test_bad_configs_name_the_file_and_key(tmp_path, text, overrides, message) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as info:
        load_config(Outer, path, overrides)
    assert "c.yaml" in str(info.value) or "key=value" in str(info.value)


@pytest.mark.parametrize(
    ("text", "value"), [("1e-3", 1e-3), ("5e-1", 0.5), ("1E+3", 1e3), ("-2.5e-4", -2.5e-4), ("1.5e3", 1.5e3)]
)
def test_exponent_floats_are_numbers_in_files_and_overrides(tmp_path, text, value) -> None:
    """YAML 1.1 reads a float without a dot (or with an unsigned exponent) as text; configs must not."""
    from_file = load_config(Outer, write(tmp_path, f"title: a\ninner:\n  rate: {text}\n"))
    from_override = load_config(Outer, None, ["title=a", f"inner.rate={text}"])
    assert from_file.inner.rate == from_override.inner.rate == value
    config = load_config(Outer, None, ["title=1e", "epochs=12"])  # no exponent digits: text; ints stay ints
    assert config.title == "1e" and config.epochs == 12 and isinstance(config.epochs, int)

    with pytest.raises(ConfigError, match="nope.yaml: config file not found"):
        load_config(Outer, tmp_path / "nope.yaml")


def test_atomic_write_leaves_nothing_behind_on_error(tmp_path) -> None:
    target = tmp_path / "out.json"
    write_json(target, {"a": 1})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half a fi")
        raise RuntimeError("crash while writing")
    assert target.read_text().strip().startswith("{") and '"a": 1' in target.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_atomic_writes_get_the_usual_file_mode(tmp_path) -> None:
    import os

    umask = os.umask(0o022)
    try:
        reference = tmp_path / "plain.txt"
        reference.write_text("x")
        write_json(tmp_path / "atomic.json", {})
    finally:
        os.umask(umask)
    assert (tmp_path / "atomic.json").stat().st_mode & 0o777 == reference.stat().st_mode & 0o777
