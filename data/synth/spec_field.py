"""The field's shape in a world spec: rows, plants, posts and wires, anti-hail nets, the ground.

Sections of `WorldSpec` (`segmin.data.synth.spec`, where code imports them from); geometry is in
metres and degrees, ranges are `[low, high]` pairs the world builder samples per plant, post or
net. Each section checks its own numbers; what depends on two sections (rows that would touch,
a net through the canopy) `WorldSpec` checks.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Literal

from segmin.common.angles import wrap_angle
from segmin.data.synth.spec_checks import Range, check_fraction, check_names, check_positive, check_range

# Colours of anti-hail nets and materials of posts (their looks: nets.py, posts.py).
NET_COLOUR_NAMES: tuple[str, ...] = ("black", "grey", "white")
POST_STYLE_NAMES: tuple[str, ...] = ("wood", "concrete", "metal")

# Rows are offset lines of the reference polyline, which the world follows point by point
# (linear between vertices). At a vertex turning by theta the offset line at distance h on the
# inner side folds back over itself by 2 h tan(theta / 2): beyond a few centimetres the
# inner rows cross themselves and their neighbours, whatever the segment lengths.
MAX_POLYLINE_FOLD = 0.1
# Upper bounds of amounts that grow a world's triangle count (and memory) without limit: a field of
# 25 m rows holds millions of triangles at these, far past anything a real row shows. Anti-hail nets
# hang 3-7 m up on their posts; 15 m clears the tallest orchard trees a world builds.
MAX_NET_HEIGHT = 15.0
MAX_TUFTS_PER_M2 = 200.0  # grass tufts per square metre: a closed sward
MAX_ROW_WEEDS_PER_M = 50.0  # weed tufts per metre of row: one every 2 cm


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
        check_positive("rows.length", self.length)
        check_positive("rows.spacing", self.spacing)
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
        check_positive("plants.spacing", self.spacing)
        if not 0 <= self.spacing_jitter < 0.5 * self.spacing:
            raise ValueError(f"plants.spacing_jitter: must be within [0, spacing/2), got {self.spacing_jitter}")
        check_fraction("plants.gap_probability", self.gap_probability)
        check_range("plants.height", self.height, strict=True)
        check_range("plants.trunk_height", self.trunk_height, strict=True)
        check_range("plants.trunk_radius", self.trunk_radius, strict=True)
        check_range("plants.canopy_bottom", self.canopy_bottom)
        check_range("plants.canopy_width", self.canopy_width, strict=True)
        check_range("plants.leaf_size", self.leaf_size, strict=True)
        for name in ("clusters", "branches", "low_branches", "hanging_shoots", "upright_shoots", "canes"):
            a, b = getattr(self, name)
            if a < 0 or a > b:
                raise ValueError(f"plants.{name}: need 0 <= low <= high, got [{a}, {b}]")
        if self.clusters[0] < 1:
            raise ValueError(f"plants.clusters: at least one leaf cluster per plant, got {self.clusters}")
        if self.low_branch_reach < 0:
            raise ValueError(f"plants.low_branch_reach: must be >= 0, got {self.low_branch_reach}")
        check_fraction("plants.leaf_density", self.leaf_density)
        check_fraction("plants.sparse_probability", self.sparse_probability)
        check_fraction("plants.dormant_probability", self.dormant_probability)
        check_fraction("plants.dormant_leaves", self.dormant_leaves)
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
            check_fraction(f"structures.nets.{name}", getattr(self, name))
        check_range("structures.nets.height", self.height, strict=True)
        if self.height[1] > MAX_NET_HEIGHT:
            raise ValueError(
                f"structures.nets.height: {list(self.height)} m; anti-hail nets hang at most {MAX_NET_HEIGHT} m up"
            )
        check_range("structures.nets.sag", self.sag)
        if self.sag[1] >= 0.5 * self.height[0]:
            raise ValueError(
                f"structures.nets.sag: {list(self.sag)} must stay below half the net height {self.height[0]}"
            )
        check_names("structures.nets.colours", self.colours, NET_COLOUR_NAMES)
        check_range("structures.nets.strand_spacing", self.strand_spacing, strict=True)
        check_range("structures.nets.strand_width", self.strand_width, strict=True)
        if self.strand_width[1] >= self.strand_spacing[0]:
            raise ValueError(
                f"structures.nets.strand_width: {list(self.strand_width)} must be narrower than the strand "
                f"spacing {list(self.strand_spacing)}"
            )
        check_range("structures.nets.dimming", self.dimming)
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
        check_positive("structures.pole_spacing", self.pole_spacing)
        check_positive("structures.pole_height", self.pole_height)
        check_positive("structures.pole_radius", self.pole_radius)
        for i, h in enumerate(self.wire_heights):
            if not 0 < h <= self.pole_height:
                raise ValueError(f"structures.wire_heights[{i}]: {h} must be within (0, pole_height]")
        if self.pergola:
            check_positive("structures.pergola_height", self.pergola_height)
            check_positive("structures.free_band_width", self.free_band_width)
        if self.post_styles:
            check_names("structures.post_styles", self.post_styles, POST_STYLE_NAMES)
        check_range("structures.post_radius", self.post_radius, strict=True)
        check_fraction("structures.square_probability", self.square_probability)
        check_fraction("structures.end_anchor_probability", self.end_anchor_probability)
        check_range("structures.wire_radius", self.wire_radius, strict=True)


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
        check_range("terrain.wavelength", self.wavelength, strict=True)
        check_positive("terrain.resolution", self.resolution)
        if self.margin < 0:
            raise ValueError(f"terrain.margin: must be >= 0, got {self.margin}")
        check_positive("terrain.texture_scale", self.texture_scale)
        for name in ("grass_tufts", "gap_grass"):
            if not 0 <= getattr(self, name) <= MAX_TUFTS_PER_M2:
                raise ValueError(
                    f"terrain.{name}: tufts per square metre within [0, {MAX_TUFTS_PER_M2:g}], got {getattr(self, name)}"
                )
        if not 0 <= self.row_weeds <= MAX_ROW_WEEDS_PER_M:
            raise ValueError(
                f"terrain.row_weeds: tufts per metre of row within [0, {MAX_ROW_WEEDS_PER_M:g}], got {self.row_weeds}"
            )
        check_range("terrain.gap_grass_height", self.gap_grass_height, strict=True)
        if self.gap_grass_height[1] > 1.0:
            raise ValueError(f"terrain.gap_grass_height: tufts up to 1 m, got {list(self.gap_grass_height)}")
        check_range("terrain.row_weed_height", self.row_weed_height, strict=True)
        if self.row_weed_height[1] > 1.5:
            raise ValueError(f"terrain.row_weed_height: weeds up to 1.5 m, got {list(self.row_weed_height)}")
        if self.row_weed_reach < 0:
            raise ValueError(f"terrain.row_weed_reach: must be >= 0, got {self.row_weed_reach}")
