"""Procedural plants: a trunk, a few branches and a canopy of leaf clusters.

A plant is first drawn as a skeleton (tapered segments and ellipsoidal leaf clusters, in the
plant's local frame: `a` along the row, `c` across it towards the left, `h` up) and then meshed at
two levels of detail. Leaves are individual double-sided triangles scattered near each cluster's
surface, so masks get holes and ragged edges like real foliage. The coarse level keeps the
same clusters with fewer, bigger leaves (same covered area), for plants far from the camera.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from segmin.data.synth.mesh import Mesh, cylinders, ellipsoid_area, ellipsoid_shell_points, leaves
from segmin.data.synth.spec import WorldSpec, pergola_reach

# Leaves per plant at the finest level (TinyRenderer pays ~1.5 us per visible triangle), and
# how many times fewer (bigger) leaves each coarser level of detail has.
LEAF_BUDGET = {"vineyard": 300, "pear": 320, "pergola": 480, "tree": 900}
LOD_FACTORS = (1, 4, 16)


@dataclass
class Plant:
    """Skeleton of one plant; `mesh(lod)` turns it into triangles in world coordinates."""

    kind: str
    base: np.ndarray  # (3,) trunk foot on the ground
    along: np.ndarray  # (2,) unit row direction
    trunk_radius: float
    leaf_size: float
    density: float
    seed: int
    segments: list[tuple[np.ndarray, np.ndarray, float, float]] = field(default_factory=list)
    clusters: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    # One-year canes of a dormant vine: wood, but the canopy of a winter row, so meshed with the leaves.
    canes: list[tuple[np.ndarray, np.ndarray, float, float]] = field(default_factory=list)

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """Local (a, c, h) points (n, 3) to world coordinates."""
        t = np.array([self.along[0], self.along[1], 0.0])
        left = np.array([-self.along[1], self.along[0], 0.0])
        local = np.atleast_2d(local)
        return self.base[None, :] + local[:, :1] * t + local[:, 1:2] * left + local[:, 2:3] * np.array([0, 0, 1.0])

    def mesh(self, level: int) -> Mesh:
        """Triangles at level of detail `level` (0 = finest, see LOD_FACTORS): leaves, then wood."""
        return Mesh.concat(list(self.mesh_parts(level)))

    def _segment_arrays(self, segments) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """World end points and radii (p0, p1, r0, r1) of skeleton segments."""
        return (
            self.to_world(np.array([s[0] for s in segments])),
            self.to_world(np.array([s[1] for s in segments])),
            np.array([s[2] for s in segments]),
            np.array([s[3] for s in segments]),
        )

    def mesh_parts(self, level: int) -> tuple[Mesh, Mesh]:
        """(canopy, wood) at level of detail `level`, so the mask can label the canopy only. The
        canopy is the leaves and, on a dormant vine, its canes (kept at every level: a far winter
        row is its canes)."""
        fine = level == 0
        rng = np.random.default_rng([self.seed, level])
        parts = []
        if self.segments:
            p0, p1, r0, r1 = self._segment_arrays(self.segments)
            trunk = r0 >= 0.6 * self.trunk_radius
            if level <= 1:
                parts.append(cylinders(p0[trunk], p1[trunk], r0[trunk], r1[trunk], 6 if fine else 4))
                parts.append(cylinders(p0[~trunk], p1[~trunk], r0[~trunk], r1[~trunk], 4 if fine else 3))
            else:
                keep = r0 >= 0.012
                parts.append(cylinders(p0[keep], p1[keep], r0[keep], r1[keep], 3))
        canes = Mesh()
        if self.canes:
            canes = cylinders(*self._segment_arrays(self.canes), 4 if fine else 3)
        if self.density <= 0:  # a bare dormant vine
            return canes, Mesh.concat(parts)
        return Mesh.concat([self._leaves(level, rng), canes]), Mesh.concat(parts)

    def _leaves(self, level: int, rng: np.random.Generator) -> Mesh:
        """Leaf triangles over the clusters' visible surface at level of detail `level`."""
        # Candidate leaf positions on every cluster's shell; drop those buried inside another
        # cluster, so leaves go where they can be seen (the union's outer surface).
        areas = np.array([ellipsoid_area(r) for _, r in self.clusters])
        n_cand = np.maximum(8, (areas / areas.sum() * 4 * LEAF_BUDGET[self.kind])).astype(int)
        pts, out = [], []
        for k, ((centre, radii), n) in enumerate(zip(self.clusters, n_cand)):
            local, outward = ellipsoid_shell_points(centre, radii, int(n), rng)
            buried = np.zeros(len(local), bool)
            for j, (c2, r2) in enumerate(self.clusters):
                if j != k:
                    buried |= (((local - c2) / r2) ** 2).sum(axis=1) < 0.85
            pts.append(local[~buried])
            out.append(outward[~buried])
        local, outward = np.concatenate(pts), np.concatenate(out)
        visible_area = float((areas * np.array([len(q) for q in pts]) / n_cand).sum())
        # Leaf count and size so that about `density` of the surface is covered (Poisson overlap).
        budget = LEAF_BUDGET[self.kind] // LOD_FACTORS[level]
        cover = -np.log(max(1.0 - self.density, 0.02))
        n = int(min(budget, len(local), max(4, 2.0 * cover * visible_area / self.leaf_size**2)))
        size = max(self.leaf_size, float(np.sqrt(2.0 * cover * visible_area / max(n, 1))))
        pick = rng.choice(len(local), size=n, replace=False) if n < len(local) else np.arange(len(local))
        # Outermost leaves (towards the gaps) first: TinyRenderer draws triangles in order and
        # skips shading a pixel that is already nearer, so this cuts the overdraw seen from a gap.
        pick = pick[np.argsort(-np.abs(local[pick, 1]), kind="stable")]
        sizes = size * rng.uniform(0.75, 1.25, size=len(pick))
        facing = self.to_world(outward[pick]) - self.base[None, :]
        return leaves(self.to_world(local[pick]), sizes, rng, facing=facing, up_bias=0.0)


def _u(rng: np.random.Generator, pair) -> float:
    return float(rng.uniform(pair[0], pair[1]))


def _i(rng: np.random.Generator, pair) -> int:
    return int(rng.integers(pair[0], pair[1] + 1))


def make_plant(spec: WorldSpec, rng: np.random.Generator, base: np.ndarray, along: np.ndarray, row_index: int) -> Plant:
    """Draw one plant of the spec's crop at `base` (ground point) facing `along` the row."""
    ps = spec.plants
    plant = Plant(
        kind=spec.crop,
        base=np.asarray(base, float),
        along=np.asarray(along, float),
        trunk_radius=_u(rng, ps.trunk_radius),
        leaf_size=_u(rng, ps.leaf_size),
        density=ps.leaf_density,
        seed=int(rng.integers(2**31)),
    )
    if ps.sparse_probability > 0 and rng.uniform() < ps.sparse_probability:
        plant.density = ps.leaf_density * float(rng.uniform(0.3, 0.55))  # young shoots on the wires
    dormant = ps.dormant_probability > 0 and rng.uniform() < ps.dormant_probability
    builder = {"vineyard": _vine, "pear": _pear, "tree": _tree, "pergola": _pergola}[spec.crop]
    builder(plant, spec, rng, row_index)
    if dormant:
        _dormant(plant, spec, rng)
    _low_branches(plant, spec, rng)
    _hanging_shoots(plant, spec, rng)
    if not dormant:  # a winter vine's canes take the shoots' place
        _upright_shoots(plant, spec, rng)
    return plant


def _upright_shoots(plant: Plant, spec: WorldSpec, rng: np.random.Generator) -> None:
    """Untrimmed shoots rising above the canopy top (vines in spring and early summer, before
    hedging; water sprouts on trained trees): a thin stem with a few leaves along its upper part,
    labelled canopy like the rest of the plant.
    Rows seen from between them show these as a sparse fringe above the top wire, which a model
    that only saw hedged canopies leaves out. Nothing is drawn (no random draw either) when the
    spec asks for none, so worlds without them render as before.
    """
    ps = spec.plants
    if not any(ps.upright_shoots) or not plant.clusters:
        return
    top = _canopy_top(plant)
    half_span = 0.45 * ps.spacing
    for _ in range(_i(rng, ps.upright_shoots)):
        start = np.array([rng.uniform(-half_span, half_span), rng.normal(0, 0.05), top - rng.uniform(0.0, 0.15)])
        rise = rng.uniform(0.25, 0.65)
        tip = start + np.array([rng.normal(0, 0.12), rng.normal(0, 0.1), rise])
        _seg(plant, start, tip, 0.005, 0.003)
        upper = start + 0.7 * (tip - start)  # above the hedge's top
        plant.clusters.append((upper, np.array([0.08, 0.07, 0.1 + 0.3 * rise]) * rng.uniform(0.7, 1.3)))


def _canopy_top(plant: Plant) -> float:
    """Height of the highest leaf cluster's top: where winter canes end and upright shoots start."""
    return max(centre[2] + radii[2] for centre, radii in plant.clusters)


def _seg(plant: Plant, a, b, r0: float, r1: float) -> None:
    plant.segments.append((np.asarray(a, float), np.asarray(b, float), r0, r1))


def _vine(plant: Plant, spec: WorldSpec, rng: np.random.Generator, row_index: int) -> None:
    ps = spec.plants
    r = plant.trunk_radius
    height, trunk_h = _u(rng, ps.height), _u(rng, ps.trunk_height)
    bottom, width = _u(rng, ps.canopy_bottom), _u(rng, ps.canopy_width)
    lean = rng.normal(0, 0.03, size=2)
    top = np.array([lean[0], lean[1], trunk_h])
    _seg(plant, [0, 0, -0.1], top, r, 0.8 * r)
    arm = 0.45 * ps.spacing
    for sign in (-1, 1):  # cordon arms along the wire
        _seg(plant, top, [sign * arm, lean[1] + rng.normal(0, 0.02), trunk_h + 0.04], 0.6 * r, 0.35 * r)
    for _ in range(_i(rng, ps.branches)):  # shoots up into the canopy
        a0 = rng.uniform(-arm, arm)
        _seg(
            plant,
            [a0, lean[1], trunk_h + 0.03],
            [a0 + rng.normal(0, 0.15), rng.normal(0, 0.08), height * 0.92],
            0.009,
            0.005,
        )
    n = _i(rng, ps.clusters)
    span = 0.5 * ps.spacing
    depth = height - bottom
    for k in range(n):
        a = -span + (2 * span) * (k + 0.5) / n + rng.normal(0, 0.05)
        rz = 0.5 * depth * rng.uniform(0.5, 0.75)
        hz = rng.uniform(bottom + rz * 0.9, height - rz)
        radii = np.array([span / n * 1.3 + 0.08, 0.5 * width * rng.uniform(0.8, 1.15), rz])
        plant.clusters.append((np.array([a, rng.normal(0, 0.04), hz]), radii))
    # The top of the hedge: one flatter cluster that reaches the nominal height.
    plant.clusters.append(
        (np.array([rng.normal(0, 0.1), 0.0, height - 0.18]), np.array([span * 0.9, 0.5 * width * 0.8, 0.18]))
    )


def _dormant(plant: Plant, spec: WorldSpec, rng: np.random.Generator) -> None:
    """A winter vine: the leaves mostly gone, one-year canes rising from the cordon.

    Canes start at spurs along the cordon arms (the vine's segments 1 and 2, see `_vine`) and rise
    in three slightly bent pieces, some arching over sideways, to about the summer canopy's top.
    """
    ps = spec.plants
    plant.density = ps.leaf_density * ps.dormant_leaves
    top = _canopy_top(plant)
    for _ in range(_i(rng, ps.canes)):
        arm = plant.segments[int(rng.integers(1, 3))]
        t = rng.uniform(0.1, 1.0)
        start = arm[0] + t * (arm[1] - arm[0])
        length = rng.uniform(0.35, 1.0) * max(top - start[2], 0.3)
        lean = np.array([rng.normal(0, 0.25), rng.normal(0, 0.12), 1.0])
        bend = np.array([rng.normal(0, 0.3), rng.normal(0, 0.15), -rng.uniform(0.0, 0.6)])
        radius = rng.uniform(0.005, 0.009)
        for k in range(3):  # each piece turns a little further towards `bend`
            d = lean + bend * (k / 2)
            end = start + d / np.linalg.norm(d) * length / 3
            plant.canes.append((start, end, radius * (1 - 0.2 * k), radius * (0.8 - 0.2 * k)))
            start = end


def _pear(plant: Plant, spec: WorldSpec, rng: np.random.Generator, row_index: int) -> None:
    ps = spec.plants
    r = plant.trunk_radius
    height, trunk_h = _u(rng, ps.height), _u(rng, ps.trunk_height)
    bottom, width = _u(rng, ps.canopy_bottom), _u(rng, ps.canopy_width)
    _seg(plant, [0, 0, -0.1], [0, 0, trunk_h], r, 0.85 * r)
    _seg(plant, [0, 0, trunk_h], [rng.normal(0, 0.05), rng.normal(0, 0.05), 0.95 * height], 0.8 * r, 0.25 * r)
    nb = _i(rng, ps.branches)
    for k in range(nb):  # fruiting tiers along the row, slightly upwards
        z = trunk_h + (0.95 * height - trunk_h - 0.3) * (k + 0.5) / max(nb, 1)
        sign = rng.choice([-1, 1])
        length = rng.uniform(0.3, 0.6)
        _seg(plant, [0, 0, z], [sign * length, rng.normal(0, 0.15), z + rng.uniform(0.05, 0.3)], 0.4 * r, 0.15 * r)
    n = _i(rng, ps.clusters)
    for k in range(n):
        hz = bottom + (height - bottom) * (k + 0.5) / n + rng.normal(0, 0.08)
        taper = 1.0 - 0.45 * (hz - bottom) / max(height - bottom, 1e-3)  # narrower at the top
        radii = np.array(
            [rng.uniform(0.3, 0.45) * taper + 0.1, 0.5 * width * taper * rng.uniform(0.8, 1.1), rng.uniform(0.25, 0.4)]
        )
        plant.clusters.append((np.array([rng.normal(0, 0.12), rng.normal(0, 0.06), hz]), radii))


def _tree(plant: Plant, spec: WorldSpec, rng: np.random.Generator, row_index: int) -> None:
    ps = spec.plants
    r = plant.trunk_radius
    height, trunk_h = _u(rng, ps.height), _u(rng, ps.trunk_height)
    bottom, width = _u(rng, ps.canopy_bottom), _u(rng, ps.canopy_width)
    lean = rng.normal(0, 0.1, size=2)
    top = np.array([lean[0], lean[1], trunk_h])
    _seg(plant, [0, 0, -0.2], top, r, 0.75 * r)
    rh, rv = 0.5 * width, 0.5 * (height - bottom)
    centre = np.array([lean[0], lean[1], bottom + rv])
    n = _i(rng, ps.clusters)
    clusters = [(centre + np.array([0, 0, rv * 0.55]), np.array([rh * 0.55, rh * 0.55, rv * 0.45]))]
    for _ in range(n - 1):
        d = rng.normal(size=3)
        d[2] *= 0.6
        d /= np.linalg.norm(d)
        c = centre + d * rng.uniform(0.35, 0.65) * np.array([rh, rh, rv])
        clusters.append((c, np.array([rh, rh, rv]) * rng.uniform(0.4, 0.55, size=3)))
    plant.clusters.extend(clusters)
    for c, _ in clusters[: max(2, _i(rng, ps.branches))]:  # scaffold branches to the clusters
        _seg(plant, top, c * np.array([0.8, 0.8, 1.0]) + np.array([0, 0, -0.3]), 0.5 * r, 0.15 * r)
    for _ in range(_i(rng, ps.branches)):
        d = rng.normal(size=2)
        d /= np.linalg.norm(d)
        tip = top + np.array([d[0] * rh * 0.7, d[1] * rh * 0.7, rng.uniform(0.5, 2.0)])
        _seg(plant, top, tip, 0.35 * r, 0.1 * r)


def _pergola(plant: Plant, spec: WorldSpec, rng: np.random.Generator, row_index: int) -> None:
    ps, st = spec.plants, spec.structures
    r = plant.trunk_radius
    ph = st.pergola_height
    height = max(_u(rng, ps.height), ph + 0.15)
    reach_right, reach_left = pergola_reach(spec)
    if row_index == 0:  # the outermost rows have no neighbouring band: spread symmetrically
        reach_right = reach_left
    if row_index == spec.rows.count - 1:
        reach_left = reach_right
    lean = rng.normal(0, 0.04, size=2)
    top = np.array([lean[0], lean[1], ph - 0.05])
    _seg(plant, [0, 0, -0.1], top, r, 0.8 * r)
    for sign, reach in ((1, reach_left), (-1, reach_right)):  # arms on the overhead wires
        _seg(plant, top, [rng.normal(0, 0.2), sign * reach * 0.85, ph + 0.02], 0.5 * r, 0.25 * r)
    n = max(2, _i(rng, ps.clusters))
    c0, c1 = -reach_right, reach_left
    thickness = max(height - ph, 0.2)
    along = 0.5 * ps.spacing + 0.2
    for k in range(n):  # flat clusters: a leaf ceiling over the span, edges at the free bands
        c = c0 + (c1 - c0) * (k + 0.5) / n
        rc = min(0.5 * (c1 - c0) / n * 1.3, c - c0, c1 - c)  # never past the band edges
        plant.clusters.append(
            (np.array([rng.normal(0, 0.1), c, ph + 0.4 * thickness]), np.array([along, rc, 0.5 * thickness]))
        )
    for sign, reach in ((1, reach_left), (-1, reach_right)):  # shoots hanging at the band edges
        drop = rng.uniform(0.15, 0.4)
        plant.clusters.append(
            (
                np.array([rng.normal(0, 0.15), sign * (reach - 0.2), ph - drop * 0.4]),
                np.array([0.35 * ps.spacing, 0.2, drop * 0.5 + 0.05]),
            )
        )
    if rng.uniform() < 0.5:  # now and then a sucker low on the trunk
        z = _u(rng, ps.canopy_bottom)
        plant.clusters.append((np.array([0.0, rng.normal(0, 0.1), z]), np.array([0.2, 0.15, 0.2])))


def _low_branches(plant: Plant, spec: WorldSpec, rng: np.random.Generator) -> None:
    """Branches that stick out into the gap below the canopy, each with a little foliage."""
    ps = spec.plants
    for _ in range(_i(rng, ps.low_branches)):
        side = rng.choice([-1.0, 1.0])
        z0 = rng.uniform(0.25, max(0.3, ps.canopy_bottom[0] + 0.2))
        reach = ps.low_branch_reach * rng.uniform(0.5, 1.0)
        tip = np.array([rng.normal(0, 0.25), side * reach, z0 + rng.uniform(-0.05, 0.25)])
        _seg(plant, [0, 0, z0], tip, 0.35 * plant.trunk_radius, 0.1 * plant.trunk_radius)
        plant.clusters.append((tip, np.array([0.18, 0.12, 0.12]) * rng.uniform(0.8, 1.4)))


def _hanging_shoots(plant: Plant, spec: WorldSpec, rng: np.random.Generator) -> None:
    """Shoots that lean out of the canopy and hang into the row: a thin stem with a narrow,
    elongated leaf cluster at its end (young vines are ragged, not trimmed hedges)."""
    ps = spec.plants
    n = _i(rng, ps.hanging_shoots)
    if not n or not plant.clusters:
        return
    for _ in range(n):
        centre, radii = plant.clusters[int(rng.integers(len(plant.clusters)))]
        side = rng.choice([-1.0, 1.0])
        start = centre + np.array(
            [rng.uniform(-radii[0], radii[0]), side * radii[1] * 0.8, radii[2] * rng.uniform(-0.2, 0.6)]
        )
        out = rng.uniform(0.15, 0.45)
        tip = start + np.array([rng.normal(0, 0.15), side * out, -rng.uniform(0.1, 0.5)])
        _seg(plant, start, tip, 0.006, 0.003)
        mid = (start + tip) / 2
        plant.clusters.append(
            (mid + np.array([0, side * 0.05, 0]), np.array([0.12, 0.1 + 0.5 * out, 0.1]) * rng.uniform(0.7, 1.3))
        )
