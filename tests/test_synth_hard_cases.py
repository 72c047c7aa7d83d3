"""The real world's hard cases in the worlds: row-end hedges and tree lines, low sun with glare,
lush grass between the rows, blank frames; the bounds on sizes; renamed and held-out worlds.

Tiny worlds and 48-64 px frames. What matters: each case follows its label rule (hedges, grass and
blank frames are background; glare touches colour only), is off by default (frames as they were),
and a bad value is refused with one line naming the key.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pybullet as p
import pytest
import yaml
from synth_helpers import tiny, write_spec

from segmin.app.cli import main
from segmin.common.shipped import shipped_names
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.render import Renderer
from segmin.data.synth.spec import RENAMED_WORLDS, load_world_spec, spec_from_dict
from segmin.data.synth.world import build_world
from segmin.data.synth.writer import FrameRenderer, is_blank

PIPELINES = Path(__file__).resolve().parents[1] / "configs" / "pipeline"
LOW_SUN_AHEAD = {"backlight_probability": 1.0, "glare_probability": 1.0, "glare_strength": [1.0, 1.0]}


def _bodies(world, kind: str) -> list[int]:
    return [b for c in world.chunks if c.kind == kind for b in c.bodies if b >= 0]


def _frame(world, s: float = 1.0, pitch: float = 0.0, size: int = 64, rng=None):
    renderer = Renderer(world, CameraModel(width=size, height=size, hfov_deg=90.0))
    x, y, yaw = world.gap_pose(world.eval_gap, s)
    return renderer.render(x, y, yaw, rng=rng, pose_offset=(0.0, 0.0, pitch, 0.0))


def _frame_alone(raw: dict, **kwargs):
    """A frame of the world `raw` built in a client of its own (body ids and masks compare across worlds)."""
    cid = p.connect(p.DIRECT)
    try:
        return _frame(build_world(spec_from_dict(raw), cid), **kwargs)
    finally:
        p.disconnect(cid)


@pytest.mark.parametrize(
    ("changes", "key"),
    [
        ({"terrain": {"row_weeds": 1000000.0}}, "terrain.row_weeds"),
        ({"terrain": {"grass_tufts": 1e6}}, "terrain.grass_tufts"),
        ({"terrain": {"gap_grass": -1.0}}, "terrain.gap_grass"),
        ({"terrain": {"gap_grass_height": [0.2, 3.0]}}, "terrain.gap_grass_height"),
        ({"structures": {"nets": {"probability": 1.0, "height": [1e6, 1e6]}}}, "structures.nets.height"),
        ({"backdrop": {"trees": 1000000}}, "backdrop.trees"),
        ({"backdrop": {"row_end_probability": 1.5}}, "backdrop.row_end_probability"),
        ({"backdrop": {"row_end_distance": [0.1, 2.0]}}, "backdrop.row_end_distance"),
        ({"backdrop": {"row_end_height": [3.0, 300.0]}}, "backdrop.row_end_height"),
        ({"backdrop": {"row_end_brightness": [0.0, 0.5]}}, "backdrop.row_end_brightness"),
        ({"sky": {"glare_probability": 0.5}}, "sky.glare_probability"),
        ({"sky": {"low_sun_behind_probability": 2.0}}, "sky.low_sun_behind_probability"),
        ({"sky": {"backlight_probability": 0.5, "glare_strength": [0.5, 1.5]}}, "sky.glare_strength"),
        ({"capture": {"blank_frames": 0.9}}, "capture.blank_frames"),
    ],
)
def test_bad_values_name_the_key(changes, key):
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        spec_from_dict(tiny(**changes))


@pytest.mark.parametrize(
    ("override", "key"),
    [("terrain.row_weeds=1000000", "terrain.row_weeds"), ("structures.nets.height=[1e6,1e6]", "nets.height")],
)
def test_unbounded_sizes_are_one_line_before_anything_is_built(tmp_path, capsys, override, key):
    world = write_spec(tmp_path / "w.yaml", tiny(structures={"nets": {"probability": 1.0}}))
    out = tmp_path / "sheet.png"
    assert main(["synth", "preview", "--world", world, override, "--out", str(out), "--size", "32"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and key in err and not out.exists()


def test_idle_keys_leave_frames_as_they_were():
    """Hard cases at probability or amount 0 draw nothing: the same bytes, colour included (each
    world in a client of its own, so body ids and the mask compare too)."""
    idle = tiny(
        backdrop={"row_end_distance": [3.0, 4.0], "row_end_height": [5.0, 6.0], "row_end_brightness": [0.3, 0.4]},
        terrain={"gap_grass_height": [0.3, 0.4]},
        sky={"glare_strength": [0.2, 0.3]},
    )
    base, same = (_frame_alone(raw, rng=np.random.default_rng(3)) for raw in (tiny(), idle))
    assert np.array_equal(base.rgb, same.rgb) and np.array_equal(base.depth, same.depth)
    assert np.array_equal(base.mask, same.mask) and np.array_equal(base.body_ids, same.body_ids)


def test_row_end_line_closes_the_view_and_is_background(bullet_client):
    spec = tiny(backdrop={"row_end_probability": 1.0, "row_end_distance": [1.0, 1.0], "row_end_height": [4.0, 4.0]})
    world = build_world(spec_from_dict(spec), bullet_client)
    line = _bodies(world, "backdrop_dark")
    assert line and world.n_triangles["row_ends"][0] > 0
    frame = _frame(world, s=2.0)
    on_line = np.isin(frame.body_ids, line)
    assert on_line.mean() > 0.05, "no row-end line in a frame looking down the row"
    # Right across the vanishing point: the middle column, above the ground, runs into the line.
    assert on_line[: 64 // 2, 28:36].any(axis=0).all()
    assert not frame.mask[on_line].any(), "row-end line labelled as crop"
    assert np.all(frame.depth[on_line] > 0)


def test_lush_grass_at_the_feet_is_background(bullet_client):
    world = build_world(spec_from_dict(tiny(terrain={"gap_grass": 80.0})), bullet_client)
    grass = _bodies(world, "lush")
    assert grass and world.n_triangles["gap_grass"][0] > world.n_triangles["gap_grass"][1] > 0
    frame = _frame(world, s=1.5, pitch=-0.35)  # look down at the strip ahead
    on_grass = np.isin(frame.body_ids, grass)
    assert on_grass[32:].mean() > 0.2, "no lush grass in the lower half of the frame"
    assert not frame.mask[on_grass].any(), "grass between the rows labelled as crop"
    green = frame.rgb[on_grass].astype(float).mean(axis=0)
    assert green[1] > green[0] and green[1] > green[2], f"lush grass is not green: {green}"


def test_glare_changes_colour_only():
    """With the sun ahead and glare, the sky is blown out; mask and depth are the geometry's."""
    a = _frame_alone(tiny(sky={"backlight_probability": 1.0}), pitch=0.2, rng=np.random.default_rng(1))
    b = _frame_alone(tiny(sky=LOW_SUN_AHEAD), pitch=0.2, rng=np.random.default_rng(1))
    assert b.stats["low_sun"] == "ahead" and b.stats["glare"] == 1.0 and a.stats["glare"] == 0.0
    assert np.array_equal(a.mask, b.mask) and np.array_equal(a.depth, b.depth)
    sky = b.body_ids < 0
    assert sky.mean() > 0.1
    assert b.rgb[sky].mean() > 235 and b.rgb[sky].mean() > a.rgb[sky].mean() + 10


def test_low_sun_behind_lights_the_rows_from_behind_the_camera(bullet_client):
    world = build_world(spec_from_dict(tiny(sky={"low_sun_behind_probability": 1.0})), bullet_client)
    renderer = Renderer(world, CameraModel(width=32, height=32))
    *_, yaw = world.gap_pose(world.eval_gap, 1.0)
    look = renderer._draw_look(np.random.default_rng(2), yaw)
    sun = np.asarray(look["light"]["lightDirection"])
    assert look["low_sun"] == "behind"
    assert sun[0] * math.cos(yaw) + sun[1] * math.sin(yaw) < 0, "the sun is not behind the camera"
    assert math.degrees(math.asin(sun[2] / np.linalg.norm(sun))) <= 25.0 + 1e-9


def test_blank_frames_have_empty_masks_and_others_keep_their_bytes():
    spec = spec_from_dict(tiny(capture={"blank_frames": 0.5}))
    plain = spec_from_dict(tiny())
    camera = CameraModel(width=48, height=48)
    blanks = [f for f in range(12) if is_blank(spec, 7, f)]
    assert 2 <= len(blanks) <= 10 and not any(is_blank(plain, 7, f) for f in range(12))
    with_blanks = FrameRenderer(spec, camera, 7, 10, noisy_depth=True)
    without = FrameRenderer(plain, camera, 7, 10, noisy_depth=True)
    try:
        for f in range(6):
            frame = with_blanks.render(f)
            if f in blanks:
                assert not frame.mask.any() and not frame.depth.any()
                assert frame.rgb.astype(float).std(axis=(0, 1)).max() < 4, "a blank frame is not uniform"
            else:
                other = without.render(f)
                assert np.array_equal(frame.rgb, other.rgb) and np.array_equal(frame.mask, other.mask)
    finally:
        with_blanks.close()
        without.close()


def test_old_world_names_load_the_renamed_worlds_with_a_warning(caplog):
    for old, new in RENAMED_WORLDS.items():
        assert new in shipped_names("worlds") and old not in shipped_names("worlds")
        with caplog.at_level(logging.WARNING):
            spec = load_world_spec(old)
        assert spec.name == new and f"{old} is now called {new}" in caplog.text


def test_held_out_worlds_are_never_trained_on():
    held_out = [n for n in shipped_names("worlds") if n.startswith("heldout_")]
    assert len(held_out) >= 5, held_out
    trained: set[str] = set()

    def collect(node) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                if key in ("train_worlds", "add_worlds"):  # a family's worlds and a fine-tuning stage's
                    trained.update(value)
                else:
                    collect(value)
        elif isinstance(node, list):
            for value in node:
                collect(value)

    for path in PIPELINES.glob("*.yaml"):
        collect(yaml.safe_load(path.read_text()))
    assert trained and not trained & set(held_out)
    seeds = {load_world_spec(n).seed for n in shipped_names("worlds") if not n.startswith("heldout_")}
    assert not seeds & {load_world_spec(n).seed for n in held_out}, "a held-out world shares a seed"
