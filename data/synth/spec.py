"""World specs: every number that shapes a procedural field, validated before anything is built.

A spec is a YAML file in `configs/worlds/` loaded strictly (unknown keys are errors, see
`segmin.common.config`). Geometry is in metres and degrees; ranges are `[low, high]` pairs that the
world builder samples per plant. Validation raises an error naming the field, so a typo or an
impossible field (negative spacing, rows that would intersect) fails before pybullet starts.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from segmin.common.angles import wrap_angle
from segmin.common.config import apply_overrides, from_dict, read_yaml
from segmin.common.shipped import resolve_config

log = logging.getLogger(__name__)

# Shipped worlds renamed for what they hold (they were named for the experiment that made them):
# the old names load the new worlds, with a warning, for one release.
RENAMED_WORLDS: dict[str, str] = {
    "train_vineyard_a_levers": "train_vineyard_under_nets",
    "train_vineyard_b_levers": "train_vineyard_winter_dormant",
    "train_pergola_a_levers": "train_pergola_under_net",
    "train_pear_a_levers": "train_pear_under_nets",
    "train_apple_wall_a_levers": "train_apple_wall_under_nets",
}

TEST_FIELDS: tuple[str, ...] = (
    "straight_vineyard",
    "curved_vineyard",
    "pergola_vineyard",
    "pear_field",
    "high_trees",
)


Range = tuple[float, float]
# Ground styles of textures.GROUND_STYLES (kept here so the spec does not import pybullet code).
GROUND_STYLE_NAMES: tuple[str, ...] = ("patchy", "mown", "long", "dry", "soil", "litter")
# Colours of anti-hail nets and materials of posts (their looks: nets.py, posts.py).
NET_COLOUR_NAMES: tuple[str, ...] = ("black", "grey", "white")
POST_STYLE_NAMES: tuple[str, ...] = ("wood", "concrete", "metal")

# The narrowest free gap a world may have: the evaluation robot's footprint (a Clearpath Jackal,
# 0.43 m wide, see nav_eval.robot.RobotConfig; data must not import nav_eval) plus 0.1 m either
# side. A narrower gap is a field no run can drive, so every run would "collide" by construction.
MIN_GAP_WIDTH = 0.63
# Rows are offset lines of the reference polyline, which the world follows point by point
# (linear between vertices). At a vertex turning by theta the offset line at distance h on the
# inner side folds back over itself by 2 h tan(theta / 2): beyond a few centimetres the
# inner rows cross themselves and their neighbours, whatever the segment lengths.
MAX_POLYLINE_FOLD = 0.1
# How far an anti-hail net's ridge (over a row line) stays above the tallest plant.
NET_CLEARANCE = 0.2
# Upper bounds of amounts that grow a world's triangle count (and memory) without limit: a field of
# 25 m rows holds millions of triangles at these, far past anything a real row shows. Anti-hail nets
# hang 3-7 m up on their posts; 15 m clears the tallest orchard trees a world builds.
MAX_NET_HEIGHT = 15.0
MAX_TUFTS_PER_M2 = 200.0  # grass tufts per square metre: a closed sward
MAX_ROW_WEEDS_PER_M = 50.0  # weed tufts per metre of row: one every 2 cm
MAX_BACKDROP_COUNT = {"trees": 200, "forest_edges": 8, "hedges": 8, "buildings": 20}


def _check_range(name: str, value: Range, *, low: float | None = 0.0, strict: bool = False) -> None:
    a, b = value
    if a > b:
        raise ValueError(f"{name}: range [{a}, {b}] has low > high")
    if low is not None and (a < low or (strict and a <= low)):
        raise ValueError(f"{name}: values must be {'>' if strict else '>='} {low}, got [{a}, {b}]")


def _check_finite(value, name: str) -> None:
    """NaN compares false with everything, so range checks would let it through: reject it (and
    infinities) in every number of the spec, naming the field."""
    if dataclasses.is_dataclass(value):
        for f in dataclasses.fields(value):
            _check_finite(getattr(value, f.name), f"{name}.{f.name}" if name else f.name)
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_finite(v, f"{name}[{i}]")
    elif isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{name}: must be a finite number, got {value}")


def _check_positive(name: str, value: float) -> None:
    if not value > 0:
        raise ValueError(f"{name}: must be > 0, got {value}")


def _check_fraction(name: str, value: float) -> None:
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{name}: must be within [0, 1], got {value}")


def _check_names(name: str, values: list[str], allowed: tuple[str, ...]) -> None:
    """A non-empty list of names out of `allowed` (styles, colours)."""
    if not values:
        raise ValueError(f"{name}: at least one of {list(allowed)}")
    for v in values:
        if v not in allowed:
            raise ValueError(f"{name}: unknown value {v!r}; choose from {list(allowed)}")


@dataclass
class RowsSpec:
    """Row layout: `count` plant rows, `count - 1` gaps the robot can drive through."""

    count: int = 4
    length: float = 25.0  # along the row, from the entrance at s = 0
    spacing: float = 1.8  # distance between neighbouring row lines
    start_x: float = 0.0  # x of the row entrance
    curve_radius: float = 0.0  # 0 = straight; > 0 bends left, < 0 bends right
    curve_start: float = 0.0  # straight part before the bend starts
    polyline: list[tuple[float, float]] = field(default_factory=list)  # optional reference line (x, y)
    lateral_jitter: float = 0.03  # plant offset from the row line (std, m)
    eval_gap: int = -1  # gap the evaluation drives through; -1 = the middle one

    def __post_init__(self) -> None:
        if self.count < 2:
            raise ValueError(f"rows.count: need at least 2 rows (one gap), got {self.count}")
        _check_positive("rows.length", self.length)
        _check_positive("rows.spacing", self.spacing)
        if self.lateral_jitter < 0:
            raise ValueError(f"rows.lateral_jitter: must be >= 0, got {self.lateral_jitter}")
        if self.curve_start < 0:
            raise ValueError(f"rows.curve_start: must be >= 0, got {self.curve_start}")
        half_width = 0.5 * (self.count - 1) * self.spacing
        if self.curve_radius != 0 and abs(self.curve_radius) <= half_width + 1.0:
            raise ValueError(
                f"rows.curve_radius: |{self.curve_radius}| m is too tight for {self.count} rows "
                f"{self.spacing} m apart; the inner rows would intersect (need > {half_width + 1.0:.1f} m)"
            )
        if self.polyline:
            self._check_polyline(half_width)
        if not -1 <= self.eval_gap < self.count - 1:
            raise ValueError(f"rows.eval_gap: must be -1 or a gap index below {self.count - 1}, got {self.eval_gap}")

    def _check_polyline(self, half_width: float) -> None:
        """The reference line must be long enough and turn gently enough for the outer rows."""
        pts = [tuple(map(float, q)) for q in self.polyline]
        if len(pts) < 2:
            raise ValueError("rows.polyline: needs at least 2 points (or leave it empty)")
        seg = [math.dist(a, b) for a, b in itertools.pairwise(pts)]
        if min(seg) <= 0:
            raise ValueError("rows.polyline: repeated point")
        if sum(seg) < self.length:
            raise ValueError(f"rows.polyline: {sum(seg):.1f} m long, shorter than rows.length {self.length}")
        reach = half_width + 1.0  # outermost row line plus its canopy and a margin
        for i in range(1, len(pts) - 1):
            a = math.atan2(pts[i][1] - pts[i - 1][1], pts[i][0] - pts[i - 1][0])
            b = math.atan2(pts[i + 1][1] - pts[i][1], pts[i + 1][0] - pts[i][0])
            turn = abs(wrap_angle(b - a))
            # The corner itself, as built (no smoothing): how far the inner rows fold back.
            fold = 2 * reach * math.tan(min(turn, math.pi * 0.999) / 2)
            if fold > MAX_POLYLINE_FOLD:
                raise ValueError(
                    f"rows.polyline: turns by {math.degrees(turn):.1f} deg at point {i} {list(pts[i])}; the rows "
                    f"{half_width:.1f} m either side would cross there (fold {fold:.2f} m > {MAX_POLYLINE_FOLD} m): "
                    "add points to round the corner"
                )
            # A run of small turns over short segments: the local radius of the bend.
            if turn > 1e-9 and 0.5 * (seg[i - 1] + seg[i]) / turn <= reach:
                raise ValueError(
                    f"rows.polyline: turns too sharply at point {i} for rows {half_width:.1f} m either side; "
                    "the inner rows would intersect"
                )


@dataclass
class PlantsSpec:
    """One plant = trunk, a few branches and a canopy of leaf clusters (see `plants.py`)."""

    spacing: float = 1.3
    spacing_jitter: float = 0.15  # uniform +- along the row (m)
    gap_probability: float = 0.05  # chance a plant is missing
    height: Range = (1.8, 2.1)  # top of the canopy above ground
    trunk_height: Range = (0.6, 0.8)  # where the trunk splits into branches / cordon
    trunk_radius: Range = (0.03, 0.05)
    canopy_bottom: Range = (0.8, 1.0)  # lowest leaves above ground
    canopy_width: Range = (0.4, 0.6)  # across the row (for pergola: unused, see structures)
    clusters: tuple[int, int] = (3, 5)  # leaf clusters per plant
    branches: tuple[int, int] = (2, 4)
    low_branches: tuple[int, int] = (0, 0)  # bare-ish branches reaching into the gap below the canopy
    low_branch_reach: float = 0.4
    leaf_size: Range = (0.08, 0.14)  # triangle edge length (fine level of detail)
    leaf_density: float = 0.7  # 0..1, how much of each cluster's shell is covered
    hanging_shoots: tuple[int, int] = (0, 0)  # shoots per plant hanging from the canopy into the row
    upright_shoots: tuple[int, int] = (0, 0)  # untrimmed shoots per plant rising above the canopy top
    sparse_probability: float = 0.0  # chance a plant is a sparse young vine (a third to half the leaves)
    dormant_probability: float = 0.0  # chance a vine is dormant (winter): bare canes, few or no leaves
    dormant_leaves: float = 0.1  # leaf density of a dormant vine, as a share of leaf_density (0 = bare)
    canes: tuple[int, int] = (6, 12)  # one-year canes per dormant vine: the canopy of a winter row
    label: Literal["canopy", "plant"] = "canopy"  # canopy: leaves (and canes) only are 1 (trunks, cordons = 0)

    def __post_init__(self) -> None:
        _check_positive("plants.spacing", self.spacing)
        if not 0 <= self.spacing_jitter < 0.5 * self.spacing:
            raise ValueError(f"plants.spacing_jitter: must be within [0, spacing/2), got {self.spacing_jitter}")
        _check_fraction("plants.gap_probability", self.gap_probability)
        _check_range("plants.height", self.height, strict=True)
        _check_range("plants.trunk_height", self.trunk_height, strict=True)
        _check_range("plants.trunk_radius", self.trunk_radius, strict=True)
        _check_range("plants.canopy_bottom", self.canopy_bottom)
        _check_range("plants.canopy_width", self.canopy_width, strict=True)
        _check_range("plants.leaf_size", self.leaf_size, strict=True)
        for name in ("clusters", "branches", "low_branches", "hanging_shoots", "upright_shoots", "canes"):
            a, b = getattr(self, name)
            if a < 0 or a > b:
                raise ValueError(f"plants.{name}: need 0 <= low <= high, got [{a}, {b}]")
        if self.clusters[0] < 1:
            raise ValueError(f"plants.clusters: at least one leaf cluster per plant, got {self.clusters}")
        if self.low_branch_reach < 0:
            raise ValueError(f"plants.low_branch_reach: must be >= 0, got {self.low_branch_reach}")
        _check_fraction("plants.leaf_density", self.leaf_density)
        _check_fraction("plants.sparse_probability", self.sparse_probability)
        _check_fraction("plants.dormant_probability", self.dormant_probability)
        _check_fraction("plants.dormant_leaves", self.dormant_leaves)
        for name in ("canopy_bottom", "trunk_height"):  # a plant's height is its top: both lie below it
            if getattr(self, name)[1] >= self.height[0]:
                raise ValueError(
                    f"plants.{name}: {list(getattr(self, name))} must lie below plants.height {list(self.height)}"
                )


@dataclass
class NetsSpec:
    """Anti-hail nets over the rows: seen in depth, never vegetation, and darker under them.

    Drawn per world build (a closed-loop episode builds its own world): whether there is a net,
    over the whole field or strips over single rows, its colour, height, mesh and how much light
    it takes away. Strands are opaque (neither renderer blends): a mesh finer than a pixel reads
    as a veil of the net's colour over the sky, like a real net seen from below.
    """

    probability: float = 0.0  # chance a world has nets
    field_probability: float = 0.5  # given nets: one net over the whole field, else strips over rows
    row_probability: float = 0.7  # strips: chance each row has one (at least one row has)
    height: Range = (2.8, 3.6)  # ridge over the row lines (m above the ground)
    sag: Range = (0.2, 0.6)  # how far the net hangs down between the ridges (m)
    colours: list[str] = field(default_factory=lambda: list(NET_COLOUR_NAMES))
    strand_spacing: Range = (0.06, 0.16)  # distance between strands of the drawn mesh (m)
    strand_width: Range = (0.006, 0.015)  # width of a drawn strand (m)
    drape_probability: float = 0.3  # chance the net hangs down the outer sides of what it covers
    dimming: Range = (0.1, 0.3)  # share of the light the net takes from everything under it

    def __post_init__(self) -> None:
        for name in ("probability", "field_probability", "row_probability", "drape_probability"):
            _check_fraction(f"structures.nets.{name}", getattr(self, name))
        _check_range("structures.nets.height", self.height, strict=True)
        if self.height[1] > MAX_NET_HEIGHT:
            raise ValueError(
                f"structures.nets.height: {list(self.height)} m; anti-hail nets hang at most {MAX_NET_HEIGHT} m up"
            )
        _check_range("structures.nets.sag", self.sag)
        if self.sag[1] >= 0.5 * self.height[0]:
            raise ValueError(
                f"structures.nets.sag: {list(self.sag)} must stay below half the net height {self.height[0]}"
            )
        _check_names("structures.nets.colours", self.colours, NET_COLOUR_NAMES)
        _check_range("structures.nets.strand_spacing", self.strand_spacing, strict=True)
        _check_range("structures.nets.strand_width", self.strand_width, strict=True)
        if self.strand_width[1] >= self.strand_spacing[0]:
            raise ValueError(
                f"structures.nets.strand_width: {list(self.strand_width)} must be narrower than the strand "
                f"spacing {list(self.strand_spacing)}"
            )
        _check_range("structures.nets.dimming", self.dimming)
        if self.dimming[1] > 0.9:
            raise ValueError(f"structures.nets.dimming: within [0, 0.9], got {list(self.dimming)}")


@dataclass
class StructuresSpec:
    """Supporting structures: they are obstacles but NOT vegetation in the mask."""

    poles: bool = True
    pole_spacing: float = 6.0
    pole_height: float = 2.1
    pole_radius: float = 0.04
    wire_heights: list[float] = field(default_factory=lambda: [0.9, 1.3, 1.7])
    pergola: bool = False
    pergola_height: float = 2.6  # height of the overhead frame and vine canopy
    free_band_width: float = 1.2  # free band over each gap (pergola only)
    free_band_offset: float = 0.0  # band centre offset from the gap middle, + = left (asymmetry)
    post_styles: list[str] = field(default_factory=list)  # varied posts: wood, concrete, metal ([] = plain poles)
    post_radius: Range = (0.035, 0.07)  # half-width of a varied post, drawn per post (m)
    square_probability: float = 0.5  # share of square varied posts (concrete, sawn wood, steel profiles)
    end_anchor_probability: float = 0.0  # chance a row end post leans outwards on an anchor wire
    wire_radius: Range = (0.006, 0.006)  # trellis wire radius, drawn per row and wire (m)
    nets: NetsSpec = field(default_factory=NetsSpec)

    def __post_init__(self) -> None:
        _check_positive("structures.pole_spacing", self.pole_spacing)
        _check_positive("structures.pole_height", self.pole_height)
        _check_positive("structures.pole_radius", self.pole_radius)
        for i, h in enumerate(self.wire_heights):
            if not 0 < h <= self.pole_height:
                raise ValueError(f"structures.wire_heights[{i}]: {h} must be within (0, pole_height]")
        if self.pergola:
            _check_positive("structures.pergola_height", self.pergola_height)
            _check_positive("structures.free_band_width", self.free_band_width)
        if self.post_styles:
            _check_names("structures.post_styles", self.post_styles, POST_STYLE_NAMES)
        _check_range("structures.post_radius", self.post_radius, strict=True)
        _check_fraction("structures.square_probability", self.square_probability)
        _check_fraction("structures.end_anchor_probability", self.end_anchor_probability)
        _check_range("structures.wire_radius", self.wire_radius, strict=True)


@dataclass
class TerrainSpec:
    """Uneven ground: a sum of smooth random waves (analytic height and normal)."""

    roughness: float = 0.06  # standard deviation of the height (m)
    wavelength: Range = (3.0, 12.0)
    slope: tuple[float, float] = (0.0, 0.0)  # constant slope dz/dx, dz/dy
    resolution: float = 1.0  # mesh grid step near the camera (m)
    margin: float = 8.0  # ground beyond the outer rows and row ends (m)
    grass_tufts: float = 0.6  # tufts per square metre (not vegetation)
    texture_scale: float = 2.0  # metres per repeat of the ground texture (finer = sharper blades)
    row_weeds: float = 0.0  # tall weed tufts per metre of row, at the row base (not vegetation)
    row_weed_height: Range = (0.4, 0.9)  # up into the canopy band (m)
    row_weed_reach: float = 0.4  # how far from the row line they grow (m)
    gap_grass: float = 0.0  # lush grass and weed tufts per square metre on the strip between the rows (not vegetation)
    gap_grass_height: Range = (0.12, 0.45)  # tuft height (m)

    def __post_init__(self) -> None:
        if self.roughness < 0:
            raise ValueError(f"terrain.roughness: must be >= 0, got {self.roughness}")
        _check_range("terrain.wavelength", self.wavelength, strict=True)
        _check_positive("terrain.resolution", self.resolution)
        if self.margin < 0:
            raise ValueError(f"terrain.margin: must be >= 0, got {self.margin}")
        _check_positive("terrain.texture_scale", self.texture_scale)
        for name in ("grass_tufts", "gap_grass"):
            if not 0 <= getattr(self, name) <= MAX_TUFTS_PER_M2:
                raise ValueError(
                    f"terrain.{name}: tufts per square metre within [0, {MAX_TUFTS_PER_M2:g}], got {getattr(self, name)}"
                )
        if not 0 <= self.row_weeds <= MAX_ROW_WEEDS_PER_M:
            raise ValueError(
                f"terrain.row_weeds: tufts per metre of row within [0, {MAX_ROW_WEEDS_PER_M:g}], got {self.row_weeds}"
            )
        _check_range("terrain.gap_grass_height", self.gap_grass_height, strict=True)
        if self.gap_grass_height[1] > 1.0:
            raise ValueError(f"terrain.gap_grass_height: tufts up to 1 m, got {list(self.gap_grass_height)}")
        _check_range("terrain.row_weed_height", self.row_weed_height, strict=True)
        if self.row_weed_height[1] > 1.5:
            raise ValueError(f"terrain.row_weed_height: weeds up to 1.5 m, got {list(self.row_weed_height)}")
        if self.row_weed_reach < 0:
            raise ValueError(f"terrain.row_weed_reach: must be >= 0, got {self.row_weed_reach}")


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
        _check_range("appearance.leaf_hue", self.leaf_hue)
        if self.leaf_hue[1] > 360:
            raise ValueError(f"appearance.leaf_hue: degrees within [0, 360], got {list(self.leaf_hue)}")
        for name in ("leaf_saturation", "leaf_value", "bark_value", "ground_green", "shade_value", "shade_saturation"):
            value = getattr(self, name)
            _check_range(f"appearance.{name}", value)
            if value[1] > 1:
                raise ValueError(f"appearance.{name}: values within [0, 1], got {list(value)}")
        _check_fraction("appearance.autumn_probability", self.autumn_probability)
        _check_fraction("appearance.shade_probability", self.shade_probability)
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
    EGL context (Mesa's llvmpipe on a CPU), several times faster, same masks and depth, no shadows
    (see data/synth/gl_raster.py).
    """

    backend: Literal["tiny", "gl"] = "tiny"
    cull_distance: float = 35.0
    lod_distances: tuple[float, float] = (4.0, 10.0)  # switch to the next coarser level beyond these
    chunk_length: float = 3.0  # plants of one row within this length share one body
    shadow_probability: float = 0.0  # share of frames with TinyRenderer shadows (about 2x the cost)

    def __post_init__(self) -> None:
        _check_fraction("render.shadow_probability", self.shadow_probability)
        _check_positive("render.cull_distance", self.cull_distance)
        _check_range("render.lod_distances", self.lod_distances)
        _check_positive("render.chunk_length", self.chunk_length)


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
        _check_fraction("sky.overcast_probability", self.overcast_probability)
        _check_fraction("sky.backlight_probability", self.backlight_probability)
        _check_fraction("sky.low_sun_behind_probability", self.low_sun_behind_probability)
        _check_fraction("sky.glare_probability", self.glare_probability)
        _check_range("sky.glare_strength", self.glare_strength)
        if self.glare_strength[1] > 1:
            raise ValueError(f"sky.glare_strength: values within [0, 1], got {list(self.glare_strength)}")
        if self.glare_probability > 0 and self.backlight_probability + self.low_sun_behind_probability == 0:
            raise ValueError(
                "sky.glare_probability: glare comes with a low sun; set sky.backlight_probability or "
                "sky.low_sun_behind_probability above 0"
            )
        _check_range("sky.cloud_cover", self.cloud_cover)
        _check_range("sky.haze", self.haze)
        _check_range("sky.sun_elevation", self.sun_elevation, strict=True)
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
        _check_range("capture.hfov_deg", self.hfov_deg, low=10.0)
        if self.hfov_deg[1] > 170:
            raise ValueError(f"capture.hfov_deg: within [10, 170], got {list(self.hfov_deg)}")
        _check_range("capture.mount_height", self.mount_height, strict=True)
        _check_range("capture.tilt_deg", self.tilt_deg, low=-60.0)
        if self.tilt_deg[1] > 60:
            raise ValueError(f"capture.tilt_deg: within [-60, 60], got {list(self.tilt_deg)}")
        _check_range("capture.vignetting", self.vignetting)
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
            _check_range(f"backdrop.{name}", getattr(self, name), strict=True)
        _check_range("backdrop.tree_distance", self.tree_distance)
        _check_fraction("backdrop.hills", self.hills)
        _check_fraction("backdrop.row_end_probability", self.row_end_probability)
        _check_range("backdrop.row_end_distance", self.row_end_distance, low=0.5)
        if self.row_end_distance[1] > 40:
            raise ValueError(f"backdrop.row_end_distance: within [0.5, 40] m, got {list(self.row_end_distance)}")
        if self.row_end_height[1] > 30:
            raise ValueError(f"backdrop.row_end_height: at most 30 m, got {list(self.row_end_height)}")
        _check_range("backdrop.row_end_brightness", self.row_end_brightness, strict=True)
        if self.row_end_brightness[1] > 1:
            raise ValueError(f"backdrop.row_end_brightness: within (0, 1], got {list(self.row_end_brightness)}")


@dataclass
class WorldSpec:
    """A whole field. `family` groups training worlds like the paper's crop families."""

    name: str
    crop: Literal["vineyard", "pergola", "pear", "tree"]
    family: Literal["vineyards", "trees"]
    seed: int
    domain: str = ""  # AgriSeg-style domain for the writer; default synth_<name>
    rows: RowsSpec = field(default_factory=RowsSpec)
    plants: PlantsSpec = field(default_factory=PlantsSpec)
    structures: StructuresSpec = field(default_factory=StructuresSpec)
    terrain: TerrainSpec = field(default_factory=TerrainSpec)
    appearance: AppearanceSpec = field(default_factory=AppearanceSpec)
    render: RenderSpec = field(default_factory=RenderSpec)
    sky: SkySpec = field(default_factory=SkySpec)
    capture: CaptureSpec = field(default_factory=CaptureSpec)
    backdrop: BackdropSpec = field(default_factory=BackdropSpec)

    def __post_init__(self) -> None:
        _check_finite(self, "")
        if not self.name or not self.name.replace("_", "").replace("-", "").isalnum():
            raise ValueError(f"name: must be a non-empty word (letters, digits, _ or -), got {self.name!r}")
        if not self.domain:
            base = self.name[len("train_") :] if self.name.startswith("train_") else self.name
            self.domain = f"synth_{base}"
        if not self.domain.replace("_", "").replace("-", "").isalnum():
            raise ValueError(f"domain: must be a word usable as a folder name, got {self.domain!r}")
        if self.seed < 0:
            raise ValueError(f"seed: must be >= 0, got {self.seed}")
        # Rows intersect when the trunk lines (plus jitter) of neighbouring rows can touch.
        trunk_clearance = 2 * (self.plants.trunk_radius[1] + 3 * self.rows.lateral_jitter)
        if self.rows.spacing <= trunk_clearance:
            raise ValueError(
                f"rows.spacing: {self.rows.spacing} m is too small, neighbouring rows would intersect "
                f"(trunks and jitter need > {trunk_clearance:.2f} m)"
            )
        free = self.free_gap_width
        if free <= MIN_GAP_WIDTH:
            raise ValueError(
                f"rows.spacing: {self.rows.spacing} m leaves a free gap of {free:.2f} m between the rows "
                f"(canopy and trunks subtracted); the robot needs more than {MIN_GAP_WIDTH} m"
            )
        self._check_levers()
        if (
            self.structures.pergola
            and self.structures.free_band_width / 2 + abs(self.structures.free_band_offset) >= self.rows.spacing / 2
        ):
            raise ValueError(
                "structures.free_band_width: the free band (with its offset) must fit between the rows "
                f"({self.structures.free_band_width} + 2*{abs(self.structures.free_band_offset)} >= {self.rows.spacing})"
            )

    def _check_levers(self) -> None:
        """Data-engine levers that only make sense for some fields: say which key is wrong and why."""
        nets, plants = self.structures.nets, self.plants
        if nets.probability > 0:
            top = max(plants.height[1], self.structures.pergola_height if self.structures.pergola else 0.0)
            if nets.height[0] < top + NET_CLEARANCE - 1e-9:  # 3.1 + 0.2 is a hair above 3.3
                raise ValueError(
                    f"structures.nets.height: {list(nets.height)} must clear the plants' top {top} m by "
                    f"{NET_CLEARANCE} m, or the net would cut through the canopy"
                )
        if plants.dormant_probability > 0 and self.crop != "vineyard":
            raise ValueError(f"plants.dormant_probability: dormant canes are built for vineyards, not {self.crop!r}")

    @property
    def free_gap_width(self) -> float:
        """Free width of a gap at the robot's height: spacing minus what reaches in from both rows.

        Hedge crops (vineyard, pear) fill the gap from the canopy down; trees and pergolas
        leave the trunk line (plus jitter and low branches) as the obstacle at robot height.
        """
        p, r = self.plants, self.rows
        if self.crop in ("vineyard", "pear"):
            reach = 0.5 * p.canopy_width[1]
        else:
            reach = p.trunk_radius[1] + 2 * r.lateral_jitter
            if p.low_branches[1] > 0:
                reach += p.low_branch_reach
        return r.spacing - 2 * reach

    @property
    def n_gaps(self) -> int:
        return self.rows.count - 1

    @property
    def eval_gap(self) -> int:
        """Index of the gap a closed-loop run drives through (the middle one by default)."""
        return self.rows.eval_gap if self.rows.eval_gap >= 0 else (self.rows.count - 1) // 2


def load_world_spec(name_or_path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> WorldSpec:
    """Load and validate a world spec (a shipped name or a YAML path); errors name the file and the field."""
    new_name = RENAMED_WORLDS.get(str(name_or_path))
    if new_name is not None:
        log.warning("world %s is now called %s; the old name goes in the next release", name_or_path, new_name)
        name_or_path = new_name
    path = resolve_config("worlds", name_or_path)
    raw = apply_overrides(read_yaml(path), list(overrides))
    return from_dict(WorldSpec, raw, where=str(path))


def spec_from_dict(raw: dict, overrides: list[str] | tuple[str, ...] = (), where: str = "world") -> WorldSpec:
    """Build a spec from a mapping (tests, programmatic worlds)."""
    return from_dict(WorldSpec, apply_overrides(raw, list(overrides)), where=where)


def pergola_reach(spec: WorldSpec) -> tuple[float, float]:
    """(right, left) reach of a pergola row's canopy towards the gaps on each side (m)."""
    s = spec.structures
    half = spec.rows.spacing / 2
    left = half + s.free_band_offset - s.free_band_width / 2  # towards the gap on the left
    right = half - s.free_band_offset - s.free_band_width / 2  # towards the gap on the right
    return max(right, 0.0), max(left, 0.0)


__all__ = [
    "GROUND_STYLE_NAMES",
    "MAX_NET_HEIGHT",
    "MAX_POLYLINE_FOLD",
    "MIN_GAP_WIDTH",
    "NET_COLOUR_NAMES",
    "POST_STYLE_NAMES",
    "RENAMED_WORLDS",
    "TEST_FIELDS",
    "AppearanceSpec",
    "BackdropSpec",
    "CaptureSpec",
    "NetsSpec",
    "PlantsSpec",
    "RenderSpec",
    "RowsSpec",
    "SkySpec",
    "StructuresSpec",
    "TerrainSpec",
    "WorldSpec",
    "load_world_spec",
    "pergola_reach",
    "spec_from_dict",
]
