"""An OpenCV window for the Gymnasium env's `render_mode="human"`.

OpenCV is already a dependency of the bare install, so a window needs no extra package where it
has a GUI; but segmin installs `opencv-python-headless`, which has none, and a server has no
display. Both are told up front in one line (`human_view_unavailable`), when the env is made,
instead of as OpenCV's own error at the first frame.
"""

from __future__ import annotations

import os
import re
import sys

import numpy as np


def opencv_has_gui() -> bool:
    """Whether this OpenCV was built with a GUI backend (its build information's `GUI:` line;
    the headless wheels say NONE)."""
    import cv2

    found = re.search(r"^\s*GUI:\s*(\S+)", cv2.getBuildInformation(), re.MULTILINE)
    return found is not None and found.group(1).upper() != "NONE"


def human_view_unavailable() -> str | None:
    """Why a window cannot open here, or None when it can: on Linux and the other X11/Wayland
    systems a display must be named (DISPLAY or WAYLAND_DISPLAY), and OpenCV needs a GUI."""
    on_x11 = sys.platform not in ("win32", "darwin")
    if on_x11 and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (neither DISPLAY nor WAYLAND_DISPLAY is set)"
    if not opencv_has_gui():
        return "this OpenCV has no GUI (opencv-python-headless); a window needs opencv-python in its place"
    return None


class FrameWindow:
    """One named OpenCV window that shows RGB frames as they come; `close()` removes it."""

    def __init__(self, title: str) -> None:
        self.title = title
        self._open = False

    def show(self, rgb: np.ndarray) -> None:
        """Draw the frame and let OpenCV process its window events (1 ms: it never blocks)."""
        import cv2

        cv2.imshow(self.title, cv2.cvtColor(np.asarray(rgb, dtype=np.uint8), cv2.COLOR_RGB2BGR))
        cv2.waitKey(1)
        self._open = True

    def close(self) -> None:
        if self._open:
            import cv2

            cv2.destroyWindow(self.title)
            self._open = False
