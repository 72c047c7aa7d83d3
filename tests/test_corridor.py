"""SegCorridor (nav_eval.corridor): exact geometry on analytic scenes, properties, bad input."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from segmin.nav_eval.demo.scenes import DemoScene, render_scene
from segmin.nav_eval.runtime.corridor import CameraGeometry, CorridorConfig, CorridorNavigator, fit_parallel_rows
from segmin.nav_eval.runtime.corridor.trunk_mode import ground_plane
from segmin.nav_eval.runtime.follower import RowFollower
from segmin.nav_eval.runtime.methods import METHOD_STATISTICS
from segmin.nav_eval.sim.config import load_nav_config
from segmin.nav_eval.sim.factories import make_navigator

SIZE = 96


def scene_camera(size: int = SIZE) -> CameraGeometry:
    """The analytic demo scenes' camera: square pixels, centre (size - 1) / 2, 0.4 m, 15 deg up."""
    focal = (size / 2) / math.tan(math.radians(69.0) / 2)
    centre = (size - 1) / 2
    return CameraGeometry(
        width=size, height=size, fx=focal, fy=focal, cx=centre, cy=centre, mount_height=0.4, tilt_deg=15.0
    )


def vine_scene(offset: float = 0.0, yaw_deg: float = 0.0, holes: float = 0.25, half_gap: float = 0.9) -> DemoScene:
    return DemoScene(
        "vines",
        half_gap=half_gap,
        foliage_low=0.4,
        foliage_high=2.0,
        canopy_base=None,
        row_length=20.0,
        lateral_offset=offset,
        yaw=math.radians(yaw_deg),
        hole_fraction=holes,
    )


def settle(navigator: CorridorNavigator, scene: DemoScene, steps: int = 3):
    mask, depth = render_scene(scene, size=SIZE)
    for _ in range(steps):
        command = navigator.step(mask, depth)
    return command


def navigator(**changes) -> CorridorNavigator:
    return CorridorNavigator(CorridorConfig(depth_threshold=5.0, **changes), scene_camera())


# ---- exact ---------------------------------------------------------------------------------------


class TiltedGround:
    """The plane z = a x + b y: a world on which the robot rolls and pitches."""

    def __init__(self, a: float, b: float) -> None:
        self.a, self.b = a, b

    def terrain_height(self, x, y):
        return self.a * np.asarray(x, float) + self.b * np.asarray(y, float)

    def terrain_normal(self, x, y):
        n = np.array([-self.a, -self.b, 1.0])
        return n / np.linalg.norm(n)


@pytest.mark.parametrize("a, b, yaw", [(0.0, 0.12, 0.0), (0.1, 0.0, 0.7), (-0.08, 0.15, -2.0)])
def test_levelling_with_the_imu_recovers_the_world_point_the_renderer_saw(a, b, yaw):
    """The renderer's camera rides on the terrain (data.synth.render.camera_pose); the IMU's
    (roll, pitch) from the robot state (nav_eval.robot.imu_attitude) undo exactly that tilt."""
    from segmin.data.synth.camera import CameraModel
    from segmin.data.synth.render import camera_pose
    from segmin.nav_eval.sim.robot import Robot, imu_attitude

    ground = TiltedGround(a, b)
    cam = CameraModel()
    geometry = CameraGeometry.from_camera(cam)
    x0, y0 = 3.0, -1.0
    robot = Robot(terrain_height=ground.terrain_height, terrain_normal=ground.terrain_normal)
    attitude = imu_attitude(robot.reset(x0, y0, yaw))
    pose = camera_pose(ground, cam, x0, y0, yaw)
    base = np.array([x0, y0, float(ground.terrain_height(x0, y0))])
    n = ground.terrain_normal(x0, y0)
    f = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    f -= f.dot(n) * n
    heading = math.atan2(f[1], f[0])  # the body's level frame (differs from yaw by about a b)
    rng = np.random.default_rng(0)
    for _ in range(20):
        p_robot = np.array([rng.uniform(1.0, 8.0), rng.uniform(-2.0, 2.0), rng.uniform(0.0, 2.5)])
        c, s = math.cos(heading), math.sin(heading)
        world = base + np.array([c * p_robot[0] - s * p_robot[1], s * p_robot[0] + c * p_robot[1], p_robot[2]])
        pc = pose[:3, :3].T @ (world - pose[:3, 3])
        col = geometry.cx + geometry.fx * pc[0] / pc[2]
        row = geometry.cy + geometry.fy * pc[1] / pc[2]
        levelled = geometry.robot_frame(np.array([row]), np.array([col]), np.array([pc[2]]), attitude)
        assert np.allclose(np.concatenate(levelled), p_robot, atol=1e-9)
        tilted = geometry.robot_frame(np.array([row]), np.array([col]), np.array([pc[2]]))
        assert np.max(np.abs(np.concatenate(tilted) - p_robot)) > 0.01  # the tilt matters


def test_a_level_attitude_changes_nothing():
    camera = scene_camera()
    rows, cols = np.array([10.0, 50.0, 90.0]), np.array([5.0, 48.0, 80.0])
    depth = np.array([2.0, 5.0, 9.0])
    assert np.allclose(camera.robot_frame(rows, cols, depth, (0.0, 0.0)), camera.robot_frame(rows, cols, depth))


@pytest.mark.parametrize("bad", [(0.1,), (0.1, 0.2, 0.3), (float("nan"), 0.0), (0.0, 2.0), "level", (None, 0.0)])
def test_an_invalid_attitude_is_refused_by_name(bad):
    nav = navigator()
    mask, depth = render_scene(vine_scene(), size=SIZE)
    with pytest.raises(ValueError, match="attitude must be \\(roll, pitch\\)"):
        nav.step(mask, depth, bad)
    follower = RowFollower(None, nav)
    with pytest.raises(ValueError, match="attitude must be"):
        follower.step(None, depth, 0.0, mask=mask, attitude=bad)


def test_back_projection_of_a_ground_pixel_lands_on_the_ground():
    camera = scene_camera()
    row, col = SIZE - 1.0, (SIZE - 1) / 2
    theta = math.radians(camera.tilt_deg)
    vertical = (row - camera.cy) / camera.fy
    depth = camera.mount_height / (vertical * math.cos(theta) - math.sin(theta))  # h = 0
    x, y, h = camera.robot_frame(np.array([row]), np.array([col]), np.array([depth]))
    assert h[0] == pytest.approx(0.0, abs=1e-9)
    assert y[0] == pytest.approx(0.0, abs=1e-12)
    assert x[0] > 0


@pytest.mark.parametrize("offset,yaw_deg", [(0.0, 0.0), (0.3, 8.0), (-0.25, -5.0), (0.1, 12.0)])
def test_centreline_of_an_analytic_row_is_exact(offset, yaw_deg):
    command = settle(navigator(), vine_scene(offset, yaw_deg))
    assert command.mode == "both"
    a, b, c = command.centre  # the default quadratic: straight rows give c = 0
    assert a == pytest.approx(-offset, abs=0.02)
    assert b == pytest.approx(-math.tan(math.radians(yaw_deg)), abs=0.01)
    assert c == pytest.approx(0.0, abs=0.003)


def test_steers_back_towards_the_centre():
    left = settle(navigator(), vine_scene(0.3))
    right = settle(navigator(), vine_scene(-0.3))
    assert left.omega < 0 < right.omega  # left of the centre: turn right (negative omega)
    assert left.omega == pytest.approx(-right.omega, rel=0.05)
    centred = settle(navigator(), vine_scene(0.0))
    assert centred.omega == pytest.approx(0.0, abs=1e-6)
    assert centred.v == pytest.approx(0.5 * (1 - 0.5**3), rel=1e-6)  # three EMA steps from rest


def test_one_row_seen_keeps_the_width_learnt_from_both():
    nav = navigator()
    settle(nav, vine_scene(0.0))
    mask, depth = render_scene(vine_scene(0.0), size=SIZE)
    right_half = mask.copy()
    right_half[:, : SIZE // 2] = False  # the left row is lost (e.g. a gap)
    for _ in range(3):
        command = nav.step(right_half, depth)
    assert command.mode == "one_side"
    assert command.centre[0] == pytest.approx(0.0, abs=0.05)


def right_row_seen_only_beyond(start: float, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """A straight vine row seen from `offset` m left of its centre with the right row's vegetation
    nearer than `start` m (planar depth) missing, as through a run of missing plants; and the
    10th percentile of that row's remaining depths."""
    mask, depth = render_scene(vine_scene(offset, holes=0.0), size=SIZE)
    right = np.zeros_like(mask)
    right[:, SIZE // 2 :] = True
    mask = mask & ~(right & (depth < start))
    return mask, depth, float(np.quantile(depth[mask & right], 0.1))


@pytest.mark.parametrize("offset", [0.0, 0.2])
def test_a_row_seen_only_far_ahead_is_left_out_beside_one_seen_near(offset):
    """row_start_max: a row whose points start beyond it is not fitted while the other row's start
    nearer; the centre is then the near row's, moved by half the running width."""
    mask, depth, far_start = right_row_seen_only_beyond(3.0, offset)
    assert far_start > 2.5
    for limit, mode in ((math.inf, "both"), (2.0, "one_side")):
        nav = navigator(row_start_max=limit)
        settle(nav, vine_scene(offset, holes=0.0))  # the width, from both rows
        for _ in range(3):
            command = nav.step(mask, depth)
        assert command.mode == mode
        assert command.centre[0] == pytest.approx(-offset, abs=0.05)


def test_a_row_seen_from_near_is_fitted_though_most_of_it_lies_beyond_row_start_max():
    """row_start_max reads where a row starts (the 10th percentile of its points' x), not where most
    of it lies: the right row, seen whole up to the depth threshold, starts nearer than 1.8 m
    though its median point is beyond; beside the left row, seen only up to 2.2 m, both are fitted."""
    offset, limit = 0.2, 1.8
    mask, depth = render_scene(vine_scene(offset, holes=0.0), size=SIZE)
    left = np.zeros_like(mask)
    left[:, : SIZE // 2] = True
    mask = mask & ~(left & (depth > 2.2))
    rows, cols = np.nonzero(mask & ~left & (depth <= 5.0))
    x = scene_camera().robot_frame(rows, cols, depth[rows, cols])[0]
    assert np.quantile(x, 0.1) < limit - 0.2 and np.median(x) > limit + 0.2
    nav = navigator(row_start_max=limit)
    settle(nav, vine_scene(offset, holes=0.0))
    for _ in range(3):
        command = nav.step(mask, depth)
    assert command.mode == "both"
    assert command.centre[0] == pytest.approx(-offset, abs=0.05)


def test_two_rows_that_both_start_far_are_both_fitted():
    """Only a row that starts far beside a near one is left out: both far is no evidence of a gap."""
    mask, depth = render_scene(vine_scene(0.0, holes=0.0), size=SIZE)
    nav = navigator(row_start_max=1.0)
    settle(nav, vine_scene(0.0, holes=0.0))
    assert nav.step(mask & (depth >= 3.0), depth).mode == "both"


def test_rows_seen_through_gaps_do_not_set_the_first_width():
    """30 % missing vines (sweep, 2026-12-04): beyond 2.2 m both bordering rows have a gap and the
    next rows, 3.1 m out, show through it. The first fit must find the bordering rows (1.8 m apart),
    not lines between them and the next rows (before the fix: no fit at all here; in the field a
    first width of 2.6 m, and the fits drifted across the corridor)."""
    near_mask, near_depth = render_scene(vine_scene(), size=SIZE)
    far_mask, far_depth = render_scene(vine_scene(half_gap=3.1, holes=0.0), size=SIZE)
    through_gap = near_mask & (near_depth > 2.2)
    assert np.count_nonzero(far_mask & through_gap) > 200  # the next rows are in view
    mask, depth = np.where(through_gap, far_mask, near_mask), np.where(through_gap, far_depth, near_depth)
    command = navigator().step(mask, depth)
    assert command.mode == "both"
    assert command.centre == pytest.approx((0.0, 0.0, 0.0), abs=0.01)
    one_row = navigator()
    one_row.step(mask, depth)
    mask[:, : SIZE // 2] = False  # then the left row is lost: the learnt width (1.8 m) places the centre
    for _ in range(3):
        command = one_row.step(mask, depth)
    assert command.mode == "one_side" and command.centre[0] == pytest.approx(0.0, abs=0.03)


def test_fallback_without_rows_is_segmind_and_is_counted():
    nav = navigator()
    mask = np.zeros((SIZE, SIZE), dtype=bool)
    depth = np.full((SIZE, SIZE), 3.0, dtype=np.float32)
    command = nav.step(mask, depth)
    assert command.mode == "fallback" and command.centre is None and command.valid
    assert command.target_column == pytest.approx((SIZE - 1) / 2)
    assert nav.mode_counts == {"both": 0, "one_side": 0, "trunks": 0, "fallback": 1}
    nav.reset()
    assert sum(nav.mode_counts.values()) == 0


def test_stop_is_invalid_and_restarts_from_rest():
    nav = navigator()
    settle(nav, vine_scene(0.2))
    stop = nav.stop()
    assert not stop.valid and stop.v == 0.0 and stop.omega == 0.0
    after = settle(nav, vine_scene(0.2), steps=1)
    fresh = settle(navigator(), vine_scene(0.2), steps=1)  # one EMA step from rest
    assert after.v == pytest.approx(fresh.v) and after.omega == pytest.approx(fresh.omega)


def test_robust_line_fit_ignores_outliers():
    rng = np.random.default_rng(0)
    x = rng.uniform(1, 5, 400)
    y = 0.8 + 0.05 * x + rng.normal(0, 0.01, x.shape)
    y[:40] = rng.uniform(-0.5, 0.3, 40)  # 10 % clutter hanging into the row
    fit = fit_parallel_rows([(x, y)], trim=2.5, iterations=2)
    (a, b) = fit.row(0)
    assert a == pytest.approx(0.8, abs=0.02) and b == pytest.approx(0.05, abs=0.01)
    assert fit.kept[0] < 400
    bend = 0.8 + 0.05 * x + 0.02 * x * x
    exact = fit_parallel_rows([(x, bend)], trim=2.5, iterations=2, degree=2)
    assert exact.row(0) == pytest.approx((0.8, 0.05, 0.02), abs=1e-9)
    assert fit_parallel_rows([(np.ones(5), np.arange(5.0))], trim=2.5, iterations=2) is None
    assert fit_parallel_rows([(x, y), (np.zeros(0), np.zeros(0))], trim=2.5, iterations=2) is None


def test_parallel_rows_share_their_shape_and_keep_their_offsets():
    rng = np.random.default_rng(1)
    xl, xr = rng.uniform(0.5, 8, 300), rng.uniform(0.5, 8, 200)
    shape = lambda x: 0.03 * x + 0.01 * x * x  # noqa: E731  (a bend to the left)
    fit = fit_parallel_rows([(xl, 1.2 + shape(xl)), (xr, -1.1 + shape(xr))], trim=2.5, iterations=2, degree=2)
    assert fit.offsets == pytest.approx((1.2, -1.1), abs=1e-9)
    assert fit.shape == pytest.approx((0.03, 0.01), abs=1e-9)
    assert fit.kept == (300, 200)


def test_a_bend_must_be_seen_in_both_rows():
    """One row curving away (the next row showing through a gap, canes hanging in) is not a bend
    of the corridor: the pair is fitted as lines; both rows curving the same way is a bend."""
    rng = np.random.default_rng(2)
    xl, xr = rng.uniform(0.5, 8, 400), rng.uniform(0.5, 8, 400)
    noise = lambda x: rng.normal(0, 0.03, x.shape)  # noqa: E731
    kwargs = {"trim": 2.5, "iterations": 2, "degree": 2, "significance": 3.0}
    one = fit_parallel_rows([(xl, 1.2 + 0.02 * xl * xl + noise(xl)), (xr, -1.2 + noise(xr))], **kwargs)
    assert one.shape[1] == 0.0
    both = fit_parallel_rows(
        [(xl, 1.2 + 0.02 * xl * xl + noise(xl)), (xr, -1.2 + 0.02 * xr * xr + noise(xr))], **kwargs
    )
    assert both.shape[1] == pytest.approx(0.02, abs=0.002) and both.offsets == pytest.approx((1.2, -1.2), abs=0.03)
    opposite = fit_parallel_rows(
        [(xl, 1.2 + 0.02 * xl * xl + noise(xl)), (xr, -1.2 - 0.02 * xr * xr + noise(xr))], **kwargs
    )
    assert opposite.shape[1] == 0.0


def test_the_quadratic_term_is_kept_only_when_significant():
    rng = np.random.default_rng(3)
    x = rng.uniform(0.5, 8, 600)
    straight = 1.0 + rng.normal(0, 0.05, x.shape)
    bent = 1.0 + x * x / (2 * 35.0) + rng.normal(0, 0.05, x.shape)  # a 35 m bend
    kwargs = {"trim": 2.5, "iterations": 2, "degree": 2}
    free = fit_parallel_rows([(x, straight)], **kwargs)
    gated = fit_parallel_rows([(x, straight)], significance=1e6, **kwargs)
    assert free.shape[1] != 0.0 and gated.shape[1] == 0.0 and len(gated.shape) == 2
    assert fit_parallel_rows([(x, bent)], significance=3.0, **kwargs).shape[1] == pytest.approx(1 / 70.0, rel=0.1)
    assert fit_parallel_rows([(x, straight)], significance=3.0, **kwargs).shape[1] == 0.0


# ---- properties ----------------------------------------------------------------------------------


@settings(max_examples=15, deadline=None)
@given(offset=st.floats(-0.4, 0.4), yaw=st.floats(-10, 10))
def test_mirrored_scene_gives_mirrored_command(offset, yaw):
    mask, depth = render_scene(vine_scene(offset, yaw, holes=0.0), size=SIZE)
    a = navigator().step(mask, depth)
    b = navigator().step(mask[:, ::-1].copy(), depth[:, ::-1].copy())
    assert a.mode == b.mode
    # The camera's centre column is (SIZE - 1) / 2, so mirroring the image mirrors the scene.
    assert a.omega == pytest.approx(-b.omega, abs=1e-6)
    assert a.v == pytest.approx(b.v, abs=1e-6)


@settings(max_examples=15, deadline=None)
@given(offset=st.floats(-0.4, 0.4), yaw=st.floats(-15, 15), holes=st.floats(0.0, 0.6))
def test_commands_stay_within_limits(offset, yaw, holes):
    command = settle(navigator(), vine_scene(offset, yaw, holes), steps=1)
    assert 0.0 <= command.v <= 0.5 and abs(command.omega) <= 1.0
    assert math.isfinite(command.v) and math.isfinite(command.omega)


def test_invalid_depth_is_no_reading():
    mask, depth = render_scene(vine_scene(0.2), size=SIZE)
    clean = navigator().step(mask, depth)
    poisoned = depth.copy()
    poisoned[::7, ::5] = np.nan
    poisoned[1::9, ::3] = -1.0
    poisoned[2::6, 1::4] = np.inf
    noisy = navigator().step(mask, poisoned)
    assert math.isfinite(noisy.omega)
    assert noisy.centre[0] == pytest.approx(clean.centre[0], abs=0.03)


# ---- wiring and bad input ------------------------------------------------------------------------


def test_built_by_the_evaluation_with_the_config_section():
    config = load_nav_config(overrides=["corridor.lookahead=3.0"])
    nav = make_navigator("segcorridor", 5.0, config)
    assert isinstance(nav, CorridorNavigator)
    assert nav.config.lookahead == 3.0 and nav.config.method == "segcorridor"
    assert nav.camera.width == 224 and nav.camera.mount_height == pytest.approx(0.40)


@pytest.mark.parametrize("key", ["trunk_stride", "significance", "roof_min_height"])
def test_a_setting_now_fixed_is_named_with_its_value_at_load(key):
    """The estimator's inner settings are constants now: an old config that sets one is told so."""
    with pytest.raises(ValueError, match=rf"corridor.*{key}.*now fixed at"):
        load_nav_config(overrides=[f"corridor.{key}=2"])


def test_unknown_corridor_key_is_refused_at_load():
    with pytest.raises(ValueError, match="corridor: unknown key"):
        load_nav_config(overrides=["corridor.look_ahead=3"])


@pytest.mark.parametrize(
    "changes,field",
    [
        ({"x_min": 9.0}, "x_min"),
        ({"h_min": 5.0}, "h_min"),
        ({"lookahead": 0.0}, "lookahead"),
        ({"stride": 0}, "stride"),
        ({"ema_lambda": 1.5}, "ema_lambda"),
        ({"min_points": 2.5}, "min_points"),
        ({"roof_opening": -1.0}, "roof_opening"),
        ({"roof_opening": 6.0}, "roof_opening"),
        ({"row_start_max": 0.3}, "row_start_max"),
        ({"row_start_max": float("nan")}, "row_start_max"),
        ({"row_start_max": True}, "row_start_max"),
    ],
)
def test_bad_settings_name_the_field(changes, field):
    with pytest.raises(ValueError, match=field):
        CorridorConfig(depth_threshold=5.0, **changes)


@pytest.mark.parametrize(
    "refused, accepted, message",
    [
        # Both rows need min_points each of the at most max_points kept points.
        ({"min_points": 301}, {"min_points": 300}, r"corridor.min_points \(301\).*corridor.max_points \(600\)"),
        ({"max_points": 59}, {"max_points": 60}, r"corridor.min_points \(30\).*corridor.max_points \(59\)"),
        # A row's points must span 1 m along x, within x_min..x_max (0.5..8.0 m by default).
        ({"x_max": 1.4}, {"x_max": 1.5}, r"corridor.x_min..x_max \(0.5..1.4\) is shorter than the 1.0 m"),
        # The roof starts at 1.5 m: with h_min there every kept point is roof, no row fit, ever.
        ({"h_min": 1.5}, {"h_min": 1.45}, r"corridor.h_min \(1.5\) must be below 1.5 m, where the roof starts"),
    ],
)
def test_limits_that_leave_no_row_ever_seen_are_refused(refused, accepted, message):
    """Each limit is valid alone; together they would turn every frame into the fallback, so a
    SegCorridor run would silently be a SegMinD run."""
    with pytest.raises(ValueError, match=message):
        CorridorConfig(depth_threshold=5.0, **refused)
    CorridorConfig(depth_threshold=5.0, **accepted)


def test_bad_camera_and_frames_are_refused():
    with pytest.raises(ValueError, match="fx"):
        dataclasses.replace(scene_camera(), fx=-1.0)
    with pytest.raises(ValueError, match="tilt"):
        dataclasses.replace(scene_camera(), tilt_deg=95.0)
    nav = navigator()
    with pytest.raises(ValueError, match="camera geometry"):
        nav.step(np.zeros((SIZE, SIZE + 8), bool), np.ones((SIZE, SIZE + 8), np.float32))
    with pytest.raises(ValueError, match="same shape"):
        nav.step(np.zeros((SIZE, SIZE), bool), np.ones((SIZE, SIZE - 1), np.float32))


def test_the_runtime_refuses_frames_that_do_not_fit_the_declared_camera():
    """Refused when the frame arrives, not frames later at the next command."""
    follower = RowFollower(None, navigator())
    with pytest.raises(ValueError, match=f"depth is 64x{SIZE} but the navigator's camera is {SIZE}x{SIZE}"):
        follower.step(None, np.ones((SIZE, 64), np.float32), 0.0, mask=np.zeros((SIZE, 64), bool))


def test_the_mode_shares_are_its_statistics():
    nav = navigator()
    assert nav.statistics() == {}  # no command yet
    settle(nav, vine_scene(0.2))  # three commands on both rows
    nav.step(np.zeros((SIZE, SIZE), bool), np.full((SIZE, SIZE), 3.0, np.float32))  # no rows: fallback
    stats = nav.statistics()
    assert tuple(stats) == METHOD_STATISTICS["segcorridor"]
    assert stats == {"one_side_share": 0.0, "trunk_share": 0.0, "fallback_share": 0.25}
    nav.reset()
    assert nav.statistics() == {}


def test_the_runtime_refuses_segcorridor_without_depth():
    follower = RowFollower(None, navigator())
    with pytest.raises(ValueError, match="segcorridor needs depth"):
        follower.step(None, None, 0.0, mask=np.zeros((SIZE, SIZE), bool))


def test_under_a_roof_with_an_opening_it_steers_exactly_as_segmind():
    from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig

    # A pergola: the foliage starts above the robot and closes over the row but for a free band.
    roofed = dataclasses.replace(vine_scene(0.3, 5.0), foliage_low=1.4, canopy_base=2.2, canopy_opening=1.0)
    mask, depth = render_scene(roofed, size=SIZE)
    corridor, segmind = navigator(), Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0))
    for _ in range(3):
        ours, paper = corridor.step(mask, depth), segmind.step(mask, depth)
        assert ours.mode == "fallback"
        assert ours.v == pytest.approx(paper.v) and ours.omega == pytest.approx(paper.omega)
        assert ours.target_column == pytest.approx(paper.target_column)


def orchard_scene(offset: float = 0.0, yaw_deg: float = 0.0, opening: float = 0.0) -> DemoScene:
    """Merged crowns from 1.6 m over a 7 m corridor, trunks every 4 m in both row lines."""
    return DemoScene(
        "orchard",
        half_gap=3.5,
        foliage_low=1.6,
        foliage_high=4.0,
        canopy_base=2.5,
        row_length=30.0,
        lateral_offset=offset,
        yaw=math.radians(yaw_deg),
        hole_fraction=0.0,
        depth_threshold=10.0,
        trunk_spacing=4.0,
        canopy_opening=opening,
    )


def orchard_navigator(**changes) -> CorridorNavigator:
    # 96 px see about 14 trunk pixels a side at trunk_stride 2: fewer than the 224 px default asks for
    return CorridorNavigator(CorridorConfig(depth_threshold=10.0, trunk_min_points=5, **changes), scene_camera())


@pytest.mark.parametrize("offset", [0.0, 0.3, -0.4])
def test_under_a_closed_canopy_the_trunks_give_the_centre(offset):
    mask, depth = render_scene(orchard_scene(offset), size=SIZE)
    nav = orchard_navigator()
    for _ in range(3):
        command = nav.step(mask, depth)
    assert command.mode == "trunks"
    assert command.centre[0] == pytest.approx(-offset, abs=0.06)
    assert not any(command.centre[1:])  # taken along the robot (docstring)
    assert len(command.centre) == 1 + nav.config.degree  # as long as the row fits' centrelines
    assert nav.mode_counts["trunks"] == 3
    assert np.sign(command.omega) == -np.sign(offset) or offset == 0.0


@pytest.mark.parametrize("offset", [0.0, 0.3])
def test_a_robot_pitched_on_a_bump_still_finds_the_trunks(offset):
    """The camera 5 deg further down than the navigator's geometry says (a bump under the
    robot): the level ground ahead rises through the trunks' height band in the robot's plane.
    Measured from the robot's plane the trunk-to-trunk width fell to 3.4 m and the centre went
    to the wrong side; measured from the ground ahead both hold."""
    mask, depth = render_scene(orchard_scene(offset), size=SIZE, tilt_deg=10.0)
    nav = orchard_navigator()
    for _ in range(3):
        command = nav.step(mask, depth)
    assert command.mode == "trunks"
    assert command.centre[0] == pytest.approx(-offset, abs=0.06)
    assert nav._trunks.width == pytest.approx(7.0, abs=0.3)


def test_the_ground_plane_is_fitted_under_trunks_and_noise():
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0.5, 12.0, 2000), rng.uniform(-5.0, 5.0, 2000)
    h = 0.05 + 0.09 * x - 0.03 * y + rng.normal(0.0, 0.02, x.shape)
    trunk_x, trunk_h = np.repeat([4.0, 8.0], 100), np.tile(np.linspace(0.0, 2.0, 100), 2)
    x, y = np.concatenate([x, trunk_x]), np.concatenate([y, np.full(200, 3.5)])
    h = np.concatenate([h, 0.05 + 0.09 * trunk_x - 0.03 * 3.5 + trunk_h])
    assert ground_plane(x, y, h) == pytest.approx((0.05, 0.09, -0.03), abs=0.01)
    # too few points near the robot's plane: that plane is the ground
    assert ground_plane(x[:20], y[:20], h[:20]) == (0.0, 0.0, 0.0)


def test_an_opening_in_the_canopy_hands_the_trunk_scene_to_segmind():
    mask, depth = render_scene(orchard_scene(0.3, opening=1.0), size=SIZE)
    assert orchard_navigator().step(mask, depth).mode == "fallback"


def test_green_pixels_are_not_trunks_when_the_image_is_given():
    """Leaves the mask missed are green; bark and posts are not."""
    mask, depth = render_scene(orchard_scene(0.3), size=SIZE)
    brown = np.broadcast_to(np.array([90, 60, 40], np.uint8), (SIZE, SIZE, 3))
    green = np.broadcast_to(np.array([60, 140, 50], np.uint8), (SIZE, SIZE, 3))
    assert orchard_navigator().step(mask, depth, rgb=brown).mode == "trunks"
    assert orchard_navigator().step(mask, depth, rgb=green).mode == "fallback"
    half_green = brown.copy()
    half_green[:, : SIZE // 2] = green[:, : SIZE // 2]  # the left row's trunks look like leaves
    nav = orchard_navigator()
    nav.step(mask, depth, rgb=brown)  # learns the trunk width from both rows
    command = nav.step(mask, depth, rgb=half_green)
    assert command.mode == "trunks" and command.centre[0] == pytest.approx(-0.3, abs=0.08)


def test_the_runtime_hands_the_image_to_segcorridor():
    mask, depth = render_scene(orchard_scene(0.3), size=SIZE)
    green = np.broadcast_to(np.array([60, 140, 50], np.uint8), (SIZE, SIZE, 3))
    modes = {}
    for name, rgb in (("no image", None), ("green image", green)):
        nav = orchard_navigator(fuse_frames=1)
        out = RowFollower(None, nav).step(rgb, depth, 0.0, mask=mask)
        modes[name] = out.command.mode
    assert modes == {"no image": "trunks", "green image": "fallback"}


def test_an_image_of_the_wrong_size_is_refused():
    mask, depth = render_scene(orchard_scene(), size=SIZE)
    with pytest.raises(ValueError, match="rgb must be 96x96x3"):
        orchard_navigator().step(mask, depth, rgb=np.zeros((SIZE, SIZE), np.uint8))
    with pytest.raises(ValueError, match="rgb must be uint8"):  # a 0-1 float image would pass every pixel as not green
        orchard_navigator().step(mask, depth, rgb=np.zeros((SIZE, SIZE, 3), np.float32))
    # the runtime refuses it with the frame that brings it, not frames later at the next command
    with pytest.raises(ValueError, match=r"frame at t=0.000000 s: rgb must be uint8"):
        RowFollower(None, orchard_navigator()).step(np.zeros((SIZE, SIZE, 3), np.float32), depth, 0.0, mask=mask)


def test_the_row_fit_after_the_trunks_keeps_every_coefficient():
    """Leaving a closed canopy for walls of vines: the first row fit's curvature term survives the
    averaging with the trunk mode's centreline (both have the same number of coefficients)."""
    nav = orchard_navigator()
    trunk_frame = render_scene(orchard_scene(0.3), size=SIZE)
    nav.step(*trunk_frame)
    command = nav.step(*trunk_frame)
    assert command.mode == "trunks"
    curved = CorridorNavigator(CorridorConfig(depth_threshold=10.0, trunk_min_points=5), scene_camera())
    bend = dataclasses.replace(vine_scene(0.0, 8.0), hole_fraction=0.0)
    mask, depth = render_scene(bend, size=SIZE)
    fresh, after = curved.step(mask, depth), nav.step(mask, depth)
    assert fresh.mode == after.mode == "both" and len(after.centre) == len(fresh.centre)
