"""The ROS 2 guide lists every rclpy and message name the node imports, with where Humble has it.

The node's tests run under a newer rclpy than Humble's (3.3): a name the node starts importing
is checked against Humble by hand and added to the guide's table, or this test fails.
"""

from __future__ import annotations

import re
from pathlib import Path

from test_architecture import ROOT, imported_names

# The ROS packages the node imports from: rclpy and the message and service packages.
ROS_PACKAGES = ("rclpy", "rcl_interfaces", "sensor_msgs", "geometry_msgs", "diagnostic_msgs", "std_msgs", "std_srvs")


def ros_names(folder: Path) -> set[str]:
    """The last part of every name the modules of `folder` import from a ROS package (`QoSProfile`,
    `SetBool`, `rclpy` itself), the modules they come from (`rclpy.qos`, `std_srvs.srv`) left out."""
    names: set[str] = set()
    for path in sorted(folder.glob("*.py")):
        for name in imported_names(path, "segmin.nav_eval.ros2.x"):
            parts = name.split(".")
            # `rclpy` itself, or a member of a module (`rclpy.qos.QoSProfile`); not a module (`rclpy.qos`).
            if parts[0] in ROS_PACKAGES and len(parts) != 2:
                names.add(parts[-1])
    return names


def humble_table(guide: Path) -> str:
    """The guide's section on ROS 2 Humble, up to the next heading."""
    text = guide.read_text()
    start = text.index("### ROS 2 Humble")
    end = text.find("\n#", start + 1)
    return text[start:end]


def test_every_ros_name_the_node_imports_is_in_the_guides_humble_table() -> None:
    names = ros_names(ROOT / "nav_eval" / "ros2")
    assert {"rclpy", "Node", "QoSProfile", "SetBool", "DiagnosticArray"} <= names  # the parse finds them
    table = humble_table(ROOT / "docs" / "guide" / "ros2.md")
    assert sorted(name for name in names if not re.search(rf"\b{name}\b", table)) == []


def test_a_name_missing_from_the_table_is_found(tmp_path: Path) -> None:
    (tmp_path / "node.py").write_text("from rclpy.event_handler import PublisherEventCallbacks\nimport rclpy\n")
    assert ros_names(tmp_path) == {"PublisherEventCallbacks", "rclpy"}
