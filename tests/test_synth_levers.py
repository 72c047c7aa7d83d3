"""Data-engine levers of the worlds: anti-hail nets, dormant vines, deep shade, varied posts, row weeds.

Tiny worlds and 48-64 px frames. What matters: each lever is off by default (frames as they were),
changes the frame when on, keeps the mask exact (nets, posts, weeds = 0; canes = 1 with the canopy
label), reaches both renderers, and the spec names the key of a bad value.
"""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest
from synth_helpers import tiny

from segmin.data.synth.camera import CameraModel
from segmin.data.synth.nets import shade_under_nets
from segmin.data.synth.plants import make_plant
from segmin.data.synth.render import Renderer
from segmin.data.synth.spec import AppearanceSpec, spec_from_dict
from segmin.data.synth.textures import plant_atlas
from segmin.data.synth.world import build_world

NETS = {"probability": 1.0, "field_probability": 1.0, "colours": ["white"], "height": [2.6, 2.8]}


@pytest.fixture(scope="module")
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


def _bodies(world, kind: str) -> set[int]:
    """Bodies of the chunks of `kind` (tiny worlds have no backdrop: `backdrop` bodies are nets or posts)."""
    return {b for c in world.chunks if c.kind == kind for b in c.bodies if b >= 0}


def _frame(world, backend: str = "tiny", s: float = 1.0, pitch: float = 0.0, size: int = 48):
    renderer = Renderer(world, CameraModel(width=size, height=size, hfov_deg=100.0), backend=backend)
    x, y, yaw = world.gap_pose(world.eval_gap, s)
    return renderer.render(x, y, yaw, pose_offset=(0.0, 0.0, pitch, 0.0)), renderer


@pytest.mark.parametrize(
    ("changes", "key"),
    [
        ({"structures": {"nets": {"probability": 1.5}}}, "structures.nets.probability"),
        ({"structures": {"nets": {"colours": ["pink"]}}}, "structures.nets.colours"),
        ({"structures": {"nets": {"probability": 0.5, "height": [1.9, 3.0]}}}, "structures.nets.height"),
        ({"structures": {"nets": {"strand_width": [0.01, 0.2]}}}, "structures.nets.strand_width"),
        ({"structures": {"nets": {"dimming": [0.1, 0.95]}}}, "structures.nets.dimming"),
        ({"structures": {"post_styles": ["plastic"]}}, "structures.post_styles"),
        ({"structures": {"wire_radius": [0.0, 0.01]}}, "structures.wire_radius"),
        ({"plants": {"canes": [5, 2]}}, "plants.canes"),
        ({"plants": {"upright_shoots": [-1, 2]}}, "plants.upright_shoots"),
        ({"plants": {"dormant_leaves": 1.5}}, "plants.dormant_leaves"),
        ({"crop": "pear", "plants": {"dormant_probability": 0.5}}, "plants.dormant_probability"),
        ({"appearance": {"shade_value": [0.5, 1.2]}}, "appearance.shade_value"),
        ({"terrain": {"row_weed_height": [0.5, 2.0]}}, "terrain.row_weed_height"),
        ({"terrain": {"row_weeds": -1.0}}, "terrain.row_weeds"),
    ],
)
def test_bad_lever_values_name_the_key(changes, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        spec_from_dict(tiny(**changes))


def test_levers_off_leave_frames_as_they_were(client):
    """Settings of levers whose probability or amount is 0 draw nothing: the same bytes."""
    base, _ = _frame(build_world(spec_from_dict(tiny()), client))
    idle = tiny(
        structures={"nets": {"colours": ["black"], "height": [3.5, 3.9]}, "end_anchor_probability": 0.0},
        plants={"canes": [1, 2], "dormant_leaves": 0.5},
        appearance={"shade_value": [0.1, 0.2]},
        terrain={"row_weed_height": [0.2, 0.3]},
    )
    same, _ = _frame(build_world(spec_from_dict(idle), client))
    assert np.array_equal(base.rgb, same.rgb) and np.array_equal(base.depth, same.depth)


@pytest.mark.parametrize("backend", ["tiny", "gl"])
def test_net_is_seen_in_depth_and_never_vegetation(bullet_client, backend):
    world = build_world(spec_from_dict(tiny(structures={"nets": NETS})), bullet_client)
    net = _bodies(world, "backdrop")
    assert net and world.n_triangles["net"][0] > world.n_triangles["net"][1] > 0  # two levels of detail
    frame, _ = _frame(world, backend, pitch=0.5, size=64)  # look up into the net
    on_net = np.isin(frame.body_ids, list(net))
    assert on_net.mean() > 0.02, "no net in a frame looking up"
    assert not frame.mask[on_net].any(), "net pixels labelled as vegetation"
    assert np.all(frame.depth[on_net] > 0)


def test_net_darkens_what_lies_under_it_not_the_sky(client):
    world = build_world(spec_from_dict(tiny(structures={"nets": NETS})), client)
    frame, renderer = _frame(world, pitch=0.2)
    before = frame.rgb.copy()
    shade_under_nets(frame, world.net_shade, renderer.camera)
    darker = np.any(frame.rgb < before, axis=-1) | (before.max(axis=-1) < 4)  # black stays black
    ground = np.isin(frame.body_ids, list(_bodies(world, "ground")))
    # Where each ground pixel is: the straight tiny rows run along +x from 0 to 6 m, 1.8 m apart.
    k, pose = renderer.camera.intrinsics(), frame.camera_pose
    v, u = np.mgrid[0:48, 0:48]
    rays = np.stack([(u - k["cx"]) / k["fx"], (v - k["cy"]) / k["fy"], np.ones_like(u, float)], -1)
    xyz = (rays * frame.depth[..., None]) @ pose[:3, :3].T + pose[:3, 3]
    inside = ground & (xyz[..., 0] > 0.2) & (xyz[..., 0] < 6.0) & (np.abs(xyz[..., 1]) < 2.5)
    outside = ground & ((xyz[..., 0] > 7.0) | (np.abs(xyz[..., 1]) > 3.0))
    assert inside.sum() > 50 and outside.sum() > 10
    assert darker[inside].all(), "ground under a field net keeps its light"
    assert not np.any(frame.rgb[outside] < before[outside]), "ground beyond the net darkened"
    assert np.array_equal(frame.rgb[frame.body_ids < 0], before[frame.body_ids < 0]), "sky darkened"
    assert not np.any(frame.rgb > before)
    ratio = frame.rgb[inside].astype(float).sum() / before[inside].astype(float).sum()
    assert 1 - world.net_shade.dimming - 0.02 <= ratio <= 1 - world.net_shade.dimming + 0.01


def test_frames_without_a_net_are_not_shaded(client):
    world = build_world(spec_from_dict(tiny()), client)
    frame, renderer = _frame(world)
    before = frame.rgb.copy()
    shade_under_nets(frame, world.net_shade, renderer.camera)
    assert world.net_shade is None and np.array_equal(frame.rgb, before)


def test_dormant_canes_are_the_canopy_of_a_winter_row(client):
    """With the canopy label, canes are 1 in the mask and the trunk and cordon 0: a bare vine
    without its canes leaves nothing in the mask."""
    bare = {"dormant_probability": 1.0, "dormant_leaves": 0.0}
    world = build_world(spec_from_dict(tiny(plants=bare)), client)
    frame, _ = _frame(world)
    assert frame.mask.mean() > 0.01
    assert not frame.mask[np.isin(frame.body_ids, list(_bodies(world, "wood")))].any()
    stripped = build_world(spec_from_dict(tiny(plants={**bare, "canes": [0, 0]})), client)
    frame, _ = _frame(stripped)
    assert not frame.mask.any(), "a dormant vine without canes still has canopy"


def test_bare_dormant_vine_has_canes_and_no_leaves():
    spec = spec_from_dict(tiny(plants={"dormant_probability": 1.0, "dormant_leaves": 0.0, "canes": [5, 8]}))
    plant = make_plant(spec, np.random.default_rng(3), np.zeros(3), np.array([1.0, 0.0]), 0)
    canopy, _ = plant.mesh_parts(0)
    assert 5 * 3 <= len(plant.canes) <= 8 * 3  # three pieces a cane
    assert canopy.n_triangles == 8 * len(plant.canes)  # 4-sided prisms at the fine level, no leaf
    assert canopy.vertices[:, 2].min() > 0.3  # canes rise from the cordon, not from the ground


def test_upright_shoots_rise_above_the_canopy_top():
    """Each shoot adds one leaf cluster, all of them above the hedge's top; none on a winter vine,
    and a vine without them draws the same plant as before the lever existed."""
    along = np.array([1.0, 0.0])

    def plant(**plants):
        return make_plant(spec_from_dict(tiny(plants=plants)), np.random.default_rng(5), np.zeros(3), along, 0)

    plain = plant()
    top = max(centre[2] + radii[2] for centre, radii in plain.clusters)
    shoots = plant(upright_shoots=[4, 4])
    added = shoots.clusters[len(plain.clusters) :]
    assert len(added) == 4
    assert all(centre[2] > top for centre, _ in added)
    assert len(shoots.segments) == len(plain.segments) + 4  # one stem a shoot
    assert [c[0].tolist() for c in shoots.clusters[: len(plain.clusters)]] == [c[0].tolist() for c in plain.clusters]
    winter = plant(upright_shoots=[4, 4], dormant_probability=1.0)
    assert len(winter.clusters) == len(plant(dormant_probability=1.0).clusters)


def test_deep_shade_variant_is_darker_and_greyer():
    appearance = AppearanceSpec(leaf_value=(0.5, 0.6), leaf_saturation=(0.6, 0.7))
    light = plant_atlas(np.random.default_rng(1), appearance, autumn=False)[:, 64:].astype(float)
    shade = plant_atlas(np.random.default_rng(1), appearance, autumn=False, shade=True)[:, 64:].astype(float)
    assert shade.mean() < 0.5 * light.mean()
    spread = lambda img: (img.max(axis=-1) - img.min(axis=-1)).mean()  # noqa: E731 - a one-line measure
    assert spread(shade) < spread(light)


def test_varied_posts_keep_their_material_and_are_not_vegetation(client):
    styles = {"post_styles": ["concrete"], "square_probability": 1.0, "end_anchor_probability": 1.0}
    world = build_world(spec_from_dict(tiny(structures=styles)), client)
    plain = build_world(spec_from_dict(tiny()), client)
    posts = [c for c in world.chunks if c.kind == "backdrop"]
    assert posts and all(min(c.tint[:3]) >= 0.6 for c in posts)  # pale concrete
    assert len(world.obstacle_circles) == len(plain.obstacle_circles)
    assert world.n_triangles["structure"][0] > 0  # wires and the anchors' wires
    frame, _ = _frame(world, s=0.3, size=64)
    on_post = np.isin(frame.body_ids, list(_bodies(world, "backdrop")))
    assert on_post.any() and not frame.mask[on_post].any()


def test_row_weeds_reach_into_the_canopy_band_and_are_not_vegetation(client):
    world = build_world(spec_from_dict(tiny(terrain={"row_weeds": 8.0, "row_weed_height": [0.6, 0.9]})), client)
    weeds = [c for c in world.chunks if c.kind == "grass" and c.meshes[0].vertices[:, 2].max() > 0.5]
    assert weeds and world.n_triangles["weeds"][0] > 0
    frame, _ = _frame(world, size=64)
    on_weed = np.isin(frame.body_ids, [b for c in weeds for b in c.bodies if b >= 0])
    assert on_weed.mean() > 0.005 and not frame.mask[on_weed].any()


def test_dataset_frames_carry_the_net_shade():
    """The writer shades its frames: the same net taking 30 % of the light or none."""
    from segmin.data.synth.writer import FrameRenderer

    frames = []
    for dimming in (0.0, 0.3):
        spec = spec_from_dict(tiny(structures={"nets": {**NETS, "dimming": [dimming, dimming]}}))
        renderer = FrameRenderer(spec, CameraModel(width=32, height=32), 1, 10, False)
        frames.append(renderer.render(0))
        renderer.close()
    lit, shaded = frames
    assert np.array_equal(lit.depth, shaded.depth)
    assert not np.any(shaded.rgb > lit.rgb)
    assert np.any(shaded.rgb < lit.rgb, axis=-1).mean() > 0.2
