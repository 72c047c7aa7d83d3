"""Build a field from a WorldSpec into a pybullet client, with its ground truth.

World frame: z up, metres, rows run along +x from the entrance near x = `rows.start_x`. Row i
(0 = rightmost, lowest y) lies at lateral offset `(i - (count-1)/2) * spacing` from a reference
line; gap g lies between rows g and g+1. Curved rows are concentric offsets of a curved
reference line, so they never intersect (the spec checks the radius).

Geometry is grouped into chunks (plants and structures of one row within `render.chunk_length`,
ground tiles) with one body per level of detail; the renderer hides chunks the camera cannot
see by setting their alpha to 0, which TinyRenderer skips.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pybullet as p

from segmin.data.synth.backdrop import backdrop_meshes, row_end_meshes
from segmin.data.synth.mesh import Mesh, blades, cylinders, grid_surface
from segmin.data.synth.nets import NetShade, net_meshes, net_shade, plan_nets
from segmin.data.synth.plants import LOD_FACTORS, Plant, make_plant
from segmin.data.synth.posts import END_POST_FACTOR, RADIUS_FACTOR, PostLook, anchor, post_looks, post_mesh
from segmin.data.synth.spec import WorldSpec
from segmin.data.synth.textures import TextureSet

CENTRELINE_STEP = 0.1  # metres between centreline points
GROUND_TILE = 6.0


class Terrain:
    """Analytic uneven ground: a sum of random plane waves plus a constant slope."""

    def __init__(self, spec: WorldSpec, rng: np.random.Generator, n_waves: int = 6) -> None:
        ts = spec.terrain
        shortest, longest = ts.wavelength
        lam = rng.uniform(shortest, longest, size=n_waves)
        theta = rng.uniform(0, 2 * np.pi, size=n_waves)
        self.k = np.stack([np.cos(theta), np.sin(theta)], axis=1) * (2 * np.pi / lam)[:, None]
        self.phase = rng.uniform(0, 2 * np.pi, size=n_waves)
        self.amp = np.full(n_waves, ts.roughness / np.sqrt(n_waves / 2))
        self.slope = np.asarray(ts.slope, float)

    def height(self, x, y):
        x, y = np.asarray(x, float), np.asarray(y, float)
        arg = x[..., None] * self.k[:, 0] + y[..., None] * self.k[:, 1] + self.phase
        return (self.amp * np.sin(arg)).sum(-1) + self.slope[0] * x + self.slope[1] * y

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        x, y = np.asarray(x, float), np.asarray(y, float)
        arg = x[..., None] * self.k[:, 0] + y[..., None] * self.k[:, 1] + self.phase
        c = self.amp * np.cos(arg)
        return (c * self.k[:, 0]).sum(-1) + self.slope[0], (c * self.k[:, 1]).sum(-1) + self.slope[1]

    def normal(self, x, y) -> np.ndarray:
        gx, gy = self.gradient(x, y)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


class RowLayout:
    """The reference line (dense polyline with arclength) and the lateral offsets of the rows."""

    def __init__(self, spec: WorldSpec, extend: float) -> None:
        rs = spec.rows
        self.length = rs.length
        self.offsets = (np.arange(rs.count) - (rs.count - 1) / 2) * rs.spacing
        s = np.arange(-extend, rs.length + extend + 1e-9, CENTRELINE_STEP / 2)
        if rs.polyline:
            xy = self._resample(np.asarray(rs.polyline, float), s)
        else:
            heading = np.zeros_like(s)
            if rs.curve_radius != 0:
                bend = np.clip(s - rs.curve_start, 0, rs.length - rs.curve_start)
                heading = bend / rs.curve_radius
            ds = np.diff(s, prepend=s[0])
            x = np.cumsum(np.cos(heading) * ds)
            y = np.cumsum(np.sin(heading) * ds)
            i0 = int(np.argmin(np.abs(s)))
            xy = np.stack([x - x[i0] + rs.start_x, y - y[i0]], axis=1)
        self.s = s
        self.xy = xy
        tangent = np.gradient(xy, s, axis=0)
        self.tangent = tangent / np.linalg.norm(tangent, axis=1, keepdims=True)
        self.left = np.stack([-self.tangent[:, 1], self.tangent[:, 0]], axis=1)

    @staticmethod
    def _resample(poly: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Polyline by arclength from its first point, extended straight at both ends."""
        seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        t0 = (poly[1] - poly[0]) / seg[0]
        t1 = (poly[-1] - poly[-2]) / seg[-1]
        out = np.stack([np.interp(s, cum, poly[:, 0]), np.interp(s, cum, poly[:, 1])], axis=1)
        before, after = s < 0, s > cum[-1]
        out[before] = poly[0] + s[before, None] * t0
        out[after] = poly[-1] + (s[after, None] - cum[-1]) * t1
        return out

    def at(self, s: np.ndarray, offset: float | np.ndarray = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Points at arclength `s` of the reference line shifted left by `offset`, and tangents."""
        s = np.atleast_1d(np.asarray(s, float))
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        tx = np.interp(s, self.s, self.tangent[:, 0])
        ty = np.interp(s, self.s, self.tangent[:, 1])
        t = np.stack([tx, ty], axis=1)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        left = np.stack([-t[:, 1], t[:, 0]], axis=1)
        return np.stack([x, y], axis=1) + np.asarray(offset)[..., None] * left, t


@dataclass
class Chunk:
    """One unit of culling: a bounding sphere and the bodies showing it at each level of detail."""

    centre: np.ndarray
    radius: float
    bodies: list[int]  # one pybullet body per level of detail, finest first
    kind: str  # "plants", "structure", "ground", "grass"
    texture: int = -1
    triangles: list[int] = field(default_factory=list)  # per level
    capsule: tuple[np.ndarray, np.ndarray, float] | None = None  # tighter bound for distances
    tint: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)  # colour before per-episode tints
    meshes: list[Mesh] = field(default_factory=list)  # per level, the triangles of `bodies` (other renderers)


@dataclass
class World:
    """A built field in one pybullet client, plus the ground truth evaluation needs."""

    spec: WorldSpec
    client_id: int
    seed: int
    terrain: Terrain
    layout: RowLayout
    plant_circles: np.ndarray
    obstacle_circles: np.ndarray
    centrelines: list[np.ndarray]
    gap_half_widths: list[float]
    gap_offsets: list[float]
    vegetation_ids: set[int]
    chunks: list[Chunk]
    textures: TextureSet
    n_triangles: dict[str, list[int]] = field(default_factory=dict)  # per chunk kind and level
    net_shade: NetShade | None = None  # where an anti-hail net darkens the frame (see nets.shade_under_nets)

    def terrain_height(self, x, y):
        """Ground height at (x, y); scalars give a float, arrays an array."""
        h = self.terrain.height(x, y)
        return float(h) if np.ndim(h) == 0 else h

    def terrain_normal(self, x, y) -> np.ndarray:
        """Unit ground normal at (x, y): shape (3,) for scalars, (..., 3) for arrays."""
        return self.terrain.normal(x, y)

    @property
    def eval_gap(self) -> int:
        """The gap a closed-loop run drives through (middle one unless the spec says otherwise)."""
        return self.spec.eval_gap

    def gap_pose(self, gap: int, s: float) -> tuple[float, float, float]:
        """(x, y, yaw) on gap `gap`'s centreline at arclength `s` from the row entrance."""
        xy, t = self.layout.at(np.array([s]), self.gap_offsets[gap])
        return float(xy[0, 0]), float(xy[0, 1]), float(np.arctan2(t[0, 1], t[0, 0]))


def _gap_geometry(spec: WorldSpec, offsets: np.ndarray) -> tuple[list[float], list[float]]:
    """Lateral offset of each gap's centreline and half its free width at ground level."""
    mids = [(offsets[g] + offsets[g + 1]) / 2 for g in range(spec.n_gaps)]
    clearance = spec.plants.trunk_radius[1] + 2 * spec.rows.lateral_jitter
    if spec.structures.pergola:
        band = spec.structures.free_band_offset
        centres = [m + band for m in mids]
    else:
        centres = mids
    half = [min(c - offsets[g], offsets[g + 1] - c) - clearance for g, c in enumerate(centres)]
    if spec.crop in ("vineyard", "pear"):  # the hedge, not the trunk line, bounds the free width
        half = [h - 0.5 * spec.plants.canopy_width[0] + clearance for h in half]
    return centres, [max(float(h), 0.1) for h in half]


def _body(client: int, mesh: Mesh, rgba=(1, 1, 1, 1), texture: int = -1) -> int:
    vs = p.createVisualShape(
        p.GEOM_MESH,
        vertices=mesh.vertices.tolist(),
        indices=mesh.indices.astype(int).tolist(),
        normals=mesh.normals.tolist(),
        uvs=mesh.uvs.tolist(),
        rgbaColor=list(rgba),
        physicsClientId=client,
    )
    if vs < 0:
        raise RuntimeError("pybullet refused a visual mesh")
    body = p.createMultiBody(baseMass=0, baseCollisionShapeIndex=-1, baseVisualShapeIndex=vs, physicsClientId=client)
    if texture >= 0:
        p.changeVisualShape(body, -1, textureUniqueId=texture, physicsClientId=client)
    return body


def _chunk(
    client: int, levels: list[Mesh], kind: str, texture: int, rgba: tuple[float, float, float, float] = (1, 1, 1, 1)
) -> Chunk:
    levels = [m for m in levels if m.n_triangles]
    centre, radius = levels[0].bounding_sphere()
    bodies = [_body(client, m, rgba, texture) for m in levels]
    return Chunk(
        centre=centre,
        radius=radius,
        bodies=bodies,
        kind=kind,
        texture=texture,
        triangles=[m.n_triangles for m in levels],
        capsule=levels[0].bounding_capsule(),
        tint=(float(rgba[0]), float(rgba[1]), float(rgba[2]), float(rgba[3])),
        meshes=levels,
    )


def build_world(spec: WorldSpec, client_id: int, seed: int | None = None) -> World:
    """Build `spec` into the (DIRECT) pybullet client `client_id`; `seed` overrides `spec.seed`.

    Each part draws from a random stream of its own (terrain, plants, structures, textures,
    ground, backdrop, nets, row weeds, row ends, gap grass), so a change to one part of a spec leaves
    the others as they were. Parts added later come last: a world without them keeps its bodies, and
    so its frames, byte for byte.
    """
    seed = spec.seed if seed is None else int(seed)
    rng_terrain, rng_plants, rng_struct, rng_tex, rng_ground = (np.random.default_rng([seed, k]) for k in range(5))
    terrain = Terrain(spec, rng_terrain)
    layout = RowLayout(spec, extend=spec.terrain.margin + GROUND_TILE)
    textures = TextureSet(client_id, spec.appearance, rng_tex)
    n_chunks = int(np.ceil(spec.rows.length / spec.render.chunk_length)) + 1
    plants, circles = _place_plants(spec, layout, terrain, rng_plants)

    chunks: list[Chunk] = []
    tris = {"plants": [0] * len(LOD_FACTORS), "structure": [0], "ground": [0, 0], "grass": [0]}
    vegetation = _plant_chunks(spec, plants, client_id, textures, chunks, tris)
    obstacles = _structures(spec, layout, terrain, rng_struct, client_id, textures, chunks, n_chunks, tris)
    _ground(spec, layout, terrain, rng_ground, client_id, textures, chunks, tris)
    _backdrop(spec, layout, terrain, np.random.default_rng([seed, 5]), client_id, textures, chunks, tris)
    shade = _nets(spec, layout, terrain, np.random.default_rng([seed, 6]), client_id, textures, chunks, tris)
    _row_weeds(spec, layout, terrain, np.random.default_rng([seed, 7]), client_id, textures, chunks, tris)
    _row_ends(spec, layout, terrain, np.random.default_rng([seed, 8]), client_id, textures, chunks, tris)
    _gap_grass(spec, layout, terrain, np.random.default_rng([seed, 9]), client_id, textures, chunks, tris)

    centre_offsets, half_widths = _gap_geometry(spec, layout.offsets)
    s_line = np.arange(0.0, spec.rows.length + 1e-9, CENTRELINE_STEP)
    return World(
        spec=spec,
        client_id=client_id,
        seed=seed,
        terrain=terrain,
        layout=layout,
        plant_circles=np.array(circles, float).reshape(-1, 3),
        obstacle_circles=np.array(obstacles, float).reshape(-1, 3),
        centrelines=[layout.at(s_line, c)[0] for c in centre_offsets],
        gap_half_widths=half_widths,
        gap_offsets=list(map(float, centre_offsets)),
        vegetation_ids=vegetation,
        chunks=chunks,
        textures=textures,
        n_triangles=tris,
        net_shade=shade,
    )


def _place_plants(
    spec: WorldSpec, layout: RowLayout, terrain: Terrain, rng: np.random.Generator
) -> tuple[dict[tuple[int, int], list[Plant]], list[tuple[float, float, float]]]:
    """The plants, row by row, keyed by chunk (row, index along the row), and each one's trunk
    circle (x, y, radius)."""
    rs, ps = spec.rows, spec.plants
    chunk_len = spec.render.chunk_length
    plants: dict[tuple[int, int], list[Plant]] = {}
    circles = []
    for row, offset in enumerate(layout.offsets):
        s = 0.25 * ps.spacing * rng.uniform()
        while s <= rs.length:
            pos_s = s + rng.uniform(-ps.spacing_jitter, ps.spacing_jitter)
            present = rng.uniform() >= ps.gap_probability
            lateral = offset + rng.normal(0, rs.lateral_jitter) if rs.lateral_jitter > 0 else offset
            if present and 0 <= pos_s <= rs.length:
                xy, t = layout.at(np.array([pos_s]), lateral)
                base = np.array([xy[0, 0], xy[0, 1], terrain.height(xy[0, 0], xy[0, 1])])
                plant = make_plant(spec, rng, base, t[0], row)
                plants.setdefault((row, int(pos_s // chunk_len)), []).append(plant)
                circles.append((base[0], base[1], plant.trunk_radius))
            s += ps.spacing
    return plants, circles


def _plant_chunks(
    spec: WorldSpec,
    plants: dict[tuple[int, int], list[Plant]],
    client: int,
    textures: TextureSet,
    chunks: list[Chunk],
    tris: dict[str, list[int]],
) -> set[int]:
    """One chunk per row piece (two with the canopy label: leaves and wood), appended to `chunks`;
    returns the bodies that are vegetation (1 in the mask).

    Creation order is TinyRenderer's drawing order, and a pixel already covered by something
    nearer skips shading: inner rows first (they hide the outer ones from the middle gaps),
    then along each row from the entrance.
    """
    vegetation: set[int] = set()
    middle = (spec.rows.count - 1) / 2
    canopy_only = spec.plants.label == "canopy"
    if canopy_only:
        tris["wood"] = [0] * len(LOD_FACTORS)
    for key in sorted(plants, key=lambda k: (abs(k[0] - middle), k[0], k[1])):
        if not canopy_only:  # one body per level: leaves and wood are both vegetation
            levels = [Mesh.concat([pl.mesh(level) for pl in plants[key]]) for level in range(len(LOD_FACTORS))]
            kinds = [("plants", levels)]
        else:  # leaves (vegetation) and wood (trunks, cordons, shoots: 0 in the mask) apart
            parts = [[pl.mesh_parts(level) for pl in plants[key]] for level in range(len(LOD_FACTORS))]
            kinds = [
                ("plants", [Mesh.concat([lv for lv, _ in lvl]) for lvl in parts]),
                ("wood", [Mesh.concat([wd for _, wd in lvl]) for lvl in parts]),
            ]
        for kind, levels in kinds:  # leaves first: they hide most of the wood (hidden pixels skip shading)
            if not any(m.n_triangles for m in levels):
                continue
            ch = _chunk(client, levels, kind, textures.plant[0])
            chunks.append(ch)
            if kind == "plants":
                vegetation.update(ch.bodies)
            tris[kind] = [
                a + b for a, b in zip(tris[kind], ch.triangles + [0] * (len(LOD_FACTORS) - len(ch.triangles)))
            ]
    return vegetation


def _backdrop(spec, layout, terrain, rng, client, textures, chunks, tris) -> None:
    """Trees, hedges, buildings and hills around the field: scenery, not vegetation in the mask."""
    tris["backdrop"] = [0]
    for kind, mesh, texture, tint in backdrop_meshes(spec, layout, terrain, rng, textures):
        if mesh.n_triangles:  # not vegetation, whatever its leaves look like
            chunks.append(_chunk(client, [mesh], kind, texture, tint))
            tris["backdrop"][0] += mesh.n_triangles


def _wire_stations(s0: float, s1: float, step: float = 1.0) -> np.ndarray:
    """Short wire pieces: TinyRenderer scans each triangle's screen bounding box, so one long
    diagonal wire costs as much as a full-screen quad; short pieces keep the boxes small."""
    return np.linspace(s0, s1, max(2, int(np.ceil((s1 - s0) / step)) + 1))


def _structures(
    spec, layout, terrain, rng, client, textures, chunks, n_chunks, tris
) -> list[tuple[float, float, float]]:
    """Poles and wires (vineyards), posts, beams and wires (pergola): obstacles, not vegetation."""
    st, rs = spec.structures, spec.rows
    chunk_len = spec.render.chunk_length
    obstacles: list[tuple[float, float, float]] = []  # (x, y, radius) of each pole or post
    parts: dict[int, list[Mesh]] = {}
    if not (st.poles or st.pergola):
        return obstacles
    pole_s = np.arange(0.0, rs.length + 1e-6, st.pole_spacing)
    if pole_s[-1] < rs.length - 0.5:
        pole_s = np.append(pole_s, rs.length)
    looks = post_looks(st.post_styles, st.square_probability, rng) if st.post_styles else {}
    styled: dict[tuple[int, str], list[Mesh]] = {}
    for offset in layout.offsets:
        _row_posts(spec, layout, terrain, rng, offset, pole_s, looks, parts, styled, obstacles)
        # Wires between consecutive poles (thin triangular prisms).
        for h in [] if st.pergola else st.wire_heights:
            lo, hi = st.wire_radius
            radius = rng.uniform(lo, hi) if hi > lo else lo
            for k in range(len(pole_s) - 1):
                ss = _wire_stations(pole_s[k], pole_s[k + 1])
                wxy, _ = layout.at(ss, offset)
                wz = terrain.height(wxy[:, 0], wxy[:, 1]) + h
                pts = np.column_stack([wxy, wz])
                parts.setdefault(int(pole_s[k] // chunk_len), []).append(
                    cylinders(pts[:-1], pts[1:], radius, radius, 3)
                )
    if st.pergola:
        # Cross beams over every gap at each pole station and wires along the rows overhead.
        for g in range(len(layout.offsets) - 1):
            for s in pole_s:
                a, _ = layout.at(np.array([s]), layout.offsets[g])
                b, _ = layout.at(np.array([s]), layout.offsets[g + 1])
                za = terrain.height(a[0, 0], a[0, 1]) + st.pergola_height
                zb = terrain.height(b[0, 0], b[0, 1]) + st.pergola_height
                parts.setdefault(int(s // chunk_len), []).append(
                    cylinders(np.array([a[0, 0], a[0, 1], za]), np.array([b[0, 0], b[0, 1], zb]), 0.035, 0.035, 4)
                )
        wire_offsets = []
        for off in layout.offsets:
            wire_offsets += [off - 1.0, off, off + 1.0]
        for off in wire_offsets:
            for k in range(len(pole_s) - 1):
                ss = _wire_stations(pole_s[k], pole_s[k + 1])
                wxy, _ = layout.at(ss, off)
                wz = terrain.height(wxy[:, 0], wxy[:, 1]) + st.pergola_height + 0.03
                pts = np.column_stack([wxy, wz])
                parts.setdefault(int(pole_s[k] // chunk_len), []).append(cylinders(pts[:-1], pts[1:], 0.006, 0.006, 3))
    for key in sorted(parts):
        mesh = Mesh.concat(parts[key])
        tint = (0.9, 0.9, 0.9, 1.0)
        chunks.append(_chunk(client, [mesh], "structure", textures.structure, tint))
        tris["structure"][0] += mesh.n_triangles
    if styled:  # own texture and tint per material: the `backdrop` kind keeps them
        tris["posts"] = [0]
    for (_, style), meshes in sorted(styled.items()):
        mesh = Mesh.concat(meshes)
        texture = textures.structure if style == "wood" else textures.plain()
        chunks.append(_chunk(client, [mesh], "backdrop", texture, looks[style].tint))
        tris["posts"][0] += mesh.n_triangles
    return obstacles


def _row_posts(
    spec, layout, terrain, rng, offset, pole_s, looks: dict[str, PostLook], parts, styled, obstacles
) -> None:
    """The posts of one row: plain poles into `parts`, or with `looks` (varied posts) a material per
    post into `styled[(chunk, material)]`; end posts on anchors with `structures.end_anchor_probability`."""
    st = spec.structures
    chunk_len = spec.render.chunk_length
    top_h = st.pergola_height if st.pergola else st.pole_height
    xy, t = layout.at(pole_s, offset + 0.0)
    z = terrain.height(xy[:, 0], xy[:, 1])
    ends = {0: -1.0, len(pole_s) - 1: 1.0}  # pole index -> direction out of the row along it
    for k, s in enumerate(pole_s):
        lean = rng.normal(0, 0.02, size=2)
        p0 = np.array([xy[k, 0], xy[k, 1], z[k] - 0.2])
        p1 = np.array([xy[k, 0] + lean[0], xy[k, 1] + lean[1], z[k] + top_h])
        key = int(s // chunk_len)
        if k in ends and st.end_anchor_probability > 0 and rng.uniform() < st.end_anchor_probability:
            outward = np.array([t[k, 0], t[k, 1], 0.0]) * ends[k]
            p1 = p1 + outward * rng.uniform(0.1, 0.3)  # pulled outwards by the anchor wire
            parts.setdefault(key, []).extend(anchor(p1, p0, outward, terrain.height, rng))
        if not looks:
            parts.setdefault(key, []).append(cylinders(p0, p1, st.pole_radius, st.pole_radius * 0.9, 5))
            obstacles.append((xy[k, 0], xy[k, 1], st.pole_radius))
            continue
        look = looks[st.post_styles[int(rng.integers(len(st.post_styles)))]]
        radius = rng.uniform(*st.post_radius) * RADIUS_FACTOR[look.style] * (END_POST_FACTOR if k in ends else 1.0)
        styled.setdefault((key, look.style), []).append(post_mesh(p0, p1, radius, look.square))
        obstacles.append((xy[k, 0], xy[k, 1], radius * (np.sqrt(2) if look.square else 1.0)))


def _nets(spec, layout, terrain, rng, client, textures, chunks, tris) -> NetShade | None:
    """Anti-hail nets (`structures.nets`), drawn for this build: strand chunks at two levels of
    detail, and the height map of the shade they cast; None without a net."""
    plan = plan_nets(spec, layout.offsets, rng)
    if plan is None:
        return None
    tris["net"] = [0, 0]
    fine, coarse = (net_meshes(spec, layout, terrain, plan, c) for c in (False, True))
    tint = (plan.grey, plan.grey, plan.grey, 1.0)
    for key in sorted(fine):
        levels = [fine[key], coarse.get(key, fine[key])]
        chunks.append(_chunk(client, levels, "backdrop", textures.plain(), tint))  # own colour: see posts
        tris["net"] = [a + m.n_triangles for a, m in zip(tris["net"], levels)]
    return net_shade(spec, layout, terrain, plan)


def _row_weeds(spec, layout, terrain, rng, client, textures, chunks, tris) -> None:
    """Tall weeds and grass at the row base, up into the canopy band (`terrain.row_weeds`): not
    vegetation in the mask, like grass; drawn to the second level-of-detail distance."""
    ts = spec.terrain
    if ts.row_weeds <= 0:
        return
    tris["weeds"] = [0, 0]
    chunk_len = spec.render.chunk_length
    n_pieces = int(np.ceil(spec.rows.length / chunk_len))
    for offset in layout.offsets:
        for piece in range(n_pieces):
            n = rng.poisson(ts.row_weeds * chunk_len)
            if not n:
                continue
            s = rng.uniform(piece * chunk_len, min((piece + 1) * chunk_len, spec.rows.length), n)
            xy, _ = layout.at(s, offset + rng.uniform(-ts.row_weed_reach, ts.row_weed_reach, n))
            bases = np.column_stack([xy, terrain.height(xy[:, 0], xy[:, 1]) - 0.01])
            heights = rng.uniform(*ts.row_weed_height, n)
            fine = blades(bases, heights, rng, per_tuft=6)
            coarse = blades(bases[: max(1, n // 2)], heights[: max(1, n // 2)], rng, per_tuft=4)
            ch = _chunk(client, [fine, coarse], "grass", textures.grass[0])
            ch.bodies.append(-1)  # beyond the second level-of-detail distance: not drawn
            ch.triangles.append(0)
            chunks.append(ch)
            tris["weeds"] = [a + m.n_triangles for a, m in zip(tris["weeds"], (fine, coarse))]


def _row_ends(spec, layout, terrain, rng, client, textures, chunks, tris) -> None:
    """Dense, dark hedges or tree lines closing the rows' ends (`backdrop.row_end_*`): scenery,
    never vegetation in the mask, right where the navigator looks for the row's vanishing point."""
    if spec.backdrop.row_end_probability <= 0:
        return
    parts = row_end_meshes(spec, layout, terrain, rng)
    if parts:
        tris["row_ends"] = [0]
    for mesh, brightness in parts:
        chunks.append(_chunk(client, [mesh], "backdrop_dark", textures.plant[0], (brightness,) * 3 + (1.0,)))
        tris["row_ends"][0] += mesh.n_triangles


def _gap_grass(spec, layout, terrain, rng, client, textures, chunks, tris) -> None:
    """Lush, bright grass and weeds on the strips the robot drives (`terrain.gap_grass`), from
    before the entrance to past the row ends: at the camera's feet, never vegetation in the mask.
    Patchy like real swards (each piece of strip draws its own density); drawn to the second
    level-of-detail distance."""
    ts = spec.terrain
    if ts.gap_grass <= 0:
        return
    tris["gap_grass"] = [0, 0]
    texture = textures.lush(rng)
    chunk_len = spec.render.chunk_length
    half = 0.45 * spec.rows.spacing
    starts = np.arange(-3.0, spec.rows.length + 3.0, chunk_len)
    for g in range(len(layout.offsets) - 1):
        middle = 0.5 * (layout.offsets[g] + layout.offsets[g + 1])
        for s0 in starts:
            n = rng.poisson(ts.gap_grass * chunk_len * 2 * half * rng.uniform(0.4, 1.6))
            if not n:
                continue
            s = rng.uniform(s0, s0 + chunk_len, n)
            xy, _ = layout.at(s, middle + rng.uniform(-half, half, n))
            bases = np.column_stack([xy, terrain.height(xy[:, 0], xy[:, 1]) - 0.01])
            heights = rng.uniform(*ts.gap_grass_height, n)
            fine = blades(bases, heights, rng, per_tuft=8, lift=2.0)
            coarse = blades(bases[: max(1, n // 3)], heights[: max(1, n // 3)], rng, per_tuft=5, lift=2.0)
            ch = _chunk(client, [fine, coarse], "lush", texture)
            ch.bodies.append(-1)  # beyond the second level-of-detail distance: not drawn
            ch.triangles.append(0)
            chunks.append(ch)
            tris["gap_grass"] = [a + m.n_triangles for a, m in zip(tris["gap_grass"], (fine, coarse))]


def _ground(spec, layout, terrain, rng, client, textures, chunks, tris) -> None:
    """Ground tiles (fine grid + grass tufts near, coarse grid far).

    Beyond the tiles the renderer paints distant ground where a ray points below the horizon
    (cheaper than a huge plane: TinyRenderer scans every triangle's whole bounding box).
    """
    ts = spec.terrain
    pts = np.concatenate([layout.at(layout.s, off)[0] for off in (layout.offsets[0], layout.offsets[-1])])
    lo = pts.min(axis=0) - ts.margin
    hi = pts.max(axis=0) + ts.margin
    nx = int(np.ceil((hi[0] - lo[0]) / GROUND_TILE))
    ny = int(np.ceil((hi[1] - lo[1]) / GROUND_TILE))
    uv_scale = 1.0 / ts.texture_scale
    for i in range(nx):
        for j in range(ny):
            x0, y0 = lo[0] + i * GROUND_TILE, lo[1] + j * GROUND_TILE
            steps = max(2, int(round(GROUND_TILE / ts.resolution)) + 1)
            xs = np.linspace(x0, x0 + GROUND_TILE, steps)
            ys = np.linspace(y0, y0 + GROUND_TILE, steps)
            fine = grid_surface(xs, ys, terrain.height, terrain.normal, uv_scale)
            coarse = grid_surface(
                np.linspace(x0, x0 + GROUND_TILE, 3),
                np.linspace(y0, y0 + GROUND_TILE, 3),
                terrain.height,
                terrain.normal,
                uv_scale,
            )
            chunks.append(_chunk(client, [fine, coarse], "ground", textures.ground[0]))
            tris["ground"][0] += fine.n_triangles
            tris["ground"][1] += coarse.n_triangles
            n_tufts = rng.poisson(ts.grass_tufts * GROUND_TILE**2)
            if n_tufts:  # grass and weeds: not vegetation in the mask; drawn near the camera only
                tx = rng.uniform(x0, x0 + GROUND_TILE, n_tufts)
                ty = rng.uniform(y0, y0 + GROUND_TILE, n_tufts)
                th = rng.uniform(0.08, 0.3, n_tufts)
                grass = blades(np.column_stack([tx, ty, terrain.height(tx, ty) - 0.01]), th, rng)
                ch = _chunk(client, [grass], "grass", textures.grass[0])
                ch.bodies.append(-1)  # beyond the first level-of-detail distance: not drawn
                ch.triangles.append(0)
                chunks.append(ch)
                tris["grass"][0] += grass.n_triangles
