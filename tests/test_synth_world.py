"""World ground truth: centrelines between the rows, terrain, collision circles, vegetation ids."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest
from synth_helpers import tiny

from segmin.data.synth.spec import spec_from_dict
from segmin.data.synth.world import build_world


def _signed_lateral(centreline: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Signed distance (+ = left of the travel direction) from each point to the polyline."""
    a, b = centreline[:-1], centreline[1:]
    ab = b - a
    out = np.empty(len(pts))
    for i, q in enumerate(pts):
        t = np.clip(((q - a) * ab).sum(1) / (ab * ab).sum(1), 0, 1)
        proj = a + t[:, None] * ab
        k = int(np.argmin(np.linalg.norm(q - proj, axis=1)))
        cross = ab[k, 0] * (q[1] - a[k, 1]) - ab[k, 1] * (q[0] - a[k, 0])
        out[i] = np.sign(cross) * np.linalg.norm(q - proj[k])
    return out


ARC = [[12.0 * np.sin(t), 12.0 * (1 - np.cos(t))] for t in np.linspace(0, 0.8, 40)]  # radius 12, left


@pytest.mark.parametrize("curve, polyline", [(0.0, []), (12.0, []), (0.0, ARC)])
def test_centreline_lies_midway_between_the_rows(bullet_client, curve, polyline):
    spec = spec_from_dict(
        tiny(
            rows={
                "count": 4,
                "curve_radius": curve,
                "curve_start": 1.0,
                "length": 8.0,
                "polyline": [[float(a), float(b)] for a, b in polyline],
            }
        )
    )
    world = build_world(spec, bullet_client)
    assert len(world.centrelines) == 3 and len(world.gap_half_widths) == 3
    half = spec.rows.spacing / 2
    tol = 4 * spec.rows.lateral_jitter + 1e-6
    for line in world.centrelines:
        steps = np.linalg.norm(np.diff(line, axis=0), axis=1)
        assert steps.max() <= 0.25 and steps.min() > 0
        d = _signed_lateral(line, world.plant_circles[:, :2])
        inside = np.abs(d) < 2 * half  # the two neighbouring rows
        assert np.all(np.abs(np.abs(d[inside]) - half) < tol), "a neighbouring plant is off its row line"
        assert (d[inside] > 0).sum() >= 4 and (d[inside] < 0).sum() >= 4
    # Ordered from the entrance: the first point is at the row start, the last one ~length away.
    first, last = world.centrelines[1][0], world.centrelines[1][-1]
    assert abs(first[0] - spec.rows.start_x) < 1e-6
    path = np.linalg.norm(np.diff(world.centrelines[1], axis=0), axis=1).sum()
    assert abs(path - spec.rows.length) < 0.1
    if curve or polyline:
        assert last[1] > 1.0  # bends left


def test_pergola_centreline_is_the_free_band(bullet_client):
    raw = tiny(
        crop="pergola",
        rows={"spacing": 6.0, "count": 3},
        plants={"spacing": 1.5, "height": [2.8, 3.0], "trunk_height": [2.3, 2.5], "canopy_bottom": [1.5, 1.8]},
        structures={
            "pergola": True,
            "pergola_height": 2.5,
            "free_band_width": 1.4,
            "free_band_offset": 0.5,
            "wire_heights": [],
        },
    )
    spec = spec_from_dict(raw)
    world = build_world(spec, bullet_client)
    # Gap 0 lies between rows at y = -6 and 0; its band centre is 0.5 m left of the middle (-3).
    assert np.allclose(world.centrelines[0][:, 1], -2.5, atol=1e-6)
    assert world.gap_half_widths[0] < 3.0


def test_terrain_normal_matches_height_gradient(bullet_client):
    spec = spec_from_dict(tiny(terrain={"roughness": 0.1, "slope": [0.02, -0.01]}))
    world = build_world(spec, bullet_client)
    xs, ys = np.array([0.3, 2.0, 4.5]), np.array([-1.0, 0.2, 1.3])
    h = world.terrain_height(xs, ys)
    assert h.shape == (3,) and isinstance(world.terrain_height(1.0, 2.0), float)
    eps = 1e-5
    gx = (world.terrain_height(xs + eps, ys) - world.terrain_height(xs - eps, ys)) / (2 * eps)
    gy = (world.terrain_height(xs, ys + eps) - world.terrain_height(xs, ys - eps)) / (2 * eps)
    n = world.terrain_normal(xs, ys)
    expect = np.stack([-gx, -gy, np.ones(3)], 1)
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    assert np.allclose(n, expect, atol=1e-6)
    assert world.terrain_normal(1.0, 1.0).shape == (3,)
    assert np.std(world.terrain_height(np.linspace(0, 6, 50), np.zeros(50))) > 0.01  # uneven


def test_collision_circles_and_vegetation_ids(bullet_client):
    spec = spec_from_dict(tiny())
    world = build_world(spec, bullet_client)
    assert world.plant_circles.shape[1] == 3 and len(world.plant_circles) >= 3 * 4
    assert np.all(world.plant_circles[:, 2] > 0)
    assert len(world.obstacle_circles) >= 3 * 2  # poles
    kinds = {b: c.kind for c in world.chunks for b in c.bodies}
    assert world.vegetation_ids == {b for b, k in kinds.items() if k == "plants"}
    assert {"plants", "structure", "ground"} <= set(kinds.values())
    # Same spec and seed build the same world; another seed moves the plants.
    c2 = p.connect(p.DIRECT)
    try:
        again = build_world(spec, c2)
        other = build_world(spec, c2, seed=99)
    finally:
        p.disconnect(c2)
    assert np.array_equal(again.plant_circles, world.plant_circles)
    assert not np.array_equal(other.plant_circles[:5], world.plant_circles[:5])
