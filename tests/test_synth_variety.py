"""The sim-to-real variety of the worlds: ground styles, sky, backdrop, camera, labels, shadows.

Tiny worlds and 32-48 px frames keep this fast on CPU. What matters: new elements show up in
frames with the right label (backdrop, wood, poles, ground = 0; leaves = 1), datasets stay
byte-identical whatever the worker count, and the spec rejects bad values by name.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pybullet as p
import pytest
from synth_helpers import tiny

from segmin.common.config import ConfigError
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.render import Renderer
from segmin.data.synth.spec import GROUND_STYLE_NAMES, AppearanceSpec, spec_from_dict
from segmin.data.synth.textures import ground_texture
from segmin.data.synth.world import build_world
from segmin.data.synth.writer import RenderJob, render_dataset

VARIED = dict(
    sky={"overcast_probability": 0.3, "backlight_probability": 0.3, "haze": [0.0, 0.4]},
    capture={"hfov_deg": [60.0, 120.0], "mount_height": [0.3, 1.2], "tilt_deg": [-5.0, 15.0], "vignetting": [0.0, 0.3]},
    backdrop={
        "trees": 6,
        "tree_distance": [0.5, 4.0],
        "tree_height": [3.0, 6.0],
        "forest_edges": 1,
        "hedges": 1,
        "buildings": 1,
        "hills": 1.0,
    },
    render={"shadow_probability": 0.5},
    plants={"spacing": 1.3, "gap_probability": 0.0, "hanging_shoots": [1, 2]},
    appearance={"ground_styles": ["mown", "soil"], "texture_variants": 2},
)


@pytest.fixture(scope="module")
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


def _kinds(world) -> dict[int, str]:
    return {b: c.kind for c in world.chunks for b in c.bodies if b >= 0}


def _labels_by_kind(world, renderer, poses, rng_seed=0) -> dict[str, set[bool]]:
    """For every chunk kind seen in the frames, the set of mask values its pixels got."""
    kinds = _kinds(world)
    seen: dict[str, set[bool]] = {}
    for k, (x, y, yaw) in enumerate(poses):
        frame = renderer.render(x, y, yaw, rng=np.random.default_rng([rng_seed, k]))
        for body in np.unique(frame.body_ids[frame.body_ids >= 0]):
            values = set(np.unique(frame.mask[frame.body_ids == body]).tolist())
            seen.setdefault(kinds.get(int(body), "?"), set()).update(values)
    return seen


def _poses(world) -> list[tuple[float, float, float]]:
    """From the entrance looking in and out, and from the exit looking out past the row ends."""
    poses = []
    for s, turn in ((0.5, 0.0), (0.5, np.pi), (5.5, 0.0), (3.0, 0.0)):
        x, y, yaw = world.gap_pose(0, s)
        poses.append((x, y, yaw + turn))
    return poses


def test_new_elements_have_the_right_label(client):
    world = build_world(spec_from_dict(tiny(**VARIED)), client)
    renderer = Renderer(world, CameraModel(width=48, height=48, hfov_deg=110.0))
    seen = _labels_by_kind(world, renderer, _poses(world))
    for kind in ("backdrop_tree", "backdrop", "wood", "ground", "grass", "plants", "structure"):
        assert kind in seen, f"no {kind} pixels in the frames: {sorted(seen)}"
    assert seen["plants"] == {True}  # canopy label: leaves only
    for kind in ("backdrop_tree", "backdrop", "wood", "ground", "grass", "structure"):
        assert seen[kind] == {False}, f"{kind} must be 0 in the mask"


def test_plant_label_counts_trunks_as_vegetation(client):
    world = build_world(spec_from_dict(tiny(plants={"label": "plant"})), client)
    assert not any(c.kind == "wood" for c in world.chunks)
    kinds = _kinds(world)
    assert {b for b, k in kinds.items() if k == "plants"} == world.vegetation_ids


def test_canopy_label_keeps_wood_out_of_vegetation(client):
    world = build_world(spec_from_dict(tiny()), client)
    wood = {b for c in world.chunks if c.kind == "wood" for b in c.bodies if b >= 0}
    assert wood and not (wood & world.vegetation_ids)


def test_dataset_with_variety_is_identical_for_any_worker_count(tmp_path):
    spec = spec_from_dict(tiny(**VARIED))
    cam = CameraModel(width=32, height=32)

    def tree(root: Path) -> dict[str, bytes]:
        return {str(q.relative_to(root)): q.read_bytes() for q in sorted(root.rglob("*")) if q.is_file()}

    render_dataset(RenderJob(spec=spec, out=tmp_path / "one", frames=8, camera=cam, workers=1, progress=False))
    render_dataset(RenderJob(spec=spec, out=tmp_path / "two", frames=8, camera=cam, workers=2, progress=False))
    for i in range(2):
        render_dataset(
            RenderJob(spec=spec, out=tmp_path / "shards", frames=8, camera=cam, shard=(i, 2), progress=False)
        )
    one = tree(tmp_path / "one")
    assert one == tree(tmp_path / "two") == tree(tmp_path / "shards")
    meta = json.loads(next((tmp_path / "one").rglob("meta.json")).read_text())
    fovs = {round(f["intrinsics"]["hfov_deg"], 3) for f in meta["frames"].values()}
    assert len(fovs) == 8 and all(60 <= v <= 120 for v in fovs)
    heights = [f["mount_height"] for f in meta["frames"].values()]
    assert all(0.3 <= h <= 1.2 for h in heights)


def test_frames_without_capture_variety_keep_the_job_camera(tmp_path):
    render_dataset(
        RenderJob(
            spec=spec_from_dict(tiny()),
            out=tmp_path,
            frames=2,
            camera=CameraModel(width=32, height=32, hfov_deg=80.0),
            progress=False,
        )
    )
    meta = json.loads(next(tmp_path.rglob("meta.json")).read_text())
    assert meta["intrinsics"]["hfov_deg"] == 80.0
    assert all("intrinsics" not in f for f in meta["frames"].values())


def test_shadows_and_overcast_follow_their_probabilities(client):
    world = build_world(
        spec_from_dict(tiny(render={"shadow_probability": 0.5}, sky={"overcast_probability": 0.3})), client
    )
    renderer = Renderer(world, CameraModel(width=32, height=32))
    x, y, yaw = world.gap_pose(0, 1.0)
    stats = [renderer.render(x, y, yaw, rng=np.random.default_rng(k)).stats for k in range(40)]
    shadow = sum(s["shadow"] for s in stats)
    overcast = sum(s["overcast"] for s in stats)
    assert 5 <= shadow <= 30 and 3 <= overcast <= 25
    assert not any(s["shadow"] and s["overcast"] for s in stats)  # overcast light casts no shadows


@pytest.mark.parametrize("style", GROUND_STYLE_NAMES)
def test_ground_styles_carry_grass_like_fine_detail(style):
    def detail(amount: float) -> float:
        img = ground_texture(np.random.default_rng(3), AppearanceSpec(ground_detail=amount), style)
        assert img.dtype == np.uint8 and img.shape[2] == 3
        grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32)
        return float(np.abs(cv2.Laplacian(grey, cv2.CV_32F)).mean())

    assert detail(0.6) > 1.5 * detail(0.0)


@pytest.mark.parametrize(
    "changes,field",
    [
        ({"sky": {"overcast_probability": 1.5}}, "sky.overcast_probability"),
        ({"sky": {"haze": [0.0, float("nan")]}}, "sky.haze"),
        ({"sky": {"sun_elevation": [10.0, 95.0]}}, "sky.sun_elevation"),
        ({"capture": {"hfov_deg": [60.0, 200.0]}}, "capture.hfov_deg"),
        ({"capture": {"mount_height": [0.0, 1.0]}}, "capture.mount_height"),
        ({"capture": {"tilt_deg": [20.0, 10.0]}}, "capture.tilt_deg"),
        ({"capture": {"fov": [60.0, 90.0]}}, "fov"),
        ({"backdrop": {"trees": -1}}, "backdrop.trees"),
        ({"backdrop": {"tree_height": [5.0, float("inf")]}}, "backdrop.tree_height"),
        ({"backdrop": {"hills": 2.0}}, "backdrop.hills"),
        ({"backdrop": {"nets": 1}}, "nets"),
        ({"render": {"shadow_probability": -0.1}}, "render.shadow_probability"),
        ({"appearance": {"ground_styles": ["astroturf"]}}, "appearance.ground_styles"),
        ({"appearance": {"ground_styles": []}}, "appearance.ground_styles"),
        ({"appearance": {"ground_detail": 3.0}}, "appearance.ground_detail"),
        ({"plants": {"label": "trunk"}}, "label"),
        ({"plants": {"hanging_shoots": [2, 1]}}, "plants.hanging_shoots"),
        ({"terrain": {"texture_scale": 0.0}}, "terrain.texture_scale"),
        ({"rows": {"spacing": float("nan")}}, "rows.spacing"),
    ],
)
def test_invalid_variety_fields_name_the_field(changes, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.").replace("[", r"\[")):
        spec_from_dict(tiny(**changes))


def test_shipped_training_worlds_use_the_variety():
    from segmin.common.shipped import shipped_names
    from segmin.data.synth.spec import load_world_spec

    training = [name for name in shipped_names("worlds") if name.startswith("train_")]
    assert len(training) >= 9, training  # three vineyard worlds, six tree worlds (fruit wall, espalier, young)
    for name in training:
        spec = load_world_spec(name)
        assert spec.backdrop.trees > 0 and spec.capture.hfov_deg[1] >= 100, name
        assert spec.sky.overcast_probability > 0 and spec.render.shadow_probability > 0, name
        assert len(spec.appearance.ground_styles) > 1 and spec.plants.label == "canopy", name
