"""Renderer: exact vegetation masks, planar depth against an analytic ground plane, camera mount."""

from __future__ import annotations

import math

import numpy as np
import pybullet as p
import pytest
from synth_helpers import tiny

from segmin.data.synth.camera import CameraModel
from segmin.data.synth.render import Renderer, camera_pose
from segmin.data.synth.spec import spec_from_dict
from segmin.data.synth.world import build_world

SMALL = CameraModel(width=48, height=48)


@pytest.fixture(scope="module")
def scene():
    client = p.connect(p.DIRECT)
    world = build_world(spec_from_dict(tiny()), client)
    yield world, Renderer(world, SMALL)
    p.disconnect(client)


def test_mask_is_exactly_the_plant_bodies(scene):
    world, renderer = scene
    x, y, yaw = world.gap_pose(world.eval_gap, 1.0)
    frame = renderer.render(x, y, yaw)
    assert frame.rgb.shape == (48, 48, 3) and frame.rgb.dtype == np.uint8
    assert frame.depth.dtype == np.float32 and frame.mask.dtype == bool
    assert 0.05 < frame.mask.mean() < 0.95, "both rows and free space should be in view"
    assert np.array_equal(frame.mask, np.isin(frame.body_ids, list(world.vegetation_ids)))
    # Hide every vegetation body: exactly the mask pixels must change depth (they were plants).
    renderer.hidden = set(world.vegetation_ids)
    try:
        without = renderer.render(x, y, yaw)
    finally:
        renderer.hidden = set()
    changed = frame.depth != without.depth
    assert not without.mask.any()
    assert np.array_equal(changed, frame.mask)
    rgb_changed = np.any(frame.rgb != without.rgb, axis=-1)
    assert np.all(frame.mask[rgb_changed]), "RGB changed outside the mask"
    assert rgb_changed[frame.mask].mean() > 0.97, "mask pixels whose colour did not change"


@pytest.mark.parametrize("backend", ["tiny", "gl"])
def test_depth_matches_an_analytic_ground_plane(bullet_client, backend):
    """Planar depth of a flat ground is exact with either rasteriser (gl interpolates it itself,
    TinyRenderer's depth buffer is linearised)."""
    raw = tiny(terrain={"roughness": 0.0, "slope": [0.0, 0.0], "grass_tufts": 0.0}, structures={"poles": False})
    world = build_world(spec_from_dict(raw), bullet_client)
    camera = CameraModel(width=64, height=48)
    renderer = Renderer(world, camera, backend=backend)
    x, y, yaw = world.gap_pose(world.eval_gap, 1.0)
    frame = renderer.render(x, y, yaw, pose_offset=(0.0, 0.0, -0.7, 0.05))  # look down, slight roll
    ground = {b for c in world.chunks if c.kind == "ground" for b in c.bodies}
    is_ground = np.isin(frame.body_ids, list(ground))
    assert is_ground.mean() > 0.3
    k = camera.intrinsics()
    v, u = np.mgrid[0:48, 0:64]
    rays = np.stack([(u - k["cx"]) / k["fx"], (v - k["cy"]) / k["fy"], np.ones_like(u, float)], -1)
    pose = frame.camera_pose
    world_dirs = rays @ pose[:3, :3].T
    expect = -pose[2, 3] / world_dirs[..., 2]  # planar depth: rays have z = 1 in camera frame
    rel = np.abs(frame.depth[is_ground] - expect[is_ground]) / expect[is_ground]
    assert rel.max() <= 1e-3, f"max relative depth error {rel.max():.2e}"
    assert np.all(frame.depth[frame.body_ids < 0] == 0)


def test_camera_mount_follows_the_paper():
    raw = tiny(terrain={"roughness": 0.0, "slope": [0.0, 0.0]})
    client = p.connect(p.DIRECT)
    try:
        world = build_world(spec_from_dict(raw), client)
        cam = CameraModel()
        pose = camera_pose(world, cam, 1.0, 0.0, 0.0)
        assert np.allclose(pose[:3, 3], [1.0 + cam.mount_forward, 0.0, cam.mount_height], atol=1e-9)
        forward = pose[:3, 2]
        assert math.isclose(math.degrees(math.asin(forward[2])), cam.tilt_deg, abs_tol=1e-6)
        assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-9)
        assert pose[1, 0] < -0.99  # image x (right) points to -y when driving along +x
    finally:
        p.disconnect(client)
    # On a slope the camera tilts with the ground.
    raw = tiny(terrain={"roughness": 0.0, "slope": [0.1, 0.0]})
    client = p.connect(p.DIRECT)
    try:
        world = build_world(spec_from_dict(raw), client)
        pose = camera_pose(world, CameraModel(), 1.0, 0.0, 0.0)
        pitch = math.degrees(math.asin(pose[2, 2]))
        assert math.isclose(pitch, 15.0 + math.degrees(math.atan(0.1)), abs_tol=1e-6)
    finally:
        p.disconnect(client)


def test_render_is_deterministic_whatever_was_rendered_before(scene):
    world, renderer = scene
    a = world.gap_pose(0, 2.0)
    b = world.gap_pose(1, 4.5)
    first = renderer.render(*a, rng=np.random.default_rng(3))
    renderer.render(*b, rng=np.random.default_rng(4))
    renderer.randomize_appearance(np.random.default_rng(1))
    renderer.randomize_appearance(np.random.default_rng(0))
    renderer.render(*b)
    x1 = renderer.render(*a, rng=np.random.default_rng(3))
    client = p.connect(p.DIRECT)  # a fresh copy of the world, in its own client
    try:
        again = Renderer(build_world(world.spec, client), SMALL)
        again.randomize_appearance(np.random.default_rng(0))
        x2 = again.render(*a, rng=np.random.default_rng(3))
    finally:
        p.disconnect(client)
    assert np.array_equal(x1.rgb, x2.rgb) and np.array_equal(x1.depth, x2.depth)
    assert np.array_equal(first.mask, x1.mask)  # appearance changes colours, never geometry


@pytest.mark.parametrize("sampling", ["pixels", "field"])
def test_depth_noise_model(sampling):
    cam = CameraModel(
        width=32,
        height=32,
        depth_noise_k=0.01,
        depth_invalid_fraction=0.1,
        max_range=8.0,
        depth_noise_sampling=sampling,
    )
    depth = np.full((32, 32), 4.0, np.float32)
    depth[:, :8] = 10.0  # beyond max range
    depth[:4] = 0.0  # no return
    noisy = cam.apply_depth_noise(depth, np.random.default_rng(0))
    assert np.all(noisy[:4] == 0) and np.all(noisy[:, :8] == 0)
    valid = noisy[4:, 8:]
    dropped = (valid == 0).mean()
    assert 0.03 < dropped < 0.2
    kept = valid[valid > 0]
    assert 0.1 < kept.std() < 0.22  # sigma = k z^2 = 0.16 m at 4 m
    assert abs(kept.mean() - 4.0) < 0.05


def test_field_sampled_noise_is_reproducible_and_white_from_frame_to_frame():
    cam = CameraModel(width=48, height=40, depth_noise_k=0.01, depth_invalid_fraction=0.1, depth_noise_sampling="field")
    depth = np.full((40, 48), 3.0, np.float32)
    runs = [[cam.apply_depth_noise(depth, rng) for _ in range(30)] for rng in map(np.random.default_rng, (5, 5, 6))]
    assert all(np.array_equal(a, b) for a, b in zip(runs[0], runs[1]))  # the same seed, the same frames
    assert not np.array_equal(runs[0][0], runs[2][0])
    # Consecutive frames' errors at a pixel are uncorrelated, as drawn per pixel (the window moves).
    errors = np.stack(runs[0]) - 3.0
    kept = np.all(np.stack(runs[0]) > 0, axis=0)
    a, b = errors[:-1, kept].ravel(), errors[1:, kept].ravel()
    assert abs(np.corrcoef(a, b)[0, 1]) < 0.05
    assert np.all(np.isfinite(errors))


def test_the_noise_window_lies_anywhere_in_the_field():
    """field_window reads the fields at a row and a column offset drawn each on its own: the window
    is the fields' block at its corner, and over frames the corners spread over the whole field,
    off its diagonal (a column offset reusing the row offset would keep them on it)."""
    from segmin.data.synth.noise_field import FIELD_SIDE, field_window, noise_fields

    normal, uniform = noise_fields(FIELD_SIDE)
    rng = np.random.default_rng(1)
    rows, columns = 40, 48
    corners = []
    for _ in range(20):
        window_normal, window_uniform = field_window(rng, (rows, columns))
        found = [
            (r, c)
            for r, c in np.argwhere(normal == window_normal[0, 0])  # a float32 value may repeat in the field
            if np.array_equal(normal[r : r + rows, c : c + columns], window_normal)
        ]
        assert len(found) == 1
        r, c = found[0]
        assert np.array_equal(window_uniform, uniform[r : r + rows, c : c + columns])
        corners.append((r, c))
    top, left = np.array(corners).T
    assert np.count_nonzero(top == left) <= 1
    assert np.ptp(top) > FIELD_SIDE / 2 and np.ptp(left) > FIELD_SIDE / 2


def test_depth_noise_sampling_is_checked():
    with pytest.raises(ValueError, match="depth_noise_sampling"):
        CameraModel(depth_noise_sampling="texture")


def test_preview_contact_sheet(tmp_path):
    import cv2
    from synth_helpers import write_spec

    from segmin.app.cli import main as segmin_main

    spec_path = write_spec(tmp_path / "tiny.yaml", tiny())
    out = tmp_path / "sheet.png"
    assert (
        segmin_main(["synth", "preview", "--world", spec_path, "--out", str(out), "--frames", "2", "--size", "40"]) == 0
    )
    sheet = cv2.imread(str(out))
    assert sheet.shape == (2 * 40, 3 * 40, 3)  # rows of RGB | mask overlay | depth
