"""The camera as a navigator sees it: pinhole intrinsics of the delivered frame and the mount on
the robot, and the back-projection of pixels with planar depth into the robot frame.

SegCorridor places its vegetation and trunk pixels with it; the runtime checks that frames match
the camera a navigator was built for (`NavigatorInputs.camera`). numpy only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .checks import check_positive


class MountedCamera(Protocol):
    """A camera model with intrinsics and a mount (`segmin.data.synth.camera.CameraModel`)."""

    mount_height: float
    tilt_deg: float
    mount_forward: float

    def intrinsics(self) -> dict: ...


@dataclass(frozen=True)
class CameraGeometry:
    """Pinhole intrinsics of the delivered frame and the camera mount on the robot."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    mount_height: float
    tilt_deg: float
    mount_forward: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"camera {name} must be an integer >= 1, got {value!r}")
        for name in ("fx", "fy", "mount_height"):
            check_positive(f"camera {name}", getattr(self, name))
        for name in ("cx", "cy", "mount_forward"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"camera {name} must be finite, got {getattr(self, name)!r}")
        if not -89.0 < self.tilt_deg < 89.0:
            raise ValueError(f"camera tilt_deg must be within (-89, 89) degrees, got {self.tilt_deg!r}")

    @property
    def frame_shape(self) -> tuple[int, int]:
        """(height, width) of the frames this camera delivers."""
        return self.height, self.width

    @classmethod
    def from_camera(cls, camera: MountedCamera) -> CameraGeometry:
        """From a `segmin.data.synth.camera.CameraModel` (its intrinsics and mount)."""
        k = camera.intrinsics()
        return cls(
            width=int(k["width"]),
            height=int(k["height"]),
            fx=float(k["fx"]),
            fy=float(k["fy"]),
            cx=float(k["cx"]),
            cy=float(k["cy"]),
            mount_height=float(camera.mount_height),
            tilt_deg=float(camera.tilt_deg),
            mount_forward=float(camera.mount_forward),
        )

    def robot_frame(
        self, rows: np.ndarray, cols: np.ndarray, depth_m: np.ndarray, attitude: tuple[float, float] | None = None
    ) -> tuple[np.ndarray, ...]:
        """(x forward, y left, h up) in metres of pixels (rows, cols) with planar depth `depth_m`.

        Without `attitude` the axes are the robot's (h along its up axis). With the IMU's
        (roll, pitch) (REP 103: positive roll lifts the left side, positive pitch lowers the
        nose) they are levelled, h along gravity: on rough ground the robot rolls by several
        degrees, and a crown 1 m above the camera then appears 1 m x roll to the side.
        """
        return self.points_on_rays(self.ray_coefficients(rows, cols), depth_m, attitude)

    def ray_coefficients(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per pixel, (a, b, c) with x = forward + z a, y = z b, h = height + z c for planar depth z.

        They depend on the pixel only, so a navigator computes them once per image size and a
        step costs three multiply-adds a point."""
        theta = math.radians(self.tilt_deg)
        s, c = math.sin(theta), math.cos(theta)
        lateral = (cols - self.cx) / self.fx
        vertical = (rows - self.cy) / self.fy
        return c + vertical * s, -lateral, s - vertical * c

    def points_on_rays(
        self, rays: Sequence[np.ndarray] | np.ndarray, depth_m: np.ndarray, attitude: tuple[float, float] | None = None
    ) -> tuple[np.ndarray, ...]:
        """`robot_frame` of the pixels whose `ray_coefficients` are `rays` (a, b, c: a tuple or
        the rows of a 3 x n array)."""
        a, b, c = rays
        x = self.mount_forward + depth_m * a
        y = depth_m * b
        h = self.mount_height + depth_m * c
        return (x, y, h) if attitude is None else self.level(x, y, h, attitude)

    @staticmethod
    def level(x: np.ndarray, y: np.ndarray, h: np.ndarray, attitude: tuple[float, float]) -> tuple[np.ndarray, ...]:
        """Robot-frame points rotated into the level frame (h along gravity) by the IMU's (roll, pitch)."""
        roll, pitch = attitude  # body-to-level rotation R_y(pitch) R_x(roll)
        sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
        return (cp * x + sp * sr * y + sp * cr * h, cr * y - sr * h, -sp * x + cp * sr * y + cp * cr * h)

    def column_of(self, x: float, y: float) -> float:
        """Image column of the robot-frame point (x, y) at camera height (for overlays)."""
        forward = (x - self.mount_forward) * math.cos(math.radians(self.tilt_deg))
        return self.cx - self.fx * y / max(forward, 1e-6)
