"""Anti-hail nets over the rows: strands in depth, never vegetation, and the shade they cast.

A net is a sheet over the whole field or a strip over single rows (`structures.nets`), its ridges
over the row lines at the net height, sagging between them, sometimes hanging down the sides.
It is drawn as a grid of thin opaque strands: neither renderer blends, and a mesh finer than a
pixel then reads as a veil of the net's colour over the sky. Strands face down (the camera is
under them) but are shaded with an upward normal, as light comes through a real net from above.

Nets take 10-30 % of the light. Both renderers light a scene with one sun and one ambient term
for everything, so the shade is applied to the rendered frame instead: every pixel whose point
(from planar depth and the camera pose) lies under the net is darkened (`shade_under_nets`). The
sky seen through the net keeps its brightness, which is what makes canopy under nets look dark.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from segmin.data.synth.mesh import Mesh, ribbons

if TYPE_CHECKING:  # world.py and render.py import this module: their types stay unnamed here
    from segmin.data.synth.camera import CameraModel
    from segmin.data.synth.spec import WorldSpec

# Grey level of each net colour (times the near-white plain texture), before per-episode tints.
NET_GREY = {"black": (0.05, 0.12), "grey": (0.3, 0.5), "white": (0.8, 0.95)}
ALONG_PIECE = 1.0  # strands along the rows in pieces this long (TinyRenderer scans each triangle's box)
ACROSS_PIECE = 0.4  # strands across the rows in pieces this long: they follow the sag
SHADE_CELL = 0.1  # resolution of the height map that says what lies under the net (m)
END_MARGIN = 0.5  # the net runs this far beyond the row ends (onto the end posts)
DOWN, UP = np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])  # strands face down, lit from above


@dataclass
class NetShade:
    """Where the net is, as a height map over the ground plane, and how much light it takes."""

    origin: np.ndarray  # (x, y) of cell (0, 0)
    height: np.ndarray  # (nx, ny) world z of the net; NaN where there is none
    dimming: float

    def under(self, points: np.ndarray) -> np.ndarray:
        """Which world points (..., 3) lie under the net (a few centimetres below it, so the
        strands themselves keep their light)."""
        ij = np.floor((points[..., :2] - self.origin) / SHADE_CELL).astype(np.int64)
        nx, ny = self.height.shape
        inside = (ij[..., 0] >= 0) & (ij[..., 0] < nx) & (ij[..., 1] >= 0) & (ij[..., 1] < ny)
        top = np.full(points.shape[:-1], np.nan)
        top[inside] = self.height[ij[inside, 0], ij[inside, 1]]
        with np.errstate(invalid="ignore"):
            return points[..., 2] < top - 0.05


@dataclass
class NetPlan:
    """One world's draw of `structures.nets`: the lateral spans covered and the net's looks."""

    spans: list[tuple[float, float]]  # (low, high) lateral offsets from the reference line
    ridge: float
    sag: float
    spacing: float
    width: float
    drapes: bool
    grey: float
    dimming: float


def plan_nets(spec: WorldSpec, offsets: np.ndarray, rng: np.random.Generator) -> NetPlan | None:
    """Draw whether this world has nets and how they look; None without."""
    ns = spec.structures.nets
    if ns.probability <= 0 or rng.uniform() >= ns.probability:
        return None
    half = 0.5 * spec.rows.spacing
    if rng.uniform() < ns.field_probability:
        spans = [(float(offsets[0] - half), float(offsets[-1] + half))]
    else:  # strips over single rows, each a little narrower than the row spacing
        covered = rng.uniform(size=len(offsets)) < ns.row_probability
        covered[int(rng.integers(len(offsets)))] = True
        w = half * rng.uniform(0.6, 0.9)
        spans = [(float(o - w), float(o + w)) for o, c in zip(offsets, covered) if c]
    colour = ns.colours[int(rng.integers(len(ns.colours)))]
    return NetPlan(
        spans=spans,
        ridge=float(rng.uniform(*ns.height)),
        sag=float(rng.uniform(*ns.sag)),
        spacing=float(rng.uniform(*ns.strand_spacing)),
        width=float(rng.uniform(*ns.strand_width)),
        drapes=bool(rng.uniform() < ns.drape_probability),
        grey=float(rng.uniform(*NET_GREY[colour])),
        dimming=float(rng.uniform(*ns.dimming)),
    )


def _lift(plan: NetPlan, lateral: np.ndarray, row_spacing: float) -> np.ndarray:
    """Net height above the ground at lateral offsets: ridges over the row lines, sagging between
    (row lines lie at multiples of the spacing from the outer row, hence the phase)."""
    phase = 2 * np.pi * lateral / row_spacing
    return plan.ridge - plan.sag * 0.5 * (1 - np.cos(phase))


def _points(plan, layout, terrain, s: np.ndarray, lateral: np.ndarray, phase0: float, spacing):
    """World points of the net surface at arclengths `s` and lateral offsets (same shapes)."""
    xy, _ = layout.at(s.reshape(-1), lateral.reshape(-1))
    z = terrain.height(xy[:, 0], xy[:, 1]) + _lift(plan, lateral.reshape(-1) - phase0, spacing)
    return np.column_stack([xy, z])


def net_meshes(spec: WorldSpec, layout, terrain, plan: NetPlan, coarse: bool) -> dict[tuple[int, int, int], Mesh]:
    """The strands of the net (and its drapes) keyed by (piece along the rows, span, band across
    them one row spacing wide): culling units, small enough for levels of detail to matter.

    The mesh is rectangular, like a real net's (across strands twice as far apart as the strands
    along the rows). `coarse`: the far level of detail, half as many strands, twice as wide."""
    step = plan.spacing * (2 if coarse else 1)
    width = plan.width * (2 if coarse else 1)
    s0, s1 = -END_MARGIN, spec.rows.length + END_MARGIN
    phase0, rs = float(layout.offsets[0]), spec.rows.spacing
    chunk = spec.render.chunk_length
    out: dict[tuple[int, int, int], list[Mesh]] = {}
    for k, (lo, hi) in enumerate(plan.spans):

        def band(lateral: np.ndarray, lo: float = lo) -> np.ndarray:
            return np.floor((lateral - lo) / rs).astype(int)

        along = (s0, s1, phase0, rs, chunk)
        lat = np.arange(lo, hi + 1e-9, step)
        _along(out, k, plan, layout, terrain, lat, band(lat), width, along)
        # Ridge cables over the row lines: three strands wide, what a real net shows most of.
        ridges = layout.offsets[(layout.offsets >= lo) & (layout.offsets <= hi)]
        if len(ridges):
            _along(out, k, plan, layout, terrain, ridges, band(ridges), 3 * width, along)
        # Strands across the rows: constant arclength, pieces of ACROSS_PIECE following the sag.
        ss = np.arange(s0, s1 + 1e-9, 2 * step)
        lat = np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / ACROSS_PIECE)) + 1))
        grid_s, grid_l = np.meshgrid(ss, lat, indexing="ij")
        pts = _points(plan, layout, terrain, grid_s, grid_l, phase0, rs).reshape(len(ss), len(lat), 3)
        a, b = pts[:, :-1].reshape(-1, 3), pts[:, 1:].reshape(-1, 3)
        bands = np.tile(band(0.5 * (lat[:-1] + lat[1:])), len(ss))
        _add(out, (k, bands), np.repeat(ss, len(lat) - 1), chunk, ribbons(a, b, width, DOWN, UP))
        if plan.drapes:
            for side in (lo, hi):
                edge = int(band(np.array([min(side, hi - 1e-6)]))[0])
                _drape(out, (k, edge), plan, layout, terrain, side, (s0, s1), step, width, chunk, phase0, rs)
    return {key: Mesh.concat(parts) for key, parts in out.items()}


def _along(out: dict, span: int, plan, layout, terrain, lateral: np.ndarray, bands: np.ndarray, width, along) -> None:
    """Strands along the rows at constant lateral offsets (in `bands`), in pieces of ALONG_PIECE;
    `along` is (first arclength, last arclength, lateral phase of the ridges, row spacing, chunk length)."""
    s0, s1, phase0, rs, chunk = along
    ss = np.linspace(s0, s1, max(2, int(np.ceil((s1 - s0) / ALONG_PIECE)) + 1))
    grid_s, grid_l = np.meshgrid(ss, lateral, indexing="ij")
    pts = _points(plan, layout, terrain, grid_s, grid_l, phase0, rs).reshape(len(ss), len(lateral), 3)
    a, b = pts[:-1].reshape(-1, 3), pts[1:].reshape(-1, 3)
    mid_s = np.repeat(0.5 * (ss[:-1] + ss[1:]), len(lateral))
    _add(out, (span, np.tile(bands, len(ss) - 1)), mid_s, chunk, ribbons(a, b, width, DOWN, UP))


def _add(out: dict, where: tuple, s: np.ndarray, chunk: float, mesh: Mesh) -> None:
    """Sort the ribbons of `mesh` (4 vertices and 6 indices each) into culling units by their
    arclength `s` and `where` = (span, band across the rows: one for all or one per ribbon)."""
    span, band = where
    keys = np.column_stack([np.floor(s / chunk).astype(int), np.broadcast_to(band, s.shape)])
    for key in np.unique(keys, axis=0):
        pick = np.nonzero((keys == key).all(axis=1))[0]
        verts = (pick[:, None] * 4 + np.arange(4)).reshape(-1)
        idx = mesh.indices.reshape(-1, 6)[pick] - (pick * 4)[:, None] + (np.arange(len(pick)) * 4)[:, None]
        part = Mesh(mesh.vertices[verts], mesh.normals[verts], mesh.uvs[verts], idx.reshape(-1))
        out.setdefault((int(key[0]), span, int(key[1])), []).append(part)


def _drape(out, where, plan, layout, terrain, lateral, s_range, step, width, chunk, phase0, rs) -> None:
    """A side curtain from the net's edge down to a metre above the ground, seen from both sides
    (from the gap beside a strip, or from inside a field net); `where` = (span, band)."""
    s0, s1 = s_range
    top = float(_lift(plan, np.array([lateral - phase0]), rs)[0])
    heights = np.arange(1.0, top + 1e-9, step)
    if len(heights) < 2:
        return
    ss = np.linspace(s0, s1, max(2, int(np.ceil((s1 - s0) / ALONG_PIECE)) + 1))
    cols = np.arange(s0, s1 + 1e-9, 2 * step)
    pieces = []
    for stations, rows in ((ss, heights), (cols, heights[[0, -1]])):
        xy, t = layout.at(stations, lateral)
        ground = terrain.height(xy[:, 0], xy[:, 1])
        grid = np.stack([np.column_stack([xy, ground + h]) for h in rows], axis=1)  # station, height, 3
        across = np.column_stack([-t[:, 1], t[:, 0], np.zeros(len(stations))])
        if rows is heights:  # horizontal strands between stations
            a, b, s = grid[:-1].reshape(-1, 3), grid[1:].reshape(-1, 3), np.repeat(stations[:-1], len(rows))
            facing = np.repeat(across[:-1], len(rows), axis=0)
        else:  # vertical strands at each station
            a, b, s, facing = grid[:, 0], grid[:, 1], stations, across
        pieces.append((a, b, s, facing))
    for a, b, s, facing in pieces:
        for sign in (1.0, -1.0):
            _add(out, where, s, chunk, ribbons(a, b, width, sign * facing, UP))


def net_shade(spec: WorldSpec, layout, terrain, plan: NetPlan) -> NetShade:
    """The net's height over a grid of SHADE_CELL cells, from a lattice twice as fine over its surface."""
    s = np.arange(-END_MARGIN, spec.rows.length + END_MARGIN, SHADE_CELL / 2)
    points = []
    for a, b in plan.spans:
        lat = np.arange(a, b, SHADE_CELL / 2)
        grid_s, grid_l = np.meshgrid(s, lat, indexing="ij")
        points.append(_points(plan, layout, terrain, grid_s, grid_l, float(layout.offsets[0]), spec.rows.spacing))
    pts = np.concatenate(points)
    origin = pts[:, :2].min(axis=0) - SHADE_CELL
    ij = np.floor((pts[:, :2] - origin) / SHADE_CELL).astype(np.int64)
    height = np.full(tuple(ij.max(axis=0) + 2), -np.inf)
    np.maximum.at(height, (ij[:, 0], ij[:, 1]), pts[:, 2])
    height[np.isinf(height)] = np.nan
    return NetShade(origin=origin, height=height, dimming=plan.dimming)


def shade_under_nets(frame, shade: NetShade | None, camera: CameraModel) -> None:
    """Darken, in place, the pixels of a RenderedFrame whose points lie under the net of `shade`
    (a world's `net_shade`; None: nothing to do)."""
    if shade is None:
        return
    v, u = np.nonzero(frame.depth > 0)
    if not len(v):
        return
    k, pose, z = camera.intrinsics(), frame.camera_pose, frame.depth[v, u]
    local = np.column_stack([(u - k["cx"]) / k["fx"] * z, (v - k["cy"]) / k["fy"] * z, z])  # camera frame
    under = shade.under(local @ pose[:3, :3].T + pose[:3, 3])
    v, u = v[under], u[under]
    frame.rgb[v, u] = (frame.rgb[v, u] * (1.0 - shade.dimming)).astype(np.uint8)
