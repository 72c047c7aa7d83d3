"""Triangle meshes built in numpy, handed to pybullet as one visual shape per chunk.

TinyRenderer costs about 1.5 us per visible triangle and almost nothing per back face, and
it culls back faces, so foliage is made of double-sided triangles ("leaves") and everything
else of low-sided prisms. All geometry of one body shares one texture atlas; `uv` regions
pick the part of the atlas (bark, leaves, ground, ...).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Texture atlas regions (u0, v0, u1, v1) shared by plant textures.
UV_BARK = (0.0, 0.0, 0.5, 1.0)
UV_LEAF = (0.5, 0.0, 1.0, 1.0)


@dataclass
class Mesh:
    """Triangles with per-vertex normals and texture coordinates (world coordinates)."""

    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    uvs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    indices: np.ndarray = field(default_factory=lambda: np.zeros((0,), dtype=np.int64))

    @property
    def n_triangles(self) -> int:
        return len(self.indices) // 3

    @staticmethod
    def concat(meshes: list[Mesh]) -> Mesh:
        meshes = [m for m in meshes if len(m.indices)]
        if not meshes:
            return Mesh()
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return Mesh(
            vertices=np.concatenate([m.vertices for m in meshes]),
            normals=np.concatenate([m.normals for m in meshes]),
            uvs=np.concatenate([m.uvs for m in meshes]),
            indices=np.concatenate([m.indices + o for m, o in zip(meshes, offsets)]),
        )

    def bounding_capsule(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Segment (a, b) along the main horizontal axis and the radius around it."""
        v = self.vertices
        centre = v.mean(axis=0)
        xy = v[:, :2] - centre[:2]
        cov = xy.T @ xy
        _w, vec = np.linalg.eigh(cov)
        axis = np.array([vec[0, -1], vec[1, -1], 0.0])
        t = (v - centre) @ axis
        a, b = centre + t.min() * axis, centre + t.max() * axis
        d = v - a
        along = np.clip(d @ axis, 0, t.max() - t.min())
        radius = float(np.linalg.norm(d - along[:, None] * axis[None, :], axis=1).max())
        return a, b, radius

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        centre = (lo + hi) / 2
        return centre, float(np.linalg.norm(self.vertices - centre, axis=1).max())


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-12)


def _perpendicular_frames(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to each row of `axis` (n, 3) and to each other."""
    helper = np.where(np.abs(axis[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    a = _unit(np.cross(axis, helper))
    b = np.cross(axis, a)
    return a, b


def cylinders(
    p0: np.ndarray,
    p1: np.ndarray,
    r0: np.ndarray,
    r1: np.ndarray,
    sides: int,
    uv_region: tuple[float, float, float, float] = UV_BARK,
    caps: bool = False,
) -> Mesh:
    """Tapered open prisms from p0 to p1 (arrays of shape (n, 3) and (n,)), outward faces only."""
    p0, p1 = np.atleast_2d(p0).astype(float), np.atleast_2d(p1).astype(float)
    r0, r1 = np.broadcast_to(r0, (len(p0),)).astype(float), np.broadcast_to(r1, (len(p0),)).astype(float)
    n = len(p0)
    axis = _unit(p1 - p0)
    a, b = _perpendicular_frames(axis)
    angles = 2 * np.pi * np.arange(sides) / sides
    ring = np.cos(angles)[None, :, None] * a[:, None, :] + np.sin(angles)[None, :, None] * b[:, None, :]  # n,s,3
    bottom = p0[:, None, :] + r0[:, None, None] * ring
    top = p1[:, None, :] + r1[:, None, None] * ring
    verts = np.concatenate([bottom, top], axis=1).reshape(-1, 3)
    normals = np.concatenate([ring, ring], axis=1).reshape(-1, 3)
    u0, v0, u1, v1 = uv_region
    u = u0 + (u1 - u0) * np.arange(sides) / sides
    length = np.linalg.norm(p1 - p0, axis=1)
    uvs = np.zeros((n, 2 * sides, 2))
    uvs[:, :sides, 0] = u
    uvs[:, sides:, 0] = u
    uvs[:, :sides, 1] = v0
    uvs[:, sides:, 1] = v0 + (v1 - v0) * np.minimum(length, 1.0)[:, None]
    i = np.arange(sides)
    j = (i + 1) % sides
    # Counter-clockwise seen from outside: (b_i, b_j, t_j), (b_i, t_j, t_i)
    quad = np.stack([i, j, sides + j, i, sides + j, sides + i], axis=1).reshape(-1)
    idx = (np.arange(n)[:, None] * 2 * sides + quad[None, :]).reshape(-1)
    mesh = Mesh(verts, normals, uvs.reshape(-1, 2), idx.astype(np.int64))
    if caps:
        cap_v = np.concatenate([p1, p0])
        cap_n = np.concatenate([axis, -axis])
        cap_uv = np.full((2 * n, 2), [u0 + 0.01, v0 + 0.01])
        base = len(verts)
        cap_idx = []
        for k in range(n):
            c_top, c_bot = base + k, base + n + k
            for s in range(sides):
                t_i, t_j = k * 2 * sides + sides + s, k * 2 * sides + sides + (s + 1) % sides
                b_i, b_j = k * 2 * sides + s, k * 2 * sides + (s + 1) % sides
                cap_idx += [c_top, t_i, t_j, c_bot, b_j, b_i]
        mesh = Mesh(
            np.concatenate([verts, cap_v]),
            np.concatenate([normals, cap_n]),
            np.concatenate([mesh.uvs, cap_uv]),
            np.concatenate([idx, np.array(cap_idx, dtype=np.int64)]),
        )
    return mesh


def leaves(
    centres: np.ndarray,
    sizes: np.ndarray,
    rng: np.random.Generator,
    uv_region: tuple[float, float, float, float] = UV_LEAF,
    up_bias: float = 0.3,
    double_sided: bool = True,
    facing: np.ndarray | None = None,
) -> Mesh:
    """One irregular triangle per leaf.

    With `facing` (n, 3) (e.g. the outward direction of the cluster surface) each leaf is
    single-sided and faces roughly that way: leaves on the far side of a cluster then face away
    from the camera and TinyRenderer culls them almost for free, a cheap occlusion culling.
    Without it, leaves are randomly oriented and double-sided.
    """
    n = len(centres)
    if n == 0:
        return Mesh()
    normal = rng.normal(size=(n, 3))
    if facing is not None:
        normal = 0.6 * normal + _unit(facing) * 1.2
        double_sided = False
    normal[:, 2] += up_bias * np.abs(rng.normal(size=n)) * 3  # leaves tend to face the sky
    normal = _unit(normal)
    a, b = _perpendicular_frames(normal)
    base_angle = rng.uniform(0, 2 * np.pi, size=(n, 1))
    angles = base_angle + np.array([0.0, 2.1, 4.2])[None, :] + rng.uniform(-0.35, 0.35, size=(n, 3))
    radius = sizes[:, None] * rng.uniform(0.45, 0.75, size=(n, 3))
    offs = np.cos(angles)[..., None] * a[:, None, :] + np.sin(angles)[..., None] * b[:, None, :]
    tri = centres[:, None, :] + radius[..., None] * offs  # n,3,3
    u0, v0, u1, v1 = uv_region
    uv_c = np.stack([rng.uniform(u0 + 0.05, u1 - 0.05, n), rng.uniform(v0 + 0.05, v1 - 0.05, n)], axis=1)
    uv = uv_c[:, None, :] + 0.04 * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    verts = tri.reshape(-1, 3)
    norms = np.repeat(normal, 3, axis=0)
    uvs = uv.reshape(-1, 2)
    # Winding (0, 1, 2) with angles increasing counter-clockwise about `normal` faces `normal`.
    front = np.arange(3 * n)
    if not double_sided:
        return Mesh(verts, norms, uvs, front.astype(np.int64))
    back = (3 * n + np.arange(3 * n).reshape(n, 3)[:, ::-1]).reshape(-1)
    return Mesh(
        np.concatenate([verts, verts]),
        np.concatenate([norms, -norms]),
        np.concatenate([uvs, uvs]),
        np.concatenate([front, back]).astype(np.int64),
    )


def blades(
    bases: np.ndarray, heights: np.ndarray, rng: np.random.Generator, per_tuft: int = 3, lift: float = 0.0
) -> Mesh:
    """Grass tufts: `per_tuft` thin leaning blades (double-sided triangles) per base point.

    `lift` tilts the shading normals towards the sky: a blade's own normal is horizontal, so the
    sun lights a tuft from the side only; lush young grass seen from above is lit like a lawn."""
    n = len(bases) * per_tuft
    if n == 0:
        return Mesh()
    base = np.repeat(bases, per_tuft, axis=0)
    h = np.repeat(heights, per_tuft) * rng.uniform(0.6, 1.2, n)
    az = rng.uniform(0, 2 * np.pi, n)
    side = np.stack([np.cos(az), np.sin(az), np.zeros(n)], axis=1)
    lean = np.stack([-np.sin(az), np.cos(az), np.zeros(n)], axis=1) * (h * rng.uniform(-0.5, 0.5, n))[:, None]
    width = rng.uniform(0.012, 0.03, n)[:, None]
    foot = base + rng.normal(0, 0.03, (n, 3)) * np.array([1, 1, 0])
    a, b = foot - side * width, foot + side * width
    tip = foot + lean + np.array([0, 0, 1.0]) * h[:, None]
    tri = np.stack([a, b, tip], axis=1)
    normal = np.cross(b - a, tip - a)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
    uv = np.stack([rng.uniform(0.05, 0.95, n), rng.uniform(0.05, 0.95, n)], axis=1)
    uvs = np.repeat(uv, 3, axis=0) + np.tile([[0, 0], [0.02, 0], [0.01, 0.05]], (n, 1))
    verts = tri.reshape(-1, 3)
    norms = np.repeat(normal, 3, axis=0)
    back_norms = -norms
    if lift:  # both faces towards the sky
        up = np.array([0.0, 0.0, lift])
        norms, back_norms = (_unit(v + up) for v in (norms, back_norms))
    front = np.arange(3 * n)
    back = (3 * n + np.arange(3 * n).reshape(n, 3)[:, ::-1]).reshape(-1)
    return Mesh(
        np.concatenate([verts, verts]),
        np.concatenate([norms, back_norms]),
        np.concatenate([uvs, uvs]),
        np.concatenate([front, back]).astype(np.int64),
    )


def grid_surface(xs: np.ndarray, ys: np.ndarray, height_fn, normal_fn, uv_scale: float) -> Mesh:
    """A height-field patch over the grid xs x ys, upward faces, uv = world xy * uv_scale."""
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    z = height_fn(gx, gy)
    verts = np.stack([gx, gy, z], axis=-1).reshape(-1, 3)
    normals = normal_fn(gx.reshape(-1), gy.reshape(-1))
    uvs = np.stack([gx.reshape(-1), gy.reshape(-1)], axis=1) * uv_scale
    nx, ny = len(xs), len(ys)
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    v00 = (i * ny + j).reshape(-1)
    v10 = ((i + 1) * ny + j).reshape(-1)
    v01 = (i * ny + j + 1).reshape(-1)
    v11 = ((i + 1) * ny + j + 1).reshape(-1)
    idx = np.stack([v00, v10, v11, v00, v11, v01], axis=1).reshape(-1)
    return Mesh(verts, normals, uvs, idx.astype(np.int64))


def ellipsoid_shell_points(
    centre: np.ndarray, radii: np.ndarray, n: int, rng: np.random.Generator, depth: float = 0.35
) -> tuple[np.ndarray, np.ndarray]:
    """`n` points inside an axis-aligned ellipsoid, concentrated near its surface, and the
    outward surface normal at each point's direction."""
    d = _unit(rng.normal(size=(n, 3)))
    r = 1.0 - depth * rng.uniform(0, 1, size=(n, 1)) ** 2
    outward = _unit(d / np.maximum(radii[None, :], 1e-6))
    return centre[None, :] + d * r * radii[None, :], outward


def ellipsoid_area(radii: np.ndarray) -> float:
    a, b, c = radii
    p = 1.6075
    return float(4 * np.pi * (((a * b) ** p + (a * c) ** p + (b * c) ** p) / 3) ** (1 / p))


def ribbons(p0: np.ndarray, p1: np.ndarray, width: np.ndarray, facing: np.ndarray, normal: np.ndarray) -> Mesh:
    """Flat strips from p0 to p1 (n, 3), `width` wide, whose front faces look along `facing` (n, 3);
    `normal` (n, 3) is what shading sees, which need not be the face's own direction (a thin net lit
    through from above: faces down, normal up)."""
    p0, p1 = np.atleast_2d(p0).astype(float), np.atleast_2d(p1).astype(float)
    n = len(p0)
    if n == 0:
        return Mesh()
    side = _unit(np.cross(p1 - p0, facing)) * (0.5 * np.broadcast_to(width, (n,)))[:, None]
    quad = np.stack([p0 - side, p0 + side, p1 + side, p1 - side], axis=1)  # n, 4, 3
    tri = np.array([0, 1, 2, 0, 2, 3])
    flip = (np.cross(quad[:, 1] - quad[:, 0], quad[:, 2] - quad[:, 0]) * facing).sum(axis=1) < 0
    order = np.where(flip[:, None], tri[[0, 2, 1, 3, 5, 4]][None, :], tri[None, :])  # front faces `facing`
    idx = (np.arange(n)[:, None] * 4 + order).reshape(-1)
    uvs = np.tile([[0.1, 0.1], [0.9, 0.1], [0.9, 0.9], [0.1, 0.9]], (n, 1))
    normals = np.repeat(_unit(np.broadcast_to(normal, (n, 3))), 4, axis=0)
    return Mesh(quad.reshape(-1, 3), normals, uvs, idx.astype(np.int64))
