"""The data flow is one way: data -> train (uses models) -> export -> nav_eval. No package imports
one downstream of it; `segmin` (the command line and the pipeline) is the only place that joins them.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# For each package: the project packages it must never import.
FORBIDDEN = {
    "data": {"models", "train", "export", "nav_eval"},
    "models": {"data", "train", "export", "nav_eval"},
    "train": {"export", "nav_eval"},
    "export": {"train", "nav_eval"},
    "nav_eval": {"train"},
}


def imported_top_levels(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_no_package_imports_downstream(package: str) -> None:
    offenders = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        bad = imported_top_levels(path) & FORBIDDEN[package]
        if bad:
            offenders[str(path.relative_to(ROOT))] = sorted(bad)
    assert offenders == {}


def test_the_check_sees_imports_inside_functions(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from nav_eval.navigator import Navigator\n    import train.run\n")
    assert imported_top_levels(module) == {"nav_eval", "train"}
