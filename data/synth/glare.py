"""Low-sun glare on a rendered colour image: a blown-out sky, bloom over what stands against it,
and with the sun ahead a lens flare (the sun's glow, ghosts along the line through the image
centre, a veil that lifts the shadows).

A camera exposed for the rows saturates where it sees a low sun's sky: the sky goes white, and
its light bleeds over thin canopy and leaf edges, which real back-lit photos show as half-washed
plants. This is an image-space effect on the colour image only: the mask and depth stay those of
the geometry, so a model learns to paint the canopy through the glare.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from segmin.data.synth.camera import CameraModel


def sun_pixel(pose: np.ndarray, light_direction, camera: CameraModel) -> tuple[float, float] | None:
    """(u, v) where the sun is in the image (possibly outside it), or None when it is behind the camera.

    `light_direction` points from the scene towards the sun (world frame), `pose` is camera-to-world."""
    d = np.asarray(light_direction, float)
    d = d / max(float(np.linalg.norm(d)), 1e-9)
    x, y, z = pose[:3, :3].T @ d
    if z <= 1e-3:
        return None
    k = camera.intrinsics()
    return float(k["cx"] + k["fx"] * x / z), float(k["cy"] + k["fy"] * y / z)


def apply_glare(
    rgb: np.ndarray, sky: np.ndarray, sun: tuple[float, float] | None, strength: float, rng: np.random.Generator
) -> np.ndarray:
    """`rgb` (uint8 H x W x 3) with glare of `strength` (0..1): `sky` is where nothing was hit, `sun`
    the sun's pixel when it is ahead (flare and veil), None for a sun behind the camera."""
    h, w = rgb.shape[:2]
    img = rgb.astype(np.float32) / 255.0
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    near_sun = np.zeros((h, w), np.float32)
    if sun is not None:
        dist = np.hypot(xx - sun[0], yy - sun[1]) / max(w, h)
        near_sun = np.exp(-dist / np.float32(0.35))
    # The sky saturates: towards white, whitest around the sun.
    blow = np.clip(strength * (0.75 + 0.5 * near_sun), 0, 1)[..., None] * sky[..., None]
    img = img + (1.0 - img) * blow
    # Bloom: the brightest parts bleed over their surroundings (thin leaves against the sky wash out).
    bright = np.clip((np.maximum(np.maximum(img[..., 0], img[..., 1]), img[..., 2]) - 0.8) / 0.2, 0, 1)
    sigma = max(1.0, 0.02 * w * (1 + strength))
    bloom = cv2.GaussianBlur(bright, (0, 0), sigma)
    img = img + (0.45 * strength) * bloom[..., None] * (1.0 - img)
    if sun is not None:
        # Exposure pulled down by the bright sky: what stands against it turns to a dark silhouette.
        img = np.where(sky[..., None], img, img * np.float32(1 - strength * rng.uniform(0.15, 0.45)))
        # The sun's glow (also from just outside the frame), and a veil that lifts every shadow.
        img = img + (1.0 - img) * (0.9 * strength * near_sun**3)[..., None]
        veil = strength * rng.uniform(0.06, 0.2)
        tone = np.array([1.0, rng.uniform(0.93, 1.0), rng.uniform(0.8, 0.95)], np.float32)
        img = img * (1 - veil) + veil * tone
        img = _ghosts(img, sun, strength, rng, xx, yy)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _ghosts(img: np.ndarray, sun: tuple[float, float], strength: float, rng: np.random.Generator, xx, yy) -> np.ndarray:
    """Faint coloured discs (the lens' internal reflections) on the line from the sun through the
    centre; each is drawn inside its own bounding box (a full-frame pass per ghost costs more than
    all the rest of the glare)."""
    h, w = img.shape[:2]
    cx, cy = w / 2, h / 2
    for _ in range(int(rng.integers(3, 7))):
        t = rng.uniform(-1.6, 0.6)  # 1 = the sun, 0 = the centre, < 0 = beyond it
        gx, gy = cx + (sun[0] - cx) * t, cy + (sun[1] - cy) * t
        radius = max(w, h) * rng.uniform(0.015, 0.09)
        hue = rng.uniform(0, 1)
        colour = np.array(
            [0.5 + 0.5 * math.cos(2 * math.pi * (hue + k / 3)) for k in range(3)], np.float32
        )  # any hue, pastel
        alpha = strength * rng.uniform(0.08, 0.3)
        x0, x1 = max(int(gx - radius), 0), min(int(gx + radius) + 2, w)
        y0, y1 = max(int(gy - radius), 0), min(int(gy + radius) + 2, h)
        if x0 >= x1 or y0 >= y1:  # outside the frame
            continue
        box = np.s_[y0:y1, x0:x1]
        edge = np.clip((radius - np.hypot(xx[box] - gx, yy[box] - gy)) / max(1.0, 0.3 * radius), 0, 1)
        img[box] += (alpha * edge)[..., None] * colour * (1.0 - img[box])
    return img
