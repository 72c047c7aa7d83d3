"""Deprecation aliases for modules that moved: the old dotted path still imports, with a warning.

A meta-path finder answers only for the listed old names and hands back a proxy module whose
attributes are the new module's, so `from old.path import Name` yields the very same objects
(isinstance checks and pickling keep working: classes keep their new `__module__`).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings
from collections.abc import Mapping


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds `package.old` for each old name and loads a proxy of `package.new`."""

    def __init__(self, package: str, moves: Mapping[str, str]) -> None:
        self.package = package
        self.moves = {f"{package}.{old}": f"{package}.{new}" for old, new in moves.items()}

    def find_spec(
        self, fullname: str, path: object = None, target: object = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname not in self.moves:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        new_name = self.moves[spec.name]
        warnings.warn(
            f"{spec.name} moved to {new_name}; the old path will be removed in the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        target = importlib.import_module(new_name)
        proxy = types.ModuleType(spec.name, target.__doc__)
        proxy.__dict__["__getattr__"] = lambda name: getattr(target, name)
        return proxy

    def exec_module(self, module: types.ModuleType) -> None:
        """Nothing to run: the proxy forwards every attribute."""


def install_moved_modules(package: str, moves: Mapping[str, str]) -> None:
    """Register old -> new sub-module names of `package` (relative names), once per package."""
    if not any(isinstance(f, _MovedModules) and f.package == package for f in sys.meta_path):
        sys.meta_path.append(_MovedModules(package, moves))
