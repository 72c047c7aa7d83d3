"""How a world looks and is seen: colours and textures, sky and light, the camera, the rasteriser
and what stands beyond the field.

Sections of `WorldSpec` (`segmin.data.synth.spec`, where code imports them from). They change
what a frame shows; where the rows, plants and posts stand is `spec_field`'s. `capture` varies
dataset frames only: a closed-loop run keeps its job's camera.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from segmin.data.synth.spec_checks import Range, check_fraction, check_positive, check_range

# Ground styles of textures.GROUND_STYLES (kept here so the spec does not import pybullet code).
GROUND_STYLE_NAMES: tuple[str, ...] = ("patchy", "mown", "long", "dry", "soil", "litter")
# Upper bounds of what stands around the field (each adds triangles without limit, see spec_field).
MAX_BACKDROP_COUNT = {"trees": 200, "forest_edges": 8, "hedges": 8, "buildings": 20}


@dataclass
class AppearanceSpec:
    """Colour, texture and season ranges sampled per texture variant and per episode."""

    leaf_hue: Range = (70.0, 115.0)  # degrees (green ~ 100)
    leaf_saturation: Range = (0.35, 0.75)
    leaf_value: Range = (0.30, 0.65)
    autumn_probability: float = 0.15  # chance a texture variant has autumn tones
    bark_value: Range = (0.22, 0.45)
    ground_green: Range = (0.2, 0.7)  # grass cover of the "patchy" ground style
    ground_styles: list[str] = field(default_factory=lambda: list(GROUND_STYLE_NAMES))  # first = variant 0
    ground_detail: float = 0.5  # amplitude of the grass-blade fine detail (0 = smooth)
    leaf_detail: float = 0.35  # amplitude of per-texel leaf detail (0 = smooth)
    texture_variants: int = 3
    shade_probability: float = 0.0  # chance a leaf texture variant is canopy in deep shade (under nets, back-lit)
    shade_value: Range = (0.08, 0.22)  # leaf brightness of a deep-shade variant
    shade_saturation: Range = (0.15, 0.45)  # grey-green: shade takes colour as well as light

    def __post_init__(self) -> None:
        check_range("appearance.leaf_hue", self.leaf_hue)
        if self.leaf_hue[1] > 360:
            raise ValueError(f"appearance.leaf_hue: degrees within [0, 360], got {list(self.leaf_hue)}")
        for name in ("leaf_saturation", "leaf_value", "bark_value", "ground_green", "shade_value", "shade_saturation"):
            value = getattr(self, name)
            check_range(f"appearance.{name}", value)
            if value[1] > 1:
                raise ValueError(f"appearance.{name}: values within [0, 1], got {list(value)}")
        check_fraction("appearance.autumn_probability", self.autumn_probability)
        check_fraction("appearance.shade_probability", self.shade_probability)
        if self.texture_variants < 1:
            raise ValueError(f"appearance.texture_variants: at least 1, got {self.texture_variants}")
        if not self.ground_styles:
            raise ValueError("appearance.ground_styles: at least one style")
        for style in self.ground_styles:
            if style not in GROUND_STYLE_NAMES:
                raise ValueError(
                    f"appearance.ground_styles: unknown style {style!r}; choose from {list(GROUND_STYLE_NAMES)}"
                )
        for name in ("ground_detail", "leaf_detail"):
            if not 0 <= getattr(self, name) <= 2:
                raise ValueError(f"appearance.{name}: must be within [0, 2], got {getattr(self, name)}")


@dataclass
class RenderSpec:
    """Per-world rendering knobs: which rasteriser, what to hide and when to switch to coarse meshes.

    `backend`: `tiny` is pybullet's TinyRenderer, the reference; `gl` is OpenGL through a headless
    EGL context (Mesa's llvmpipe on a CPU), several times faster, same masks, depth and shadows (see
    data/synth/gl_raster.py); `auto` is gl wherever EGL loads and tiny elsewhere, said in one log line.
    """

    backend: Literal["auto", "tiny", "gl"] = "auto"
    cull_distance: float = 35.0
    lod_distances: tuple[float, float] = (4.0, 10.0)  # switch to the next coarser level beyond these
    chunk_length: float = 3.0  # plants of one row within this length share one body
    shadow_probability: float = 0.0  # share of frames drawn with shadows (TinyRenderer's model, both backends)

    def __post_init__(self) -> None:
        check_fraction("render.shadow_probability", self.shadow_probability)
        check_positive("render.cull_distance", self.cull_distance)
        check_range("render.lod_distances", self.lod_distances)
        check_positive("render.chunk_length", self.chunk_length)


@dataclass
class SkySpec:
    """Sky and light per frame: clear to overcast skies, sun height, haze and back-light."""

    overcast_probability: float = 0.0  # white/grey overcast sky, soft light (no strong sun)
    cloud_cover: Range = (0.0, 0.8)  # cloud amount of clear-sky frames
    sun_elevation: Range = (20.0, 80.0)  # degrees above the horizon
    backlight_probability: float = 0.0  # low sun in front of the camera (dark, rim-lit plants)
    haze: Range = (0.0, 0.0)  # distance haze: fraction of the horizon colour at 50 m
    low_sun_behind_probability: float = 0.0  # low sun behind the camera: warm, hard, frontal light
    glare_probability: float = 0.0  # share of low-sun frames with a blown-out sky, bloom and (sun ahead) lens flare
    glare_strength: Range = (0.4, 1.0)  # how strong the glare is, 1 = sky white, canopy edges washed out

    def __post_init__(self) -> None:
        check_fraction("sky.overcast_probability", self.overcast_probability)
        check_fraction("sky.backlight_probability", self.backlight_probability)
        check_fraction("sky.low_sun_behind_probability", self.low_sun_behind_probability)
        check_fraction("sky.glare_probability", self.glare_probability)
        check_range("sky.glare_strength", self.glare_strength)
        if self.glare_strength[1] > 1:
            raise ValueError(f"sky.glare_strength: values within [0, 1], got {list(self.glare_strength)}")
        if self.glare_probability > 0 and self.backlight_probability + self.low_sun_behind_probability == 0:
            raise ValueError(
                "sky.glare_probability: glare comes with a low sun; set sky.backlight_probability or "
                "sky.low_sun_behind_probability above 0"
            )
        check_range("sky.cloud_cover", self.cloud_cover)
        check_range("sky.haze", self.haze)
        check_range("sky.sun_elevation", self.sun_elevation, strict=True)
        for name in ("cloud_cover", "haze"):
            if getattr(self, name)[1] > 1:
                raise ValueError(f"sky.{name}: values within [0, 1], got {list(getattr(self, name))}")
        if self.sun_elevation[1] > 90:
            raise ValueError(f"sky.sun_elevation: degrees within (0, 90], got {list(self.sun_elevation)}")


@dataclass
class CaptureSpec:
    """Camera variety of dataset frames (the writer only; closed-loop runs keep their camera).

    A range with low == high keeps the job camera's value; otherwise each frame draws its own
    (recorded in meta.json with the frame's intrinsics).
    """

    hfov_deg: Range = (69.0, 69.0)  # horizontal field of view; real robots use 60-120
    mount_height: Range = (0.4, 0.4)  # camera height above the ground (m)
    tilt_deg: Range = (15.0, 15.0)  # upward tilt
    vignetting: Range = (0.0, 0.0)  # corner darkening (fraction of brightness lost)
    blank_frames: float = 0.0  # share of frames all black, all white or one colour: empty mask, no depth

    def __post_init__(self) -> None:
        check_range("capture.hfov_deg", self.hfov_deg, low=10.0)
        if self.hfov_deg[1] > 170:
            raise ValueError(f"capture.hfov_deg: within [10, 170], got {list(self.hfov_deg)}")
        check_range("capture.mount_height", self.mount_height, strict=True)
        check_range("capture.tilt_deg", self.tilt_deg, low=-60.0)
        if self.tilt_deg[1] > 60:
            raise ValueError(f"capture.tilt_deg: within [-60, 60], got {list(self.tilt_deg)}")
        check_range("capture.vignetting", self.vignetting)
        if self.vignetting[1] > 0.8:
            raise ValueError(f"capture.vignetting: within [0, 0.8], got {list(self.vignetting)}")
        if not 0 <= self.blank_frames <= 0.5:
            raise ValueError(f"capture.blank_frames: a share within [0, 0.5], got {self.blank_frames}")


@dataclass
class BackdropSpec:
    """What stands beyond the field: never vegetation in the mask, whatever it looks like.

    Real rows end in hedges, forest edges, single trees, buildings and hills; a model that never
    saw them paints them as crop. Distances are measured from the field's edge (the outer rows
    and the row ends).
    """

    trees: int = 0  # single trees and forest-edge trees around the field
    tree_height: Range = (5.0, 14.0)
    tree_distance: Range = (4.0, 30.0)
    forest_edges: int = 0  # dense lines of trees along a side of the field
    hedges: int = 0  # low continuous hedges along a side
    hedge_height: Range = (1.2, 3.0)
    buildings: int = 0
    building_height: Range = (3.0, 8.0)
    hills: float = 0.0  # probability of a ridge of hills on the horizon
    row_end_probability: float = 0.0  # chance each end of the rows is closed by a dense, dark hedge or tree line
    row_end_distance: Range = (1.5, 6.0)  # from the row ends to the line (m)
    row_end_height: Range = (2.5, 9.0)  # top of the line: a hedge (2-4 m) to a line of trees
    row_end_brightness: Range = (0.2, 0.55)  # its leaves' share of the crop's light: dark, in its own shade

    def __post_init__(self) -> None:
        for name, most in MAX_BACKDROP_COUNT.items():
            if not 0 <= getattr(self, name) <= most:
                raise ValueError(f"backdrop.{name}: within [0, {most}], got {getattr(self, name)}")
        for name in ("tree_height", "hedge_height", "building_height", "row_end_height"):
            check_range(f"backdrop.{name}", getattr(self, name), strict=True)
        check_range("backdrop.tree_distance", self.tree_distance)
        check_fraction("backdrop.hills", self.hills)
        check_fraction("backdrop.row_end_probability", self.row_end_probability)
        check_range("backdrop.row_end_distance", self.row_end_distance, low=0.5)
        if self.row_end_distance[1] > 40:
            raise ValueError(f"backdrop.row_end_distance: within [0.5, 40] m, got {list(self.row_end_distance)}")
        if self.row_end_height[1] > 30:
            raise ValueError(f"backdrop.row_end_height: at most 30 m, got {list(self.row_end_height)}")
        check_range("backdrop.row_end_brightness", self.row_end_brightness, strict=True)
        if self.row_end_brightness[1] > 1:
            raise ValueError(f"backdrop.row_end_brightness: within (0, 1], got {list(self.row_end_brightness)}")
