"""Reads an installed launch file as `ros2 launch` would; run by test_ros2_package.py in the ROS environment.

Usage (the colcon install space sourced, so that ament_index_python finds the package):

    ROSENV/bin/python tests/ros2_launch_reader.py LAUNCH_FILE OUT.json [NAME:=VALUE ...]

The launch system (`launch`, `launch_ros`) has no wheel in the package registry, so this script
puts stand-ins for the few names a launch file of one node uses into `sys.modules` before
loading the file; ament_index_python is the real one. The stand-ins keep launch_ros's keyword
names (an unknown keyword is a TypeError, as in launch_ros), resolve each `LaunchConfiguration`
from NAME:=VALUE or the argument's default (a missing one is an error, as in launch), find the
executable where launch_ros does (`<prefix of the package>/lib/<package>/<executable>`) and
lay the command out as launch_ros does: the executable, its arguments, then `--ros-args` with
one `-r FROM:=TO` per remapping.

Writes JSON: the declared arguments (name, default, description) and each node (package,
executable, arguments, remappings, command), substitutions resolved.
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys
import types
from pathlib import Path

from ament_index_python.packages import get_package_prefix


class LaunchConfiguration:
    def __init__(self, variable_name: str) -> None:
        self.variable_name = variable_name


class DeclareLaunchArgument:
    def __init__(self, name: str, *, default_value: str | None = None, description: str = "") -> None:
        self.name, self.default_value, self.description = name, default_value, description


class LaunchDescription:
    def __init__(self, initial_entities: list | None = None) -> None:
        self.entities = list(initial_entities or [])


# launch_ros.actions.Node's own keywords, and those of launch's ExecuteProcess it passes on.
NODE_KEYWORDS = {"package", "executable", "name", "namespace", "exec_name", "parameters", "remappings"}
NODE_KEYWORDS |= {"ros_arguments", "arguments", "output", "emulate_tty", "respawn", "respawn_delay", "additional_env"}


class Node:
    def __init__(self, **keywords: object) -> None:
        unknown = set(keywords) - NODE_KEYWORDS
        if unknown:
            raise TypeError(f"Node() got unexpected keyword arguments {sorted(unknown)}")
        if "executable" not in keywords:
            raise TypeError("Node() missing required keyword argument: 'executable'")
        self.keywords = keywords


def install_stand_ins() -> None:
    """`launch`, `launch.actions`, `launch.substitutions` and `launch_ros.actions` with the stand-ins."""
    modules = {
        "launch": {"LaunchDescription": LaunchDescription},
        "launch.actions": {"DeclareLaunchArgument": DeclareLaunchArgument},
        "launch.substitutions": {"LaunchConfiguration": LaunchConfiguration},
        "launch_ros": {},
        "launch_ros.actions": {"Node": Node},
    }
    for name, members in modules.items():
        module = types.ModuleType(name)
        module.__dict__.update(members)
        sys.modules[name] = module


def load_description(path: Path) -> LaunchDescription:
    """The launch file's `generate_launch_description()`, loaded as a module as `ros2 launch` loads it."""
    spec = importlib.util.spec_from_file_location(path.name.replace(".", "_"), path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def main() -> int:
    path, out = Path(sys.argv[1]), Path(sys.argv[2])
    given = dict(item.split(":=", 1) for item in sys.argv[3:])
    install_stand_ins()
    description = load_description(path)
    declared = [e for e in description.entities if isinstance(e, DeclareLaunchArgument)]
    values = {a.name: a.default_value for a in declared if a.default_value is not None} | given

    def resolve(value: object) -> str:
        if isinstance(value, LaunchConfiguration):
            if value.variable_name not in values:
                raise KeyError(f"launch configuration {value.variable_name!r} is not set")
            return values[value.variable_name]
        assert isinstance(value, str), value
        return value

    nodes = []
    for node in (e for e in description.entities if isinstance(e, Node)):
        keywords = node.keywords
        package, executable = str(keywords["package"]), str(keywords["executable"])
        arguments = [resolve(a) for a in keywords.get("arguments") or []]
        remappings = [[resolve(a), resolve(b)] for a, b in keywords.get("remappings") or []]
        command = [os.path.join(get_package_prefix(package), "lib", package, executable), *arguments]
        if remappings:
            command += ["--ros-args", *(part for a, b in remappings for part in ("-r", f"{a}:={b}"))]
        nodes.append(
            {
                "package": package,
                "executable": executable,
                "arguments": arguments,
                "remappings": remappings,
                "command": command,
            }
        )
    arguments = [{"name": a.name, "default": a.default_value, "description": a.description} for a in declared]
    out.write_text(json.dumps({"arguments": arguments, "nodes": nodes}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
