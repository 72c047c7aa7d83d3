"""A D435i-like RGB-D camera: intrinsics, mount on the robot, and a depth noise model.

The colour sensor is 4:3 with about 69 degrees of horizontal field of view; the real pipeline
resizes its frames to 224 x 224, so pixels are not square (fx != fy). Depth is planar (along the
optical axis) in metres, 0 = no return, like the RealSense. The camera sits `mount_forward` ahead
of the robot centre, `mount_height` above the ground, tilted `tilt_deg` upwards.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from segmin.data.synth.noise_field import field_window


@dataclass
class CameraModel:
    width: int = 224
    height: int = 224
    hfov_deg: float = 69.0
    sensor_aspect: float = 4.0 / 3.0  # width / height of the physical colour sensor
    near: float = 0.05
    far: float = 60.0
    mount_forward: float = 0.2
    mount_height: float = 0.40  # Jackal camera height above the ground
    tilt_deg: float = 15.0
    # Depth noise (RealSense-like): sigma = depth_noise_k * z^2, random dropouts, max range.
    depth_noise_enabled: bool = True
    depth_noise_k: float = 0.004
    depth_invalid_fraction: float = 0.02
    max_range: float = 16.0
    # Where the noise's random draws come from: "pixels" (drawn per pixel, the reference) or "field"
    # (a window of fixed random fields, data.synth.noise_field: same model, a fraction of the time).
    depth_noise_sampling: Literal["pixels", "field"] = "pixels"

    def __post_init__(self) -> None:
        if self.width < 8 or self.height < 8:
            raise ValueError(f"camera.width/height: at least 8 pixels, got {self.width}x{self.height}")
        if not 10 <= self.hfov_deg <= 170:
            raise ValueError(f"camera.hfov_deg: must be within [10, 170], got {self.hfov_deg}")
        if not 0 < self.near < self.far:
            raise ValueError(f"camera.near/far: need 0 < near < far, got {self.near}, {self.far}")
        if self.max_range <= 0:
            raise ValueError(f"camera.max_range: must be > 0, got {self.max_range}")
        if self.depth_noise_k < 0 or not 0 <= self.depth_invalid_fraction <= 1:
            raise ValueError("camera.depth_noise_k must be >= 0 and depth_invalid_fraction within [0, 1]")
        if self.depth_noise_sampling not in ("pixels", "field"):
            raise ValueError(f"camera.depth_noise_sampling: 'pixels' or 'field', got {self.depth_noise_sampling!r}")

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view of the 4:3 sensor (the 224 x 224 frame keeps both FOVs)."""
        return math.degrees(2 * math.atan(math.tan(math.radians(self.hfov_deg) / 2) / self.sensor_aspect))

    def intrinsics(self) -> dict:
        """Pinhole intrinsics of the delivered frame, matching TinyRenderer's pixel sampling.

        Pixel (u, v) (column, row from the top) looks along camera-frame direction
        ((u - cx) / fx, (v - cy) / fy, 1) with x right, y down, z forward (OpenCV convention).
        TinyRenderer samples pixel centres half a pixel off the usual convention, hence cx, cy.
        """
        fx = (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)
        fy = (self.height / 2) / math.tan(math.radians(self.vfov_deg) / 2)
        return {
            "width": self.width,
            "height": self.height,
            "fx": fx,
            "fy": fy,
            "cx": self.width / 2,
            "cy": self.height / 2 - 1,
            "hfov_deg": self.hfov_deg,
            "vfov_deg": self.vfov_deg,
            "near": self.near,
            "far": self.far,
            "max_range": self.max_range,
        }

    def pixel_rays(self) -> np.ndarray:
        """(H, W, 3) camera-frame directions with z = 1 (planar depth multiplies them)."""
        k = self.intrinsics()
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        return np.stack([(u - k["cx"]) / k["fx"], (v - k["cy"]) / k["fy"], np.ones_like(u, float)], axis=-1)

    def apply_depth_noise(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """RealSense-like depth: Gaussian noise ~ k z^2, dropouts and far returns reported as 0.

        In place on one float32 array and one boolean one: a simulator step spends a fraction of
        a millisecond here, where temporaries cost as much as the arithmetic. The products come in
        the reference's order ((k z) z n + z), so the frames are bit for bit the same."""
        true = depth.astype(np.float32, copy=False)
        uniform: np.ndarray | None = None
        if self.depth_noise_sampling == "field":
            normal, uniform = field_window(rng, true.shape)
        else:  # normal first, uniform after: the reference's frames depend on the order
            normal = rng.standard_normal(true.shape, dtype=np.float32)
        out = true * np.float32(self.depth_noise_k)
        out *= true
        out *= normal
        out += true
        if uniform is None:
            uniform = rng.random(out.shape, dtype=np.float32)
        no_return = true > 0
        no_return &= true <= self.max_range  # no return beyond the maximum range (nor for NaN)
        np.logical_not(no_return, out=no_return)
        no_return |= uniform < self.depth_invalid_fraction  # dropouts
        no_return |= out <= 0
        np.copyto(out, np.float32(0.0), where=no_return)
        return out
