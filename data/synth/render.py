"""Render RGB, planar depth and an exact vegetation mask of a built world, fast.

pybullet's TinyRenderer has no culling of its own: every frame we hide (alpha 0) the chunks
outside the view frustum or beyond `render.cull_distance`, and show far chunks at their coarse
level of detail. Shadows double a frame's cost, so they are drawn on a share of frames only
(`render.shadow_probability`); light direction, colour and ambient/diffuse terms, overcast or
back-lit skies, a low sun behind the camera, glare (`glare.py`) and distance haze are randomised
from the world's `sky` section. Backdrop chunks
skip the distance cut. Where nothing was hit, a sky (gradient plus clouds) is composited and
depth is 0 (no return).

`render.backend` picks the rasteriser: `tiny` (TinyRenderer, the reference) or `gl` (OpenGL through
EGL, `gl_raster.py`), which draws the same meshes, and TinyRenderer's shadows by TinyRenderer's
model, and needs no alpha changes in pybullet; culling, level of detail, sky, haze and exposure are
this module's for both. `auto`, the default, is gl wherever OpenGL through EGL loads, and
TinyRenderer elsewhere, said in one log line per process (`resolve_backend`). The gl context opens
at the first frame, not when the renderer is built (see `Renderer.raster`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pybullet as p

from segmin.data.synth.camera import CameraModel
from segmin.data.synth.glare import apply_glare, sun_pixel
from segmin.data.synth.world import World

if TYPE_CHECKING:
    from segmin.data.synth.gl_raster import GlRasteriser

log = logging.getLogger(__name__)

BACKENDS = ("auto", "tiny", "gl")
_fallback_said: list[str] = []  # the one fallback line of this process, once said


def resolve_backend(name: str) -> str:
    """`tiny` or `gl` for a `render.backend` value: `auto` is gl where OpenGL through EGL loads
    (`gl_raster.headless_gl_problem`), else TinyRenderer, with one line saying why."""
    if name not in BACKENDS:
        raise ValueError(f"render backend: one of {', '.join(BACKENDS)}, got {name!r}")
    if name != "auto":
        return name
    from segmin.data.synth.gl_raster import headless_gl_problem

    problem = headless_gl_problem()
    if problem is None:
        return "gl"
    _say_fallback(problem)
    return "tiny"


def _say_fallback(problem: str) -> None:
    """The one log line of a process whose `auto` backend is TinyRenderer."""
    if not _fallback_said:
        _fallback_said.append(problem)
        log.warning(
            "render.backend=auto: no headless OpenGL through EGL (%s); rendering with TinyRenderer, "
            "several times slower (render.backend=tiny says so and hides this line)",
            problem,
        )


@dataclass
class PoseOffset:
    """Camera pose perturbation relative to the nominal robot pose (metres, radians)."""

    lateral: float = 0.0  # + = left of the robot heading
    yaw: float = 0.0
    pitch: float = 0.0  # + = camera looks further up
    roll: float = 0.0

    @staticmethod
    def coerce(value) -> PoseOffset:
        if value is None:
            return PoseOffset()
        if isinstance(value, PoseOffset):
            return value
        if isinstance(value, dict):
            return PoseOffset(**value)
        return PoseOffset(*[float(v) for v in value])


@dataclass
class RenderedFrame:
    """One camera frame. `camera_pose` is camera-to-world 4x4 (OpenCV axes: x right, y down, z forward)."""

    rgb: np.ndarray | None  # uint8 H x W x 3; None when rendered without colour (`Renderer.render`)
    depth: np.ndarray  # float32 H x W metres, planar, 0 = invalid / no return
    mask: np.ndarray  # bool H x W, exact vegetation (trunks, branches, leaves)
    camera_pose: np.ndarray  # float64 4 x 4
    robot_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    body_ids: np.ndarray | None = None  # int32 H x W pybullet body id per pixel, -1 = nothing hit
    stats: dict = field(default_factory=dict)


def camera_pose(
    world: World, camera: CameraModel, x: float, y: float, yaw: float, pose_offset: PoseOffset | None = None
) -> np.ndarray:
    """Camera-to-world 4x4 of the camera on a robot at (x, y, yaw), following the terrain."""
    off = PoseOffset.coerce(pose_offset)
    x = x - math.sin(yaw) * off.lateral
    y = y + math.cos(yaw) * off.lateral
    heading = yaw + off.yaw
    n = np.asarray(world.terrain_normal(x, y), float).reshape(3)
    f0 = np.array([math.cos(heading), math.sin(heading), 0.0])
    f = f0 - f0.dot(n) * n
    f /= np.linalg.norm(f)
    base = np.array([x, y, world.terrain_height(x, y)])
    pos = base + camera.mount_forward * f + camera.mount_height * n
    pitch = math.radians(camera.tilt_deg) + off.pitch
    fwd = math.cos(pitch) * f + math.sin(pitch) * n
    up = -math.sin(pitch) * f + math.cos(pitch) * n
    y_cv = -up
    x_cv = _cross(y_cv, fwd)
    if off.roll:
        c, s = math.cos(off.roll), math.sin(off.roll)
        x_cv, y_cv = c * x_cv + s * y_cv, -s * x_cv + c * y_cv
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x_cv, y_cv, fwd, pos
    return pose


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors, as np.cross computes it (the same products, bit for bit) without its
    axis handling, which costs a tenth of a millisecond a frame."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _fixed_look() -> dict:
    """The look of a frame rendered without randomness: clear sky, the sun high, no haze or shadow."""
    return {
        "overcast": False,
        "cover": 0.0,
        "haze": 0.0,
        "shadow": False,
        "horizon": np.array([0.80, 0.85, 0.90]),
        "zenith": np.array([0.35, 0.55, 0.85]),
        "low_sun": "",
        "glare": 0.0,
        "light": {
            "lightDirection": [0.4, 0.3, 1.0],
            "lightColor": [1.0, 1.0, 1.0],
            "lightDistance": 100.0,
            "lightAmbientCoeff": 0.55,
            "lightDiffuseCoeff": 0.5,
            "lightSpecularCoeff": 0.05,
        },
    }


def sun_look(direction: list[float], distance: float) -> dict:
    """The fixed look lit by a sun from `direction`, `distance` metres away, shadows on: one light
    for both backends where they are compared."""
    look = _fixed_look()
    look["light"] = {**look["light"], "lightDirection": list(direction), "lightDistance": float(distance)}
    look["shadow"] = True
    return look


class Renderer:
    """Renders frames of one world with one camera model; keeps the per-body visibility state.

    Use one Renderer per world at a time: it tracks which bodies it has hidden, so a second
    renderer changing the same bodies would leave the first one's bookkeeping stale.
    """

    def __init__(self, world: World, camera: CameraModel | None = None, backend: str | None = None) -> None:
        """`backend` overrides the world's `render.backend` (the agreement bench renders one world with
        both: the gl backend leaves pybullet's bodies alone, so a tiny renderer beside it stays right)."""
        self.world = world
        self.client = world.client_id
        self._optics: dict[tuple, tuple] = {}
        self.set_camera(camera or CameraModel())
        chunks = world.chunks
        self.centres = np.array([c.centre for c in chunks])
        self.radii = np.array([c.radius for c in chunks])
        self.always = np.isinf(self.radii)
        # Things beyond the field are seen from anywhere: frustum culling only, no distance cap.
        self.far_ok = np.array([c.kind.startswith("backdrop") for c in chunks])
        caps = [c.capsule if c.capsule is not None else (c.centre, c.centre, c.radius) for c in chunks]
        self.cap_a = np.array([c[0] for c in caps])
        self.cap_ab = np.array([c[1] - c[0] for c in caps])
        self.cap_r = np.array([c[2] for c in caps])
        n_levels = max(len(c.bodies) for c in chunks)
        self.bodies = np.full((len(chunks), n_levels), -1, np.int64)
        self.tris = np.zeros((len(chunks), n_levels), np.int64)
        for i, c in enumerate(chunks):
            self.bodies[i, : len(c.bodies)] = c.bodies
            self.tris[i, : len(c.triangles)] = c.triangles
        self.n_levels = np.array([len(c.bodies) for c in chunks])
        self.veg_lut = np.zeros(int(self.bodies.max()) + 2, bool)
        for b in world.vegetation_ids:
            self.veg_lut[b + 1] = True
        self.rgba: dict[int, list[float]] = {}
        self.texture: dict[int, int] = {}
        self.shown: dict[int, bool] = {}
        self.hidden: set[int] = set()  # bodies kept hidden whatever the culling says (tests, ablations)
        self.state = self.bodies >= 0  # shown flag per (chunk, level), mirrors `shown`
        self.requested_backend = backend or world.spec.render.backend
        self.backend = resolve_backend(self.requested_backend)
        self._raster: GlRasteriser | None = None
        # Put every body in a known state: another renderer may have used this world before.
        for c in chunks:
            for b in c.bodies:
                if b < 0:
                    continue
                self.rgba[b] = list(c.tint[:3])
                self.texture[b] = c.texture
                self.shown[b] = True
                self._set_visual(b, texture=c.texture)
        self._noise_rng = np.random.default_rng([world.seed, 7])
        self.far_ground = np.array([0.42, 0.42, 0.3], np.float32)

    def set_camera(self, camera: CameraModel) -> None:
        """Switch to another camera model (dataset frames vary field of view and mount per frame);
        projections and sky rays are cached per field of view and size."""
        self.camera = cam = camera
        key = (cam.width, cam.height, cam.hfov_deg, cam.sensor_aspect, cam.near, cam.far)
        if key not in self._optics:
            aspect = math.tan(math.radians(cam.hfov_deg) / 2) / math.tan(math.radians(cam.vfov_deg) / 2)
            projection = p.computeProjectionMatrixFOV(
                cam.vfov_deg, aspect, cam.near, cam.far, physicsClientId=self.client
            )
            rays = cam.pixel_rays()
            rays = (rays / np.linalg.norm(rays, axis=-1, keepdims=True)).astype(np.float32)
            small = (max(2, cam.width // 4), max(2, cam.height // 4))
            yy, xx = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float32)
            radius = np.hypot((xx - cam.width / 2) / (cam.width / 2), (yy - cam.height / 2) / (cam.height / 2))
            if len(self._optics) > 64:
                self._optics.clear()
            self._optics[key] = (
                aspect,
                projection,
                cv2.resize(rays, small, interpolation=cv2.INTER_AREA),
                (radius / math.sqrt(2)).astype(np.float32),
            )
        self.aspect, self.projection, self.rays_small, self.radius = self._optics[key]
        self.tan_h = math.tan(math.radians(cam.hfov_deg) / 2)
        self.tan_v = math.tan(math.radians(cam.vfov_deg) / 2)

    @property
    def raster(self) -> GlRasteriser | None:
        """The gl backend's rasteriser (None with TinyRenderer), built at the first frame: a process
        that builds a renderer and draws nothing (Gymnasium's async vector builds an env in the parent
        for its spaces) opens no OpenGL context, so the workers it forks can open theirs. Where no
        context opens, an `auto` backend turns to TinyRenderer (one log line); `gl` says why and stops."""
        if self.backend != "gl":
            return None
        if self._raster is None:
            from segmin.data.synth.gl_raster import GlRasteriser, NoHeadlessGl

            try:
                self._raster = GlRasteriser(self.world)
                self._raster.set_looks(self.rgba, self.texture)
            except NoHeadlessGl as err:
                if self.requested_backend != "auto":
                    raise
                _say_fallback(err.reason)
                self.backend = "tiny"
                for body in self.shown:  # TinyRenderer reads tint, texture and shown flag from pybullet
                    self._set_visual(body, texture=self.texture[body])
        return self._raster

    def _set_visual(self, body: int, texture: int | None = None) -> None:
        """Show TinyRenderer a body's tint, texture and shown flag (alpha); the gl backend is given
        `rgba` and `texture` when they change (`GlRasteriser.set_looks`) and reads `state` at draw time."""
        if self.backend == "gl":
            return
        rgba = self.rgba[body] + [1.0 if self.shown[body] else 0.0]
        if texture is None:
            p.changeVisualShape(body, -1, rgbaColor=rgba, physicsClientId=self.client)
        else:
            p.changeVisualShape(body, -1, textureUniqueId=texture, rgbaColor=rgba, physicsClientId=self.client)

    # ----------------------------------------------------------------- appearance
    def randomize_appearance(self, rng: np.random.Generator) -> None:
        """Per-episode look: texture variants (incl. autumn) and colour tints of every chunk."""
        tex = self.world.textures
        main_plant = int(rng.integers(len(tex.plant)))
        ground = int(rng.integers(len(tex.ground)))
        ground_tint = rng.uniform(0.75, 1.0) * (1 + rng.uniform(-0.06, 0.06, 3))
        self.far_ground = (np.clip(ground_tint, 0, 1) * tex.ground_mean[ground]).astype(np.float32)
        struct_tint = rng.uniform(0.55, 1.0) * (1 + rng.uniform(-0.05, 0.05, 3))
        for c in self.world.chunks:
            if c.kind in ("plants", "wood"):
                variant = main_plant if rng.uniform() > 0.2 else int(rng.integers(len(tex.plant)))
                texture = tex.plant[variant]
                tint = rng.uniform(0.78, 1.0) * (1 + rng.uniform(-0.07, 0.07, 3))
            elif c.kind == "backdrop_tree":  # any leaf texture, often darker than the crop
                texture = tex.plant[int(rng.integers(len(tex.plant)))]
                tint = rng.uniform(0.45, 1.0) * (1 + rng.uniform(-0.1, 0.1, 3))
            elif c.kind == "backdrop_dark":  # a line closing the row: any leaf texture, in its own shade
                texture = tex.plant[int(rng.integers(len(tex.plant)))]
                tint = np.asarray(c.tint[:3]) * rng.uniform(0.85, 1.1) * (1 + rng.uniform(-0.08, 0.08, 3))
            elif c.kind == "lush":  # bright grass between the rows keeps its own texture
                texture, tint = c.texture, np.full(3, rng.uniform(0.85, 1.0)) * (1 + rng.uniform(-0.05, 0.05, 3))
            elif c.kind == "backdrop":  # buildings and hills keep their own tint
                texture, tint = c.texture, np.asarray(c.tint[:3]) * rng.uniform(0.8, 1.1)
            elif c.kind == "ground":
                texture, tint = tex.ground[ground], ground_tint
            elif c.kind == "grass":
                texture, tint = tex.grass[ground], ground_tint
            else:
                texture, tint = tex.structure, struct_tint
            for b in c.bodies:
                if b < 0:
                    continue
                self.rgba[b] = [min(max(float(v), 0.0), 1.0) for v in tint]
                self.texture[b] = texture
                self._set_visual(b, texture=texture)
        if self._raster is not None:
            self._raster.set_looks(self.rgba, self.texture)

    # ----------------------------------------------------------------- culling
    def _cull(self, pose: np.ndarray) -> dict:
        rot, pos = pose[:3, :3], pose[:3, 3]
        rel = (self.centres - pos) @ rot  # camera-frame coordinates (x right, y down, z fwd)
        r = self.radii
        spec = self.world.spec.render
        with np.errstate(invalid="ignore"):
            visible = (
                (rel[:, 2] > -r)
                & (np.abs(rel[:, 0]) <= rel[:, 2] * self.tan_h + r * math.sqrt(1 + self.tan_h**2))
                & (np.abs(rel[:, 1]) <= rel[:, 2] * self.tan_v + r * math.sqrt(1 + self.tan_v**2))
            )
        visible |= self.always
        # Distance to each chunk's capsule (rows are long and thin: a sphere is too loose).
        ab2 = np.maximum((self.cap_ab**2).sum(axis=1), 1e-9)
        t = np.clip(((pos - self.cap_a) * self.cap_ab).sum(axis=1) / ab2, 0, 1)
        closest = self.cap_a + t[:, None] * self.cap_ab
        dist = np.linalg.norm(closest - pos, axis=1) - np.where(self.always, 0.0, self.cap_r)
        visible &= self.always | self.far_ok | (dist < spec.cull_distance)
        level = np.searchsorted(np.asarray(spec.lod_distances), dist)
        level = np.minimum(level, self.n_levels - 1)
        want = visible[:, None] & (np.arange(self.bodies.shape[1])[None, :] == level[:, None]) & (self.bodies >= 0)
        if self.hidden:
            want &= ~np.isin(self.bodies, list(self.hidden))
        changed = np.nonzero(want != self.state)
        for i, lv in zip(*changed):
            b = int(self.bodies[i, lv])
            self.shown[b] = bool(want[i, lv])
            self._set_visual(b)
        self.state = want
        return {
            "visible_chunks": int(visible.sum()),
            "fine_chunks": int((visible & (level == 0)).sum()),
            "changes": len(changed[0]),
            "triangles": int(self.tris[want].sum()),
        }

    # ----------------------------------------------------------------- sky
    def _draw_look(self, rng: np.random.Generator | None, heading: float) -> dict:
        """Per-frame sky, sun and haze drawn from the world's `sky` ranges (`_fixed_look` without rng)."""
        if rng is None:
            return _fixed_look()
        sky = self.world.spec.sky
        # The first draws keep the order of the original renderer (sun, colour, terms, sky colours).
        az, el = rng.uniform(0, 2 * np.pi), math.radians(rng.uniform(*sky.sun_elevation))
        warm = rng.uniform(-0.12, 0.12)
        ambient, diffuse, specular = rng.uniform(0.35, 0.7), rng.uniform(0.3, 0.7), rng.uniform(0.0, 0.12)
        horizon = np.clip(np.array([0.78, 0.83, 0.88]) + rng.uniform(-0.1, 0.1, 3), 0, 1)
        zenith = np.clip(np.array([0.3, 0.5, 0.85]) + rng.uniform(-0.15, 0.12, 3), 0, 1)
        cover = rng.uniform(*sky.cloud_cover)
        overcast = sky.overcast_probability > 0 and rng.uniform() < sky.overcast_probability
        if overcast:  # white to grey, brighter at the horizon; soft light from everywhere
            grey = rng.uniform(0.6, 0.97)
            zenith = np.clip(grey * 0.92 + rng.uniform(-0.03, 0.03, 3), 0, 1)
            horizon = np.clip(np.full(3, min(grey * 1.05, 1.0)) + rng.uniform(-0.02, 0.02, 3), 0, 1)
            cover, warm = 0.0, warm * 0.3
            ambient, diffuse, specular = rng.uniform(0.6, 0.85), rng.uniform(0.1, 0.3), 0.0
        low_sun = ""
        if not overcast and sky.backlight_probability > 0 and rng.uniform() < sky.backlight_probability:
            az = heading + rng.normal(0, 0.4)  # sun ahead, low: plants seen from their dark side
            el = math.radians(rng.uniform(8, 30))
            horizon = np.clip(horizon + 0.12, 0, 1)
            low_sun = "ahead"
        haze = rng.uniform(*sky.haze) if sky.haze[1] > 0 else 0.0
        shadow = (
            not overcast
            and self.world.spec.render.shadow_probability > 0
            and rng.uniform() < self.world.spec.render.shadow_probability
        )
        # Drawn after everything above, and only when asked for: other worlds keep their frames.
        behind = sky.low_sun_behind_probability
        if not (overcast or low_sun) and behind > 0 and rng.uniform() < behind:  # sun behind, low: hard, warm
            az, el = heading + math.pi + rng.normal(0, 0.5), math.radians(rng.uniform(5, 25))
            warm = rng.uniform(0.06, 0.15)
            ambient, diffuse = rng.uniform(0.3, 0.45), rng.uniform(0.65, 0.9)
            low_sun = "behind"
        glare = 0.0
        if low_sun and sky.glare_probability > 0 and rng.uniform() < sky.glare_probability:
            glare = rng.uniform(*sky.glare_strength)
        light = {
            "lightDirection": [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)],
            "lightColor": [float(np.clip(1 + warm, 0, 1)), 1.0 - abs(warm) * 0.3, float(np.clip(1 - warm, 0, 1))],
            "lightDistance": 100.0,
            "lightAmbientCoeff": ambient,
            "lightDiffuseCoeff": diffuse,
            "lightSpecularCoeff": specular,
        }
        return {
            "overcast": overcast,
            "cover": cover,
            "haze": haze,
            "shadow": shadow,
            "horizon": horizon,
            "zenith": zenith,
            "light": light,
            "low_sun": low_sun,
            "glare": glare,
        }

    def _sky(self, pose: np.ndarray, rng: np.random.Generator | None, look: dict) -> np.ndarray:
        """Sky (and distant ground below the horizon), computed at 1/4 resolution and upsampled:
        it is smooth, and this keeps it under a millisecond."""
        cam = self.camera
        elev = self.rays_small @ pose[2, :3].astype(np.float32)  # world z of each pixel's ray
        horizon, zenith, cover = look["horizon"], look["zenith"], look["cover"]
        t = np.clip(elev * (1 / 0.6), 0, 1)
        t = t * (2 - t)
        sky = horizon.astype(np.float32) + t[..., None] * (zenith - horizon).astype(np.float32)
        below = elev < 0
        if below.any():  # distant ground beyond the tiles, fading into haze at the horizon
            haze = np.clip(-elev[below] * 12, 0, 1)[:, None]
            sky[below] = horizon * (1 - haze) + self.far_ground * haze
        # Clouds are drawn per frame; a look without rng (`_fixed_look`) has none.
        if rng is not None and look["overcast"]:  # soft large-scale structure of a cloud deck
            h, w = elev.shape
            deck = cv2.resize(rng.uniform(-1, 1, size=(3, 4)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
            sky[~below] *= (1 + 0.05 * deck[~below])[:, None]
        if rng is not None and cover > 0:
            h, w = elev.shape
            small = rng.uniform(0, 1, size=(5, 7)).astype(np.float32)
            fine = rng.uniform(0, 1, size=(14, 14)).astype(np.float32)
            clouds = 0.75 * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) + 0.25 * cv2.resize(
                fine, (w, h), interpolation=cv2.INTER_CUBIC
            )
            amount = np.clip((clouds - (1 - cover)) * 3, 0, 1) * np.clip(elev * 8 + 0.3, 0, 1)
            grey = np.float32(rng.uniform(0.75, 1.0))
            sky += amount[..., None] * (grey - sky)
        sky = cv2.resize(sky, (cam.width, cam.height), interpolation=cv2.INTER_LINEAR)
        return (np.clip(sky, 0, 1) * 255).astype(np.uint8)

    # ----------------------------------------------------------------- render
    def render(
        self,
        x: float,
        y: float,
        yaw: float,
        *,
        rng: np.random.Generator | None = None,
        noisy_depth: bool = False,
        pose_offset=None,
        colour: bool = True,
    ) -> RenderedFrame:
        """Render the camera of a robot at (x, y, yaw); `rng` randomises light, sky and exposure.

        The draws from `rng` come in a fixed order (look, sky, exposure, vignetting, depth noise):
        it is part of every frame's bytes.

        `colour=False` leaves the image out (`rgb` is None) for a consumer of depth and mask only:
        the gl backend then draws depth and ids alone, and no backend draws sky, haze or exposure.
        Depth, mask and ids are the colour frame's. A randomised look (`rng`) is for colour frames:
        it is refused without colour rather than drawn in a different order.
        """
        if not colour and rng is not None:
            raise ValueError("render(colour=False) takes no rng: light, sky and exposure are colour only")
        cam = self.camera
        pose = camera_pose(self.world, cam, x, y, yaw, pose_offset)
        stats = self._cull(pose)
        look = self._draw_look(rng, math.atan2(pose[1, 2], pose[0, 2]))
        rgb, depth, ids = self.rasterise(pose, look, colour)
        mask = np.take(self.veg_lut, ids + 1, mode="clip")  # one pass (ids of bodies outside the table: clipped)
        rgb = self._colour(rgb, pose, rng, look, ids, depth) if colour and rgb is not None else None
        if noisy_depth and cam.depth_noise_enabled:
            depth = cam.apply_depth_noise(depth, rng if rng is not None else self._noise_rng)
        return RenderedFrame(
            rgb=rgb,
            depth=depth,
            mask=mask,
            camera_pose=pose,
            robot_pose=(float(x), float(y), float(yaw)),
            body_ids=ids,
            stats={
                **stats,
                "shadow": bool(look["shadow"]),
                "overcast": bool(look["overcast"]),
                "low_sun": look["low_sun"],
                "glare": float(look["glare"]),
            },
        )

    def _colour(
        self,
        rgb: np.ndarray,
        pose: np.ndarray,
        rng: np.random.Generator | None,
        look: dict,
        ids: np.ndarray,
        depth: np.ndarray,
    ) -> np.ndarray:
        """The rasterised image finished: sky where nothing was hit, haze, exposure, then glare (what
        saturates stays saturated whatever the exposure)."""
        hit = ids >= 0
        if not hit.all():  # OpenCV's masked copy: numpy's copyto with a broadcast mask took 40x as long
            rgb = cv2.copyTo(self._sky(pose, rng, look), (~hit).view(np.uint8), rgb)
        if look["haze"] > 0:  # aerial perspective: far things fade towards the horizon colour
            fade = (look["haze"] / (1 - math.exp(-1))) * (1 - np.exp(-depth / np.float32(50.0)))
            fade[~hit] = 0.0
            rgb = (rgb * (1 - fade[..., None]) + (look["horizon"] * 255).astype(np.float32) * fade[..., None]).astype(
                np.uint8
            )
        if rng is not None:
            rgb = self._expose(rgb, rng)
        if look["glare"] > 0 and rng is not None:  # colour only: mask and depth keep the geometry
            sun = sun_pixel(pose, look["light"]["lightDirection"], self.camera) if look["low_sun"] == "ahead" else None
            rgb = apply_glare(rgb, ~hit, sun, look["glare"], rng)
        return rgb

    def rasterise(
        self, pose: np.ndarray, look: dict, colour: bool = True
    ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """The backend's raw image of the bodies shown now (after `_cull(pose)`) in `look`'s light and
        shadow: RGB (None without `colour`; TinyRenderer always draws it), planar depth and body ids,
        before sky, haze and exposure. The render-agreement bench compares backends through it."""
        raster = self.raster
        if raster is None:
            return self._shoot(pose, look)
        bodies = self.bodies[self.state].tolist()
        if not colour:
            return None, *raster.shoot_depth_ids(self.camera, pose, bodies)
        return raster.shoot(self.camera, pose, look["light"], bodies, shadow=bool(look["shadow"]))

    def _shoot(self, pose: np.ndarray, look: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """TinyRenderer's image from `pose` in `look`'s light: RGB, planar depth (0 where nothing was
        hit) and body ids (-1 there)."""
        cam = self.camera
        eye = pose[:3, 3]
        view = p.computeViewMatrix(
            eye.tolist(), (eye + pose[:3, 2]).tolist(), (-pose[:3, 1]).tolist(), physicsClientId=self.client
        )
        _, _, rgba, zbuf, seg = p.getCameraImage(
            cam.width,
            cam.height,
            view,
            self.projection,
            shadow=int(look["shadow"]),
            renderer=p.ER_TINY_RENDERER,
            physicsClientId=self.client,
            **look["light"],
        )
        rgba = np.reshape(np.asarray(rgba, np.uint8), (cam.height, cam.width, 4))
        zbuf = np.reshape(np.asarray(zbuf, np.float32), (cam.height, cam.width))
        seg = np.reshape(np.asarray(seg, np.int32), (cam.height, cam.width))
        hit = seg >= 0
        ids = np.where(hit, seg & 0xFFFFFF, -1).astype(np.int32)
        near, far = cam.near, cam.far
        depth = np.float32(far * near) / (np.float32(far) - np.float32(far - near) * zbuf)
        depth[~hit] = 0.0
        return cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB), depth, ids

    def _expose(self, rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Camera exposure: a random gain per channel (saturating), then the world's vignetting."""
        gain = rng.uniform(0.85, 1.15) * (1 + rng.uniform(-0.04, 0.04, 3))
        rgb = cv2.multiply(rgb, (float(gain[0]), float(gain[1]), float(gain[2]), 0.0))  # saturating
        vig = self.world.spec.capture.vignetting
        if vig[1] > 0:
            amount = np.float32(rng.uniform(*vig))
            falloff = 1 - amount * np.clip(self.radius, 0, 1) ** 2
            rgb = (rgb * falloff[..., None]).astype(np.uint8)
        return rgb
