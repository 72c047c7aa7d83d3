"""segmin: train, export and validate crop-segmentation navigation (SegMin / SegMinD).

Subpackages follow the data flow: `common` (ground) -> `data` -> `models` -> `train` -> `export`
-> `nav_eval` -> `app` (command line, pipeline, benches).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("segmin")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
