"""The robot runtime: what a robot runs, and all that the bare `pip install segmin` needs.

camera frame -> segmenter (ONNX) -> mask -> navigator -> `RowFollower` timing -> (v, omega)

The interfaces between those pieces are `typing.Protocol`s in `protocols` (`Segmenter`,
`MaskNavigator` and the `NavigatorInputs` a navigator declares); the command, its limits and
the EMA that every navigator shares are in `control`; what configures them all, the one
`FollowerConfig` and `make_navigator`, in `follower_config`.

Only numpy, OpenCV and onnxruntime: never torch, pybullet or matplotlib (the architecture test
checks it); `LiteRtSegmenter` loads ai-edge-litert (the `litert` extra) when one is made. The main names are importable from here; each is defined in its own module.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .camera import CameraGeometry
    from .control import Command
    from .corridor import CorridorConfig, CorridorNavigator
    from .follower import FollowerOutput, RowFollower, RuntimeConfig
    from .follower_config import CameraConfig, FollowerConfig, load_follower_config, make_navigator
    from .navigator import Navigator, NavigatorConfig, target_column
    from .protocols import MaskNavigator, NavigatorInputs, Segmenter
    from .segmenter import LiteRtSegmenter, OnnxSegmenter
    from .sensor_faults import SensorChecks

# Name -> defining module; loaded on first use so that importing one piece does not load the rest
# (the segmenter pulls in onnxruntime, which a navigator-only user does not need).
_EXPORTS: dict[str, str] = {
    "CameraGeometry": "camera",
    "Command": "control",
    "MaskNavigator": "protocols",
    "NavigatorInputs": "protocols",
    "Segmenter": "protocols",
    "Navigator": "navigator",
    "NavigatorConfig": "navigator",
    "target_column": "navigator",
    "CorridorConfig": "corridor",
    "CorridorNavigator": "corridor",
    "RowFollower": "follower",
    "RuntimeConfig": "follower",
    "FollowerOutput": "follower",
    "CameraConfig": "follower_config",
    "FollowerConfig": "follower_config",
    "load_follower_config": "follower_config",
    "make_navigator": "follower_config",
    "OnnxSegmenter": "segmenter",
    "LiteRtSegmenter": "segmenter",
    "SensorChecks": "sensor_faults",
}
__all__ = [
    "CameraConfig",
    "CameraGeometry",
    "Command",
    "CorridorConfig",
    "CorridorNavigator",
    "FollowerConfig",
    "FollowerOutput",
    "LiteRtSegmenter",
    "MaskNavigator",
    "Navigator",
    "NavigatorConfig",
    "NavigatorInputs",
    "OnnxSegmenter",
    "RowFollower",
    "RuntimeConfig",
    "Segmenter",
    "SensorChecks",
    "load_follower_config",
    "make_navigator",
    "target_column",
]


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
