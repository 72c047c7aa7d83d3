"""segmin's layers and their one-way data flow, checked on the source.

common -> data -> models -> train -> export -> robot runtime -> ROS topic names -> replay and the live view /
ROS 2 node / demo / photo scoring ->
simulator -> closed-loop evaluation -> sweeps -> benches -> app -> the repository's benchmarks/ (outside
the wheel: segmin never imports it): a module may import its own layer
and the layers before it, never one after it, and no set of modules may import one another in a
cycle. Imports inside functions count: a lazy import is still a dependency. The robot runtime is
what the bare install ships, so it may import only the bare install's dependencies.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Installed package -> folder in the repository (the package-dir mapping of pyproject.toml).
PACKAGE_DIRS: dict[str, str] = {
    "segmin": "segmin",
    "segmin.data": "data",
    "segmin.models": "models",
    "segmin.train": "train",
    "segmin.export": "export",
    "segmin.nav_eval": "nav_eval",
    # The developers' benchmarks: outside the wheel, downstream of everything it ships.
    "benchmarks": "benchmarks",
}
# The data flow, first to last. `segmin` alone (its __init__) and `segmin.common` are the ground.
# A tuple is one layer of several packages (they may import one another, without a cycle).
LAYERS: tuple[str | tuple[str, ...], ...] = (
    "segmin.common",
    "segmin.data",
    "segmin.models",
    "segmin.train",
    "segmin.export",
    "segmin.nav_eval.runtime",
    # The ROS 2 topic and frame names: plain strings, importing nothing, read by replay, the live
    # view, the node and the simulator's bags (matched before the node's layer below).
    "segmin.nav_eval.ros2.topics",
    # The live view streams replay's steps (and the node's, nav-eval's) and replay's CLI starts it.
    ("segmin.nav_eval.replay", "segmin.nav_eval.live"),
    "segmin.nav_eval.ros2",
    "segmin.nav_eval.demo",
    "segmin.nav_eval.seg_eval",
    "segmin.nav_eval.sim",
    "segmin.nav_eval.evaluation",
    "segmin.nav_eval.sweeps",
    "segmin.nav_eval.bench",
    "segmin.app",
    "benchmarks",
)
OLD_TOP_LEVELS = {"data", "models", "train", "export", "nav_eval"}


def module_files(root: Path, package_dirs: dict[str, str]) -> dict[str, Path]:
    """Every module of the project, by its installed dotted name."""
    modules: dict[str, Path] = {}
    for package, folder in package_dirs.items():
        for path in sorted((root / folder).rglob("*.py")):
            parts = list(path.relative_to(root / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join([package, *parts])
            # segmin/ holds only its own modules; the mapped folders are not below it.
            modules.setdefault(name, path)
    return modules


def imported_names(path: Path, module: str) -> set[str]:
    """Every dotted name a module imports, anywhere in it (relative imports resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return names_of(ast.walk(tree), module, is_package=path.name == "__init__.py")


def names_of(nodes: Iterable[ast.AST], module: str, *, is_package: bool) -> set[str]:
    """The dotted names that these import statements import (other nodes are passed over)."""
    names: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base if is_package else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            names.add(prefix)
            names.update(f"{prefix}.{alias.name}" for alias in node.names)
    return names


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports (a `from pkg import name` counts pkg and pkg.name)."""
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        graph[module] = {name for name in imported_names(path, module) if name in modules and name != module}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def layer_of(module: str) -> int:
    """Position in the data flow; the bare `segmin` package is the ground like `segmin.common`."""
    for position, layer in enumerate(LAYERS):
        for package in (layer,) if isinstance(layer, str) else layer:
            if module == package or module.startswith(package + "."):
                return position
    # segmin.envs registers the Gymnasium envs by their import path (a string): it imports no module
    # of the project, and the simulator's env module imports it to register on import too.
    if module in ("segmin", "segmin.configs", "segmin.nav_eval", "segmin.envs"):
        return 0
    raise AssertionError(f"{module}: not in any layer; add it to LAYERS")


def against_the_flow(graph: dict[str, set[str]]) -> dict[str, list[str]]:
    return {
        module: sorted(target for target in targets if layer_of(target) > layer_of(module))
        for module, targets in sorted(graph.items())
        if any(layer_of(target) > layer_of(module) for target in targets)
    }


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(module_files(ROOT, PACKAGE_DIRS))


def test_no_module_imports_one_downstream_of_it(graph: dict[str, set[str]]) -> None:
    assert against_the_flow(graph) == {}


def test_no_import_cycles(graph: dict[str, set[str]]) -> None:
    assert cycles(graph) == []


def test_nothing_imports_the_old_top_level_names() -> None:
    offenders = {}
    for path in sorted(ROOT.rglob("*.py")):
        relative = path.relative_to(ROOT).parts  # hidden folders (.venv, .ros-venv) hold installed packages
        if any(part.startswith(".") for part in relative) or "build" in relative:
            continue
        tops = {name.split(".")[0] for name in imported_names(path, "x")} & OLD_TOP_LEVELS
        if tops:
            offenders[str(path.relative_to(ROOT))] = sorted(tops)
    assert offenders == {}


def test_every_module_lies_in_a_layer(graph: dict[str, set[str]]) -> None:
    for module in graph:
        layer_of(module)  # raises for a module outside the layers


def _tree(tmp_path: Path, files: dict[str, str]) -> dict[str, set[str]]:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return import_graph(module_files(tmp_path, {"segmin.nav_eval": "nav_eval", "segmin.train": "train"}))


def test_the_checks_fail_on_a_cycle_through_a_function_import(tmp_path: Path) -> None:
    graph = _tree(
        tmp_path,
        {
            "nav_eval/__init__.py": "",
            "nav_eval/evaluate.py": "from segmin.nav_eval.plots import figure\n",
            "nav_eval/plots.py": "def figure():\n    from segmin.nav_eval import evaluate\n",
            "nav_eval/sim.py": "from . import plots\n",
        },
    )
    assert cycles(graph) == [["segmin.nav_eval.evaluate", "segmin.nav_eval.plots"]]
    assert graph["segmin.nav_eval.sim"] == {"segmin.nav_eval", "segmin.nav_eval.plots"}  # `from . import` resolved


def test_the_checks_fail_on_an_import_against_the_flow(tmp_path: Path) -> None:
    graph = _tree(
        tmp_path,
        {
            "train/__init__.py": "",
            "train/run.py": "def f():\n    import segmin.nav_eval.runtime.navigator\n",
            "nav_eval/__init__.py": "",
            "nav_eval/runtime/__init__.py": "",
            "nav_eval/runtime/navigator.py": "import segmin.train.run\n",
        },
    )
    assert against_the_flow(graph) == {"segmin.train.run": ["segmin.nav_eval.runtime.navigator"]}


# The bare install (`pip install segmin`, the robot) has these besides the standard library.
BARE_DEPENDENCIES = {"numpy", "cv2", "onnxruntime", "yaml"}
# Sub-packages a robot runs; their module-level imports, followed through segmin, stay bare.
BARE_PACKAGES = ("segmin.nav_eval.runtime", "segmin.nav_eval.replay", "segmin.nav_eval.ros2", "segmin.nav_eval.demo")
# Modules inside them that load more, only when it is there: replay's figure (the [sim] extra; replay
# skips its plot and says so on the bare install) and the ROS 2 node (the robot's own rclpy).
ROS2_MODULES = {"rclpy", "rcl_interfaces", "sensor_msgs", "geometry_msgs", "std_msgs", "std_srvs", "diagnostic_msgs"}
OPTIONAL_MODULES = {"segmin.nav_eval.replay.plot": {"matplotlib"}, "segmin.nav_eval.ros2.node": ROS2_MODULES}


def module_level_imports(path: Path, module: str) -> set[str]:
    """Dotted names imported when the module is loaded: top-level statements (and try / if blocks
    at the top level), not imports inside functions and not `if TYPE_CHECKING:` blocks."""
    tree = ast.parse(path.read_text(), filename=str(path))
    body: list[ast.stmt] = []
    pending = list(tree.body)
    while pending:
        node = pending.pop()
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            continue
        if isinstance(node, (ast.If, ast.Try)):
            pending.extend(node.body + node.orelse + getattr(node, "finalbody", []))
            for handler in getattr(node, "handlers", []):
                pending.extend(handler.body)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            body.append(node)
    return names_of(body, module, is_package=path.name == "__init__.py")


def third_party_at_load(start: str, modules: dict[str, Path]) -> dict[str, set[str]]:
    """Third-party top-level packages loaded by importing `start`, with the modules that import them."""
    seen: set[str] = set()
    found: dict[str, set[str]] = {}
    pending = [start]
    while pending:
        module = pending.pop()
        if module in seen:
            continue
        seen.add(module)
        parts = module.split(".")
        parents = [".".join(parts[:i]) for i in range(1, len(parts))]
        pending.extend(parent for parent in parents if parent in modules)
        for name in module_level_imports(modules[module], module):
            if name in modules:
                pending.append(name)
            top = name.split(".")[0]
            if top and top != "segmin" and top not in sys.stdlib_module_names and top != "__future__":
                found.setdefault(top, set()).add(module)
    return found


def test_the_robot_side_loads_only_the_bare_install() -> None:
    modules = module_files(ROOT, PACKAGE_DIRS)
    offenders = {}
    for module in sorted(modules):
        if module.startswith(BARE_PACKAGES):
            allowed = BARE_DEPENDENCIES | OPTIONAL_MODULES.get(module, set())
            found = third_party_at_load(module, modules)
            extra = {top: sorted(by) for top, by in found.items() if top not in allowed}
            if extra:
                offenders[module] = extra
    assert offenders == {}


def test_the_runtime_never_imports_beyond_the_bare_install_even_lazily() -> None:
    modules = module_files(ROOT, PACKAGE_DIRS)
    offenders = {}
    for module, path in sorted(modules.items()):
        if module.startswith("segmin.nav_eval.runtime"):
            tops = {name.split(".")[0] for name in imported_names(path, module)}
            extra = sorted(
                t
                for t in tops
                if t not in BARE_DEPENDENCIES
                and t != "segmin"
                and t not in sys.stdlib_module_names
                and t != "__future__"
            )
            if extra:
                offenders[module] = extra
    assert offenders == {}


def test_the_bare_install_check_sees_a_heavy_import_through_a_helper(tmp_path: Path) -> None:
    for name, text in {
        "nav_eval/__init__.py": "",
        "nav_eval/runtime/__init__.py": "",
        "nav_eval/runtime/navigator.py": "import numpy\nfrom segmin.nav_eval.runtime import helper\n",
        "nav_eval/runtime/helper.py": "try:\n    import torch\nexcept ImportError:\n    pass\n",
    }.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    modules = module_files(tmp_path, {"segmin.nav_eval": "nav_eval"})
    found = third_party_at_load("segmin.nav_eval.runtime.navigator", modules)
    assert found == {"numpy": {"segmin.nav_eval.runtime.navigator"}, "torch": {"segmin.nav_eval.runtime.helper"}}
