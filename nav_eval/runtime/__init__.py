"""The robot runtime: what a robot runs, and all that the bare `pip install segmin` needs.

camera frame -> segmenter (ONNX) -> mask -> navigator -> `RowFollower` timing -> (v, omega)

Only numpy, OpenCV and onnxruntime: never torch, pybullet or matplotlib (the architecture test
checks it). The main names are importable from here; each is defined in its own module.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from segmin.nav_eval.runtime.corridor import CorridorConfig, CorridorNavigator
    from segmin.nav_eval.runtime.follower import FollowerOutput, RowFollower, RuntimeConfig
    from segmin.nav_eval.runtime.navigator import Command, Navigator, NavigatorConfig, target_column
    from segmin.nav_eval.runtime.segmenter import OnnxSegmenter

# Name -> defining module; loaded on first use so that importing one piece does not load the rest
# (the segmenter pulls in onnxruntime, which a navigator-only user does not need).
_EXPORTS: dict[str, str] = {
    "Command": "navigator",
    "Navigator": "navigator",
    "NavigatorConfig": "navigator",
    "target_column": "navigator",
    "CorridorConfig": "corridor",
    "CorridorNavigator": "corridor",
    "RowFollower": "follower",
    "RuntimeConfig": "follower",
    "FollowerOutput": "follower",
    "OnnxSegmenter": "segmenter",
}
__all__ = [
    "Command",
    "CorridorConfig",
    "CorridorNavigator",
    "FollowerOutput",
    "Navigator",
    "NavigatorConfig",
    "OnnxSegmenter",
    "RowFollower",
    "RuntimeConfig",
    "target_column",
]


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
