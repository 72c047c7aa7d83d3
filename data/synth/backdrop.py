"""What stands beyond the field: trees, forest edges, hedges, buildings and hills.

Real rows end in hedges and tree lines, with buildings and hills behind them; a model that only
saw sky beyond the rows paints every tree as crop. These elements are never vegetation in the
mask, even where they carry the crop's own leaf textures: the model has to learn from context
(distance, size, position) what the crop is. A flat band at the horizon taught the opposite of
that (see docs/sim_to_real.md), so every element here has its own 3D shape and size.

Returned as meshes (kind, mesh, texture id, tint); `world.build_world` turns them into chunks of
kind `backdrop_tree` (leaf texture re-drawn per episode) or `backdrop` (own texture and tint).
"""

from __future__ import annotations

import numpy as np

from segmin.data.synth.mesh import Mesh, cylinders, ellipsoid_area, ellipsoid_shell_points, leaves

BackdropPart = tuple[str, Mesh, int, tuple[float, float, float, float]]
TREE_LEAVES = 260  # leaf triangles per backdrop tree at most (they are far: big leaves are fine)
BUILDING_TINTS = ((0.95, 0.93, 0.85), (0.85, 0.55, 0.45), (0.7, 0.7, 0.72), (0.9, 0.8, 0.6))


def _field_box(layout, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box around the outer rows, plus `margin`."""
    pts = np.concatenate([layout.at(layout.s, off)[0] for off in (layout.offsets[0], layout.offsets[-1])])
    inside = (layout.s >= 0) & (layout.s <= layout.length)
    pts = pts[np.concatenate([inside, inside])]
    return pts.min(axis=0) - margin, pts.max(axis=0) + margin


def _around(
    rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, distance: float, side: int | None = None
) -> tuple[np.ndarray, int]:
    """A point `distance` beyond the box edge on `side` (0 = beyond the row ends, 1 = before the
    entrance, 2 = right, 3 = left), spread along that side."""
    side = int(rng.integers(4)) if side is None else side
    span = hi - lo
    if side in (0, 1):
        x = hi[0] + distance if side == 0 else lo[0] - distance
        y = rng.uniform(lo[1] - 0.5 * span[1] - distance, hi[1] + 0.5 * span[1] + distance)
    else:
        y = lo[1] - distance if side == 2 else hi[1] + distance
        x = rng.uniform(lo[0] - 0.3 * span[0], hi[0] + 0.3 * span[0])
    return np.array([x, y]), side


def tree_mesh(rng: np.random.Generator, foot: np.ndarray, height: float, max_leaves: int = TREE_LEAVES) -> Mesh:
    """A broadleaf tree: a trunk and a crown of overlapping ellipsoids covered with leaves."""
    crown_base = height * rng.uniform(0.2, 0.45)
    width = height * rng.uniform(0.35, 0.7)
    trunk_r = 0.03 * height * rng.uniform(0.7, 1.3)
    top = foot + np.array([rng.normal(0, 0.1), rng.normal(0, 0.1), crown_base + 0.3 * (height - crown_base)])
    parts = [cylinders(foot - np.array([0, 0, 0.2]), top, trunk_r, 0.5 * trunk_r, 5)]
    centre = foot + np.array([0, 0, 0.5 * (crown_base + height)])
    radii = np.array([0.5 * width, 0.5 * width, 0.5 * (height - crown_base)])
    clusters = [(centre, radii * 0.8)]
    for _ in range(int(rng.integers(2, 6))):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        clusters.append((centre + d * radii * 0.45, radii * rng.uniform(0.4, 0.65, 3)))
    areas = np.array([ellipsoid_area(r) for _, r in clusters])
    leaf_size = float(np.sqrt(1.6 * areas.sum() / max_leaves))
    pts, out = [], []
    for (c, r), a in zip(clusters, areas):
        n = max(6, int(max_leaves * a / areas.sum()))
        local, outward = ellipsoid_shell_points(c, r, n, rng)
        pts.append(local)
        out.append(outward)
    pts_a, out_a = np.concatenate(pts), np.concatenate(out)
    sizes = leaf_size * rng.uniform(0.8, 1.3, len(pts_a))
    return Mesh.concat([leaves(pts_a, sizes, rng, facing=out_a, up_bias=0.0)] + parts)


def hedge_mesh(rng: np.random.Generator, a: np.ndarray, b: np.ndarray, height: float, terrain) -> Mesh:
    """A continuous hedge from a to b (xy): a chain of leafy ellipsoids."""
    length = float(np.linalg.norm(b - a))
    n = max(2, int(length / 2.0))
    pts, out = [], []
    for k in range(n):
        xy = a + (b - a) * (k + rng.uniform(0.3, 0.7)) / n
        h = height * rng.uniform(0.8, 1.15)
        c = np.array([xy[0], xy[1], float(terrain.height(xy[0], xy[1])) + 0.5 * h])
        r = np.array([0.75 * length / n + 0.3, rng.uniform(0.5, 1.0), 0.55 * h])
        local, outward = ellipsoid_shell_points(c, r, 70, rng)
        pts.append(local)
        out.append(outward)
    pts_a, out_a = np.concatenate(pts), np.concatenate(out)
    return leaves(pts_a, np.full(len(pts_a), 0.4) * rng.uniform(0.8, 1.3, len(pts_a)), rng, facing=out_a, up_bias=0.0)


def building_mesh(rng: np.random.Generator, foot: np.ndarray, height: float) -> tuple[Mesh, Mesh]:
    """(walls, roof): a box (4-sided prism with caps) and a pyramid roof."""
    r = rng.uniform(3.0, 8.0)
    top = foot + np.array([0, 0, height])
    walls = cylinders(foot - np.array([0, 0, 0.5]), top, r, r, 4, caps=True)
    roof = cylinders(top, top + np.array([0, 0, rng.uniform(1.0, 3.0)]), r * 1.1, 0.05, 4, caps=True)
    return walls, roof


def hills_mesh(rng: np.random.Generator, centre: np.ndarray, radius: float, terrain) -> Mesh:
    """A ridge of hills on an arc around the field: varied heights, no flat band."""
    start = rng.uniform(0, 2 * np.pi)
    arc = rng.uniform(1.5, 4.0)
    n = 24
    theta = start + arc * np.arange(n + 1) / n
    profile = np.cumsum(rng.normal(0, 1.0, n + 1))
    profile = (profile - profile.min()) / max(float(np.ptp(profile)), 1e-6)
    heights = rng.uniform(2.0, 5.0) + rng.uniform(2.0, 9.0) * profile
    ring = centre[None, :] + radius * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    ground = np.array([terrain.height(x, y) for x, y in ring]) - 1.0
    lower = np.column_stack([ring, ground])
    upper = np.column_stack([ring, ground + 1.0 + heights])
    verts = np.concatenate([lower, upper])
    inward = -np.column_stack([np.cos(theta), np.sin(theta), np.zeros(n + 1)])
    normals = np.concatenate([inward, inward * 0.5 + np.array([0, 0, 0.5])])
    uvs = np.concatenate([np.column_stack([theta * 4, np.zeros(n + 1)]), np.column_stack([theta * 4, heights / 4])])
    i = np.arange(n)
    # Faces towards the field (the camera is always inside the arc).
    quads = np.stack([i, n + 1 + i + 1, i + 1, i, n + 1 + i, n + 1 + i + 1], axis=1).reshape(-1)
    return Mesh(verts, normals, uvs, quads.astype(np.int64))


def backdrop_meshes(spec, layout, terrain, rng: np.random.Generator, textures) -> list[BackdropPart]:
    """All backdrop parts of the spec's `backdrop` section (empty by default)."""
    bd = spec.backdrop
    parts: list[BackdropPart] = []
    lo, hi = _field_box(layout, margin=0.5 * spec.rows.spacing)
    leaf_tex = textures.plant[0]
    for _ in range(bd.trees):
        xy, _ = _around(rng, lo, hi, rng.uniform(*bd.tree_distance))
        foot = np.array([xy[0], xy[1], float(terrain.height(*xy))])
        parts.append(("backdrop_tree", tree_mesh(rng, foot, rng.uniform(*bd.tree_height)), leaf_tex, (1, 1, 1, 1)))
    for _ in range(bd.forest_edges):  # a dense line of trees along one whole side
        side = int(rng.integers(4))
        distance = rng.uniform(*bd.tree_distance)
        count = int(rng.integers(8, 16))
        for _ in range(count):
            xy, _ = _around(rng, lo, hi, distance + rng.uniform(0, 4), side)
            foot = np.array([xy[0], xy[1], float(terrain.height(*xy))])
            parts.append(
                ("backdrop_tree", tree_mesh(rng, foot, rng.uniform(*bd.tree_height), 160), leaf_tex, (1, 1, 1, 1))
            )
    for _ in range(bd.hedges):
        side = int(rng.integers(4))
        distance = rng.uniform(1.0, max(1.5, 0.5 * bd.tree_distance[1]))
        span = hi - lo
        if side in (0, 1):
            x = hi[0] + distance if side == 0 else lo[0] - distance
            a, b = np.array([x, lo[1] - 0.3 * span[1]]), np.array([x, hi[1] + 0.3 * span[1]])
        else:
            y = lo[1] - distance if side == 2 else hi[1] + distance
            a, b = np.array([lo[0] - 0.2 * span[0], y]), np.array([hi[0] + 0.2 * span[0], y])
        for k in range(4):  # in pieces, so culling and TinyRenderer's bounding boxes stay small
            pa, pb = a + (b - a) * k / 4, a + (b - a) * (k + 1) / 4
            parts.append(
                (
                    "backdrop_tree",
                    hedge_mesh(rng, pa, pb, rng.uniform(*bd.hedge_height), terrain),
                    leaf_tex,
                    (1, 1, 1, 1),
                )
            )
    for _ in range(bd.buildings):
        xy, _ = _around(rng, lo, hi, rng.uniform(max(8.0, bd.tree_distance[0]), max(10.0, bd.tree_distance[1])))
        foot = np.array([xy[0], xy[1], float(terrain.height(*xy))])
        walls, roof = building_mesh(rng, foot, rng.uniform(*bd.building_height))
        tint = BUILDING_TINTS[int(rng.integers(len(BUILDING_TINTS)))]
        parts.append(("backdrop", walls, textures.structure, (*tint, 1.0)))
        roof_tint = (0.55, 0.25, 0.2) if rng.uniform() < 0.6 else (0.35, 0.35, 0.38)
        parts.append(("backdrop", roof, textures.structure, (*roof_tint, 1.0)))
    if bd.hills > 0 and rng.uniform() < bd.hills:
        centre = 0.5 * (lo + hi)
        radius = 0.5 * float(np.linalg.norm(hi - lo)) + rng.uniform(12.0, 20.0)
        green = rng.uniform(0.35, 0.6)
        hill_tint = (green * 0.8, green, green * rng.uniform(0.8, 1.1), 1.0)
        parts.append(("backdrop", hills_mesh(rng, centre, radius, terrain), textures.ground[0], hill_tint))
    return parts


def row_end_line(
    rng: np.random.Generator, a: np.ndarray, b: np.ndarray, height: float, terrain, pieces: int
) -> list[Mesh]:
    """A dense, dark hedge or tree line from a to b (xy) that closes the end of the rows, in `pieces`
    meshes along it (culling and TinyRenderer's bounding boxes stay small).

    Real rows end in lines of trees or tall hedges that fill the view right across the vanishing
    point, dark because the camera sees their shaded side: a solid leafy wall (nothing shows
    through it, unlike `hedge_mesh`) up to about three quarters of the height, leaves over both of
    its faces, under crowns of uneven heights, so the skyline is ragged like trees of different ages.
    """
    length = float(np.linalg.norm(b - a))
    along = (b - a) / max(length, 1e-9)
    facing = np.array([along[1], -along[0], 0.0])
    n_crowns = max(2, int(length / rng.uniform(2.5, 5.0)))
    crown_t = np.sort(rng.uniform(0, 1, n_crowns))
    crown_h = height * rng.uniform(0.6, 1.2, n_crowns)
    crown_r = 0.5 * length / n_crowns + rng.uniform(0.8, 1.6, n_crowns)
    t = np.linspace(0, 1, max(2, int(length) + 1))  # wall stations every metre or so
    xy = a[None, :] + (b - a)[None, :] * t[:, None]
    ground = np.asarray(terrain.height(xy[:, 0], xy[:, 1]), float)
    top = ground + 0.75 * np.interp(t, crown_t, crown_h) * rng.uniform(0.9, 1.05, len(t))
    meshes = []
    for k in range(pieces):
        t0, t1 = k / pieces, (k + 1) / pieces
        st = np.nonzero((t >= t0 - 1e-9) & (t <= t1 + 1e-9))[0]
        st = np.arange(max(st[0] - 1, 0), min(st[-1] + 1, len(t) - 1) + 1)  # overlap the neighbours
        parts = [_wall(xy[st], ground[st], top[st], facing)]
        pts, out = [], []
        for tc, h, r in zip(crown_t, crown_h, crown_r):
            if not t0 <= tc < t1:
                continue
            p = a + (b - a) * tc
            radii = np.array([r, rng.uniform(0.8, 1.6), 0.35 * h])
            n = int(np.clip(ellipsoid_area(radii) / 0.12, 40, 600))  # about covered by 0.55 m leaves
            centre = np.array([p[0], p[1], float(terrain.height(p[0], p[1])) + 0.65 * h])
            local, outward = ellipsoid_shell_points(centre, radii, n, rng, depth=0.2)
            pts.append(local)
            out.append(outward)
        # Leaves over both faces of the wall, so it is not flat.
        n_face = int(1.2 * (t1 - t0) * length * float(np.mean(top[st] - ground[st])))
        tf = rng.uniform(t0, t1, n_face)
        fxy = a[None, :] + (b - a)[None, :] * tf[:, None]
        fz = np.asarray(terrain.height(fxy[:, 0], fxy[:, 1]), float)
        fz = fz + rng.uniform(0.05, 1.0, n_face) * (np.interp(tf, t, top) - fz)
        side = np.where(rng.uniform(size=n_face) < 0.5, -1.0, 1.0)[:, None] * facing[None, :]
        pts.append(np.column_stack([fxy, fz]) + side * rng.uniform(0.05, 0.3, (n_face, 1)))
        out.append(side + np.array([0.0, 0.0, 0.3]))
        pts_a, out_a = np.concatenate(pts), np.concatenate(out)
        sizes = 0.55 * rng.uniform(0.7, 1.4, len(pts_a))
        parts.append(leaves(pts_a, sizes, rng, facing=out_a, up_bias=0.0))
        meshes.append(Mesh.concat(parts))
    return meshes


def _wall(xy: np.ndarray, ground: np.ndarray, top: np.ndarray, facing: np.ndarray) -> Mesh:
    """A double-sided vertical strip from below the ground to `top` through the stations `xy`,
    textured with the atlas' leaves: the opaque core of a row-end line."""
    lower = np.column_stack([xy, ground - 0.3])
    upper = np.column_stack([xy, top])
    quads = np.stack([lower[:-1], lower[1:], upper[1:], upper[:-1]], axis=1)  # n, 4, 3
    n = len(quads)
    verts = quads.reshape(-1, 3)
    uvs = np.tile([[0.55, 0.05], [0.95, 0.05], [0.95, 0.95], [0.55, 0.95]], (n, 1))
    front = (np.arange(n)[:, None] * 4 + np.array([0, 1, 2, 0, 2, 3])[None, :]).reshape(-1)
    back = (np.arange(n)[:, None] * 4 + np.array([0, 2, 1, 0, 3, 2])[None, :] + 4 * n).reshape(-1)
    normals = np.tile(facing, (4 * n, 1))
    return Mesh(
        np.concatenate([verts, verts]),
        np.concatenate([normals, -normals]),
        np.concatenate([uvs, uvs]),
        np.concatenate([front, back]).astype(np.int64),
    )


def row_end_meshes(spec, layout, terrain, rng: np.random.Generator) -> list[tuple[Mesh, float]]:
    """(mesh, brightness) of the lines that close the rows' ends (`backdrop.row_end_*`): each end
    (beyond the last plants, then before the entrance) draws its own line, across the whole field
    and well beyond its sides, square to the rows there."""
    bd = spec.backdrop
    parts: list[tuple[Mesh, float]] = []
    half = 0.5 * (layout.offsets[-1] - layout.offsets[0]) + spec.rows.spacing
    for end in (1, 0):  # the far end first: forward frames look at it
        if rng.uniform() >= bd.row_end_probability:
            continue
        distance = rng.uniform(*bd.row_end_distance)
        xy, tangent = layout.at(np.array([layout.length if end else 0.0]))
        out = tangent[0] if end else -tangent[0]  # straight on out of the rows
        centre = xy[0] + out * distance
        reach = half + rng.uniform(15.0, 30.0)  # wide enough to fill a 120 degree view
        across = np.array([-out[1], out[0]]) * reach
        height = rng.uniform(*bd.row_end_height)
        brightness = rng.uniform(*bd.row_end_brightness)
        for mesh in row_end_line(rng, centre - across, centre + across, height, terrain, pieces=6):
            parts.append((mesh, brightness))
    return parts
