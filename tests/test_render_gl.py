"""The gl render backend: same masks and depth as TinyRenderer, exact masks, analytic depth, and one
clear line for a bad backend name or a machine without EGL."""

from __future__ import annotations

import ctypes.util
import multiprocessing
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pybullet as p
import pytest
from synth_helpers import tiny, write_spec

from benchmarks.cli import main as benchmarks_main
from benchmarks.render_agreement import field_agreement, shadow_mask
from segmin.common import machine
from segmin.common.config import ConfigError
from segmin.data.synth import gl_raster, render
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.render import Renderer, sun_look
from segmin.data.synth.spec import load_world_spec, spec_from_dict
from segmin.data.synth.world import build_world
from segmin.nav_eval.sim.config import load_nav_config
from segmin.nav_eval.sim.factories import FieldContext

SMALL = CameraModel(width=48, height=48)
ROOT = Path(__file__).resolve().parents[1]


def test_gl_frames_agree_with_tinyrenderer():
    figures, row = field_agreement(spec_from_dict(tiny()), CameraModel(width=64, height=48), poses=3)
    assert figures.mask_iou_min >= 0.98, figures
    assert figures.ids_equal >= 0.98, figures
    assert figures.depth_median_m < 1e-3 and figures.depth_p95_m < 0.01, figures
    assert figures.rgb_mad < 8.0, figures  # same texels, tints and light; the sky is shared code
    assert min(figures.shadow_share.values()) > 0.05, figures  # the bench's sun casts shadows in view
    assert figures.shadow_iou >= 0.8, figures  # and they fall in the same places
    assert row.shape == (48, 5 * 64, 3)


@pytest.mark.parametrize("backend", ["tiny", "gl"])
def test_shadows_darken_direct_light_only_with_the_sun_within_the_far_plane(bullet_client, backend):
    """TinyRenderer's shadow pass sees the scene through the camera's near and far planes from the
    sun: the worlds' own sun (100 m away) shadows nothing, one 40 m away does; where it does, the
    direct light is 0.8 of the lit one in both backends."""
    world = build_world(spec_from_dict(tiny()), bullet_client)
    renderer = Renderer(world, SMALL, backend=backend)
    pose = renderer.render(*world.gap_pose(world.eval_gap, 1.0)).camera_pose
    sun = [0.5, 0.3, 0.81]
    assert not shadow_mask(renderer, pose, sun_look(sun, 100.0)).any()
    look = sun_look(sun, 40.0)
    shaded = shadow_mask(renderer, pose, look)
    assert 0.05 < shaded.mean() < 0.9
    lit, _, _ = renderer.rasterise(pose, {**look, "shadow": False})
    dark, _, _ = renderer.rasterise(pose, look)
    # Direct light alone, bright (and not saturated): the shadowed pixels keep 0.8 of it.
    look["light"] = {**look["light"], "lightAmbientCoeff": 0.0, "lightDiffuseCoeff": 1.0}
    direct_lit, _, _ = renderer.rasterise(pose, {**look, "shadow": False})
    direct_dark, _, _ = renderer.rasterise(pose, look)
    assert lit is not None and dark is not None and direct_lit is not None and direct_dark is not None
    bright = shaded & (direct_lit.min(axis=-1) > 30) & (direct_lit.max(axis=-1) < 255)
    assert bright.sum() > 10, bright.sum()
    assert abs(direct_dark[bright].sum() / direct_lit[bright].sum() - 0.8) < 0.02
    assert (dark[shaded] >= direct_dark[shaded]).all()  # the ambient term stays


def test_the_gl_backend_skips_a_sun_pass_that_sees_nothing_and_draws_the_same(bullet_client, monkeypatch):
    world = build_world(spec_from_dict(tiny()), bullet_client)
    renderer = Renderer(world, SMALL, backend="gl")
    pose = renderer.render(*world.gap_pose(world.eval_gap, 1.0)).camera_pose
    sun = [0.5, 0.3, 0.81]
    raster = renderer.raster
    assert raster is not None
    assert not raster._sun_sees_something(SMALL, sun_look(sun, 100.0)["light"])
    assert raster._sun_sees_something(SMALL, sun_look(sun, 40.0)["light"])
    skipped, _, _ = renderer.rasterise(pose, sun_look(sun, 100.0))
    monkeypatch.setattr(raster, "_sun_sees_something", lambda *_: True)
    drawn, _, _ = renderer.rasterise(pose, sun_look(sun, 100.0))
    assert skipped is not None and np.array_equal(skipped, drawn)


def test_the_gl_backend_draws_shadow_frames(bullet_client):
    """`render.shadow_probability` picks the frames with shadows in the gl backend too."""
    spec = spec_from_dict(tiny(render={"shadow_probability": 1.0}, sky={"overcast_probability": 0.0}))
    renderer = Renderer(build_world(spec, bullet_client), SMALL, backend="gl")
    frame = renderer.render(*renderer.world.gap_pose(renderer.world.eval_gap, 1.0), rng=np.random.default_rng(0))
    assert frame.stats["shadow"]


def test_gl_mask_is_exactly_the_plant_bodies(bullet_client):
    world = build_world(spec_from_dict(tiny()), bullet_client)
    renderer = Renderer(world, SMALL, backend="gl")
    x, y, yaw = world.gap_pose(world.eval_gap, 1.0)
    frame = renderer.render(x, y, yaw)
    assert 0.05 < frame.mask.mean() < 0.95, "both rows and free space should be in view"
    assert np.array_equal(frame.mask, np.isin(frame.body_ids, list(world.vegetation_ids)))
    renderer.hidden = set(world.vegetation_ids)
    without = renderer.render(x, y, yaw)
    assert not without.mask.any()
    assert np.array_equal(frame.depth != without.depth, frame.mask)


@pytest.mark.parametrize("multi_draw", [True, False])
def test_a_frame_without_colour_has_the_colour_frames_depth_mask_and_ids(bullet_client, multi_draw):
    """The depth + ids pass (one indirect multi-draw, or one draw per body on a GL 3.3 driver)
    draws the full pass's depth and ids pixel for pixel, and leaves the image out."""
    world = build_world(spec_from_dict(tiny()), bullet_client)
    renderer = Renderer(world, SMALL, backend="gl")
    renderer.raster.multi_draw = multi_draw and renderer.raster.ctx.version_code >= 430
    for along in (0.5, 1.5, 3.0):
        x, y, yaw = world.gap_pose(world.eval_gap, along)
        full, bare = renderer.render(x, y, yaw), renderer.render(x, y, yaw, colour=False)
        assert bare.rgb is None and full.rgb is not None and full.mask.any()
        assert np.array_equal(bare.depth, full.depth) and np.array_equal(bare.body_ids, full.body_ids)
        assert np.array_equal(bare.mask, full.mask)


@pytest.mark.parametrize("multi_draw", [True, False])
def test_the_colour_pass_draws_each_bodys_tint_and_texture_of_now(bullet_client, multi_draw):
    """Tints and textures reach the one-draw colour pass when the renderer retints the world,
    whether its rasteriser existed before (`set_looks` on retint) or is made after (at its first
    frame); one draw per body (a GL 3.3 driver) gives the same image."""
    world = build_world(spec_from_dict(tiny()), bullet_client)
    pose = world.gap_pose(world.eval_gap, 1.0)
    before = Renderer(world, SMALL, backend="gl")
    first = before.render(*pose).rgb
    before.randomize_appearance(np.random.default_rng(5))
    after = Renderer(world, SMALL, backend="gl")
    after.randomize_appearance(np.random.default_rng(5))
    after.raster.multi_draw = multi_draw and after.raster.ctx.version_code >= 430
    retinted = before.render(*pose).rgb
    assert not np.array_equal(first, retinted)
    assert np.array_equal(retinted, after.render(*pose).rgb)


def test_render_threads_follow_this_processs_share_of_the_cores(monkeypatch):
    """A pool's worker renders with its share of the cores (`serve` notes it), a process alone
    with all it may use; what the user set in LP_NUM_THREADS stays."""
    monkeypatch.delenv(machine.WORKER_CORES_VARIABLE, raising=False)
    assert machine.cores_for_this_process() == machine.usable_cores()
    monkeypatch.setenv(machine.WORKER_CORES_VARIABLE, "1")
    assert machine.cores_for_this_process() == 1
    monkeypatch.setenv(machine.WORKER_CORES_VARIABLE, "many")  # not a count: ignored
    assert machine.cores_for_this_process() == machine.usable_cores()


def test_tinyrenderer_frames_without_colour_leave_only_the_image_out(bullet_client):
    world = build_world(spec_from_dict(tiny()), bullet_client)
    renderer = Renderer(world, SMALL, backend="tiny")
    pose = world.gap_pose(world.eval_gap, 1.0)
    full, bare = renderer.render(*pose), renderer.render(*pose, colour=False)
    assert bare.rgb is None and np.array_equal(bare.depth, full.depth) and np.array_equal(bare.mask, full.mask)


def test_a_frame_without_colour_refuses_a_randomised_look(bullet_client):
    world = build_world(spec_from_dict(tiny()), bullet_client)
    renderer = Renderer(world, SMALL, backend="gl")
    with pytest.raises(ValueError, match="colour=False"):
        renderer.render(*world.gap_pose(world.eval_gap, 1.0), rng=np.random.default_rng(0), colour=False)


def test_the_backend_is_validated():
    assert load_world_spec("straight_vineyard", ["render.backend=gl"]).render.backend == "gl"
    with pytest.raises(ConfigError, match="render.backend"):
        load_world_spec("straight_vineyard", ["render.backend=egl"])
    client = p.connect(p.DIRECT)
    try:
        with pytest.raises(ValueError, match="render backend"):
            Renderer(build_world(spec_from_dict(tiny()), client), SMALL, backend="vulkan")
    finally:
        p.disconnect(client)


def test_no_egl_is_one_line(monkeypatch):
    import moderngl

    def refuse(**_kwargs):
        raise Exception("libEGL.so: cannot open shared object file")  # what glcontext raises

    monkeypatch.setattr(moderngl, "create_context", refuse)
    with pytest.raises(OSError, match=r"render.backend=gl found no headless OpenGL .* libEGL.so"):
        gl_raster.open_context()


@pytest.fixture
def fresh_fallback(monkeypatch):
    """A process that has not yet probed for EGL nor said the fallback line."""
    monkeypatch.setattr(render, "_fallback_said", [])
    gl_raster.headless_gl_problem.cache_clear()
    yield
    gl_raster.headless_gl_problem.cache_clear()


def _fallback_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "render.backend=auto" in r.getMessage()]


def test_auto_is_gl_where_egl_loads_and_tinyrenderer_with_one_line_where_it_does_not(
    bullet_client, monkeypatch, caplog, fresh_fallback
):
    world = build_world(spec_from_dict(tiny()), bullet_client)
    assert world.spec.render.backend == "auto"
    assert Renderer(world, SMALL).backend == "gl" and not _fallback_lines(caplog)
    gl_raster.headless_gl_problem.cache_clear()
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None if name == "EGL" else "libGL.so.1")
    renderers = [Renderer(world, SMALL) for _ in range(2)]
    assert [r.backend for r in renderers] == ["tiny", "tiny"]
    assert renderers[0].render(*world.gap_pose(world.eval_gap, 1.0)).mask.any()
    assert _fallback_lines(caplog) == [
        "render.backend=auto: no headless OpenGL through EGL (no libEGL found (Mesa's libegl1 and "
        "libgl1-mesa-dri provide it)); rendering with TinyRenderer, several times slower "
        "(render.backend=tiny says so and hides this line)"
    ]
    assert Renderer(world, SMALL, backend="gl").backend == "gl"  # asked for by name: no fallback


def test_auto_turns_to_tinyrenderer_when_the_context_fails_at_the_first_frame(
    bullet_client, monkeypatch, caplog, fresh_fallback
):
    """EGL found but no context opens (no driver or device): the first frame says so once and is
    TinyRenderer's, the same as a tiny renderer's; a gl backend asked for by name stops with one line."""

    def refuse(_world):
        raise gl_raster.NoHeadlessGl("eglInitialize failed")

    world = build_world(spec_from_dict(tiny()), bullet_client)
    monkeypatch.setattr(gl_raster, "GlRasteriser", refuse)
    pose = world.gap_pose(world.eval_gap, 1.0)
    auto = Renderer(world, SMALL)
    frame = auto.render(*pose)
    assert auto.backend == "tiny" and len(_fallback_lines(caplog)) == 1
    reference = Renderer(world, SMALL, backend="tiny").render(*pose)
    assert np.array_equal(frame.rgb, reference.rgb) and np.array_equal(frame.depth, reference.depth)
    with pytest.raises(OSError, match=r"render.backend=gl found no headless OpenGL .* eglInitialize failed"):
        Renderer(world, SMALL, backend="gl").render(*pose)
    assert len(_fallback_lines(caplog)) == 1


def test_a_forked_process_is_told_to_spawn_instead_of_hanging(bullet_client):
    """OpenGL does not survive a fork: a child of a process that rendered with gl says so in one
    line (its first frame used to wait forever)."""
    world = build_world(spec_from_dict(tiny()), bullet_client)
    Renderer(world, SMALL, backend="gl").render(*world.gap_pose(world.eval_gap, 1.0))
    child = multiprocessing.get_context("fork").Process(target=_render_in_child)
    child.start()
    child.join(timeout=120)
    if child.is_alive():
        child.kill()
    assert child.exitcode == 3, child.exitcode  # 3: refused with the message; None: it hung


def _render_in_child() -> None:
    client = p.connect(p.DIRECT)
    try:
        world = build_world(spec_from_dict(tiny()), client)
        Renderer(world, SMALL, backend="gl").render(*world.gap_pose(world.eval_gap, 1.0))
    except OSError as err:
        os._exit(3 if "forked" in str(err) and "spawn" in str(err) else 4)
    os._exit(5)


def test_agreement_bench_refuses_to_overwrite_its_sheet(tmp_path, capsys):
    sheet = tmp_path / "sheet.png"
    sheet.write_bytes(b"keep")
    assert benchmarks_main(["render-agreement", "--sheet", str(sheet)]) == 2
    assert "--force" in capsys.readouterr().err and sheet.read_bytes() == b"keep"


def test_the_nav_config_picks_the_backend_of_every_field(tmp_path):
    field = write_spec(tmp_path / "tiny.yaml", tiny())
    for backend in (None, "tiny", "gl"):
        overrides = [] if backend is None else [f"render.backend={backend}"]
        ctx = FieldContext(field, load_nav_config(None, overrides))
        try:
            expected = backend or "gl"  # None: the field's own, auto: gl where EGL loads
            assert ctx.renderer.backend == expected
            assert (ctx.renderer.raster is not None) == (expected == "gl")
            # The depth noise follows the backend auto resolved to: fields of noise with gl.
            assert ctx.camera.depth_noise_sampling == ("field" if expected == "gl" else "pixels")
        finally:
            ctx.close()


def test_torch_and_triton_load_after_a_gl_frame():
    """llvmpipe's LLVM and triton's must not meet: a process that renders with gl and then imports
    torch's compiler (training after rendering, the test suite) used to segfault."""
    code = (
        "import sys; sys.path.insert(0, 'tests')\n"
        "import importlib.util, pybullet as p\n"
        "from synth_helpers import tiny\n"
        "from segmin.data.synth.camera import CameraModel\n"
        "from segmin.data.synth.render import Renderer\n"
        "from segmin.data.synth.spec import spec_from_dict\n"
        "from segmin.data.synth.world import build_world\n"
        "world = build_world(spec_from_dict(tiny()), p.connect(p.DIRECT))\n"
        "Renderer(world, CameraModel(width=16, height=16), backend='gl').render(*world.gap_pose(0, 1.0))\n"
        "assert importlib.util.find_spec('triton'), 'triton is not installed: nothing to check'\n"
        "import triton\n"
        "print('ok')\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], check=False, capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert result.returncode == 0 and result.stdout.strip().endswith("ok"), result.stderr[-2000:]
