"""Sensor faults stop the robot (`runtime.sensor_faults`, run by `RowFollower`): hand-built frames
for every reason, the stop within one command, driving again when good frames return."""

from __future__ import annotations

import time

import numpy as np
import pytest

from segmin.nav_eval.runtime.follower import FollowerOutput, RowFollower, RuntimeConfig
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from segmin.nav_eval.runtime.sensor_faults import REASONS, SensorChecks, depth_fault

H, W = 24, 64
HZ = 30.0
GREEN = (40, 160, 40)


class GreenSegmenter:
    """Vegetation where the image is clearly green: a black or white image gives an empty mask,
    which the paper's histogram reads as an open row."""

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        colour = rgb.astype(np.int16)
        return (colour[..., 1] - colour[..., 0] > 40) & (colour[..., 1] - colour[..., 2] > 40)

    def probabilities(self, rgb: np.ndarray) -> np.ndarray:
        return self.segment(rgb).astype(np.float32)


def _rows(i: int) -> np.ndarray:
    """Two green rows (columns 0-15 and 48-63) beside a grey corridor, with a camera's noise."""
    rgb = np.full((H, W, 3), 110, dtype=np.uint8)
    rgb[:, :16] = GREEN
    rgb[:, 48:] = GREEN
    noise = np.random.default_rng(i).integers(0, 3, size=(H, W, 3), dtype=np.uint8)
    return rgb + noise


def _depth(metres: float = 2.0) -> np.ndarray:
    return np.full((H, W), metres, dtype=np.float32)


def _live_depth(i: int) -> np.ndarray:
    """2 m with a depth camera's noise (a millimetre or so, new every frame)."""
    return _depth() + np.random.default_rng(i).normal(0.0, 0.001, size=(H, W)).astype(np.float32)


def _follower(method: str = "segmind", **checks: object) -> RowFollower:
    navigator = Navigator(NavigatorConfig(method=method, depth_threshold=5.0, smooth_window=1))
    return RowFollower(GreenSegmenter(), navigator, RuntimeConfig(checks=SensorChecks(**checks)))


def _drive(follower: RowFollower, frames: list[tuple], start: int, now_offset: float | None = None):
    """Step (rgb, depth) frames at 30 Hz from frame index `start`; the outputs."""
    out = []
    for k, (rgb, depth) in enumerate(frames):
        t = (start + k) / HZ
        out.append(follower.step(rgb, depth, t, now=None if now_offset is None else t + now_offset))
    return out


def _good(n: int, start: int) -> list[tuple]:
    return [(_rows(start + k), _live_depth(start + k)) for k in range(n)]


def _first_fresh(outputs: list[FollowerOutput]) -> FollowerOutput:
    return next(o for o in outputs if o.fresh)


def _check_stop_then_resume(
    follower: RowFollower, bad: list[tuple], reason: str, now_offset: float | None = None, within: float = 0.2
):
    """1 s good, 1 s bad, 1 s good: driving, a stop naming `reason` within `within` s of the first
    bad frame, held while the bad frames come, and driving again within 0.5 s of the good frames."""
    before = _drive(follower, _good(30, 0), 0)
    assert before[-1].command.valid and before[-1].command.v > 0.1 and before[-1].stopped is None
    during = _drive(follower, bad, 30, now_offset)
    stopped_at = next(k for k, o in enumerate(during) if not o.command.valid)
    assert stopped_at / HZ <= within + 1e-9 and during[stopped_at].stopped == reason
    assert all(not o.command.valid and o.stopped == reason for o in during[stopped_at:])
    assert reason in follower.faults and follower.sensor_fault[0] == reason
    after = _drive(follower, _good(30, 60), 60)
    resumed = next(k for k, o in enumerate(after) if o.command.valid)
    assert resumed / HZ <= 0.5 and after[-1].command.v > 0.1 and follower.faults == {}
    return during[stopped_at]


@pytest.mark.parametrize("value", [np.nan, 0.0, -1.0, np.inf, -np.inf, 25.0])
def test_depth_without_readings_stops_the_robot_instead_of_opening_the_row(value: float) -> None:
    # 25 m is beyond the sensor's range (max_depth_m 20): no reading either.
    bad = [(_rows(30 + k), _depth(value)) for k in range(30)]
    stop = _check_stop_then_resume(_follower(), bad, "depth_invalid")
    assert "0% of the" in str(_follower_detail(bad, "depth_invalid"))
    assert stop.command.v == 0.0 and stop.command.omega == 0.0


def _follower_detail(bad: list[tuple], reason: str) -> str:
    follower = _follower()
    _drive(follower, _good(10, 0) + bad[:10], 0)
    return follower.faults[reason]


def test_realsense_zero_millimetres_stop_the_robot_too() -> None:
    good = [(_rows(k), (_live_depth(k) * 1000).astype(np.uint16)) for k in range(30)]  # noisy millimetres
    follower = _follower()
    assert _drive(follower, good, 0)[-1].command.valid
    bad = _drive(follower, [(_rows(k), np.zeros((H, W), np.uint16)) for k in range(30, 40)], 30)
    assert bad[-1].stopped == "depth_invalid" and not bad[-1].command.valid


@pytest.mark.parametrize(("side", "columns"), [("left", slice(0, W // 2)), ("right", slice(W // 2, None))])
def test_one_blind_image_half_stops_the_robot_instead_of_steering_into_it(side: str, columns: slice) -> None:
    depth = _depth()
    depth[:, columns] = np.nan
    bad = [(_rows(30 + k), depth) for k in range(30)]
    _check_stop_then_resume(_follower(), bad, f"depth_invalid_{side}")
    assert f"the {side} image half" in _follower_detail(bad, f"depth_invalid_{side}")


def test_black_and_white_images_stop_the_robot() -> None:
    black = np.zeros((H, W, 3), np.uint8)
    _check_stop_then_resume(_follower(), [(black, _depth()) for _ in range(30)], "image_black")
    white = np.full((H, W, 3), 250, np.uint8)
    _check_stop_then_resume(_follower(), [(white, _depth()) for _ in range(30)], "image_white")
    # A dark but lit scene is no fault.
    dim = (_rows(0) // 4).astype(np.uint8)
    assert _drive(_follower(method="segmin"), [(dim + k % 2, _live_depth(k)) for k in range(30)], 0)[-1].stopped is None


def test_a_frozen_image_stops_a_driving_robot_but_not_a_standing_one() -> None:
    frozen = _rows(99)
    # Identical pixels for longer than frozen_s (0.25 s): the frame after that stops the robot.
    stop = _check_stop_then_resume(_follower(), [(frozen, _depth()) for _ in range(30)], "image_frozen", within=0.3)
    assert stop.t - 30 / HZ > 0.25
    # A robot held stopped by another fault sees a still scene: no frozen fault stacks on it.
    follower = _follower()
    _drive(follower, [(frozen, _depth(np.nan)) for _ in range(60)], 0)
    assert set(follower.faults) == {"depth_invalid"}


def test_a_frozen_depth_stream_under_a_live_image_stops_a_driving_robot_but_not_a_standing_one() -> None:
    """A driver that repeats its last depth frame while colour stays live: stale depth, a stop
    naming depth_frozen after frozen_s; NaN readings repeated are repeated too (NaN-safe)."""
    stale = _live_depth(99)
    stale[:4] = np.nan  # no return from the top rows, as from the sky
    bad = [(_rows(30 + k), stale) for k in range(30)]
    stop = _check_stop_then_resume(_follower(), bad, "depth_frozen", within=0.3)
    assert stop.t - 30 / HZ > 0.25
    assert "the sampled depth pixels have not changed for 0.2" in _follower_detail(bad, "depth_frozen")
    held = _follower()
    for k in range(30):  # driving off: a still scene, no stop
        held.step(_rows(k), stale, k / HZ, driving=False)
    assert held.faults == {}
    without = _follower(method="segmin")  # a navigator run without depth: nothing to judge
    assert _drive(without, [(_rows(k), None) for k in range(30)], 0)[-1].stopped is None


def test_a_robot_whose_driving_is_off_sees_its_still_scene_without_a_frozen_stop() -> None:
    """The node runs the runtime while driving is disabled: commands move, the wheels do not."""
    frozen = _rows(99)
    held = _follower()
    for k in range(30):  # a second of one still frame, the runtime commanding motion, driving off
        held.step(frozen, _depth(), k / HZ, driving=False)
    assert "image_frozen" not in held.faults
    assert held.step(frozen, _depth(), 30 / HZ, driving=True).command.valid  # enabled: it drives at once
    free = _follower()
    for k in range(30):
        free.step(frozen, _depth(), k / HZ)  # driving None: the commands reach the wheels
    assert "image_frozen" in free.faults


def test_frames_stamped_far_from_the_followers_clock_stop_the_robot_and_name_use_sim_time() -> None:
    follower = _follower()
    bad = _good(30, 30)
    _check_stop_then_resume(follower, bad, "clock_offset", now_offset=1796571822.0)
    follower = _follower()
    _drive(follower, bad, 0, now_offset=1796571822.0)
    detail = follower.faults["clock_offset"]
    assert "1796571822.000 s behind" in detail and "use_sim_time" in detail
    _drive(follower, bad[:1], 40, now_offset=-0.8)  # under a second: how far, no hint
    assert (
        "0.800 s ahead of" in follower.faults["clock_offset"] and "use_sim_time" not in follower.faults["clock_offset"]
    )
    assert _drive(_follower(), bad, 0, now_offset=0.1)[-1].command.valid  # a camera's latency is no fault


def test_the_simulators_dropouts_and_a_sky_without_returns_do_not_trip_the_checks() -> None:
    """2 % random dropouts and no return above the rows (the sky, outside the mask) are normal frames."""
    rng = np.random.default_rng(0)
    follower = _follower()
    outputs = []
    for k in range(60):
        depth = _depth()
        depth[rng.random((H, W)) < 0.02] = 0.0
        depth[:6] = 0.0  # the sky: no return, no vegetation
        rgb = _rows(k)
        rgb[:6] = (120, 160, 220)
        outputs.append(follower.step(rgb, depth, k / HZ))
    assert all(o.stopped is None for o in outputs) and outputs[-1].command.valid


def test_segmin_without_depth_is_not_judged_on_depth() -> None:
    follower = _follower(method="segmin")
    outputs = _drive(follower, [(_rows(k), None) for k in range(30)], 0)
    assert outputs[-1].command.valid and follower.faults == {}


def test_depth_fault_names_the_failing_half_or_the_whole() -> None:
    checks = SensorChecks()
    mask = np.ones((H, W), dtype=bool)
    depth = _depth()
    assert depth_fault(mask, depth, checks) is None
    depth[:, :40] = 0.0  # the left half blind and part of the right: the whole fails, one half
    assert depth_fault(mask, depth, checks)[0] == "depth_invalid_left"
    depth[:, :60] = 0.0  # both halves fail
    assert depth_fault(mask, depth, checks)[0] == "depth_invalid"
    few = np.zeros((H, W), dtype=bool)
    few[0, :10] = True  # fewer vegetation pixels than min_judged_pixels: not judged
    assert depth_fault(few, np.zeros((H, W), np.float32), checks) is None
    assert (
        depth_fault(mask, np.zeros((H, W), np.float32), SensorChecks(min_valid_depth=0, min_valid_depth_side=0)) is None
    )


def test_the_checks_take_well_under_a_millisecond_on_a_full_size_frame() -> None:
    from segmin.nav_eval.runtime.sensor_faults import SensorFaults

    faults = SensorFaults(SensorChecks())
    rgb = np.random.default_rng(0).integers(0, 255, size=(480, 640, 3), dtype=np.uint8)
    depth, mask = np.full((480, 640), 2.0, np.float32), np.ones((480, 640), dtype=bool)
    start = time.perf_counter()
    for k in range(50):
        rgb[0, 0, 0] = k  # a live camera: some pixel changes
        faults.on_frame(rgb, k / HZ, k / HZ, moving=True)
        faults.on_command(mask, depth)
    assert (time.perf_counter() - start) / 50 < 0.01  # 10 ms: a loose bound on a loaded machine (median 0.3 ms)
    assert faults.active == {}


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"min_valid_depth": 1.5}, "min_valid_depth must be a share within [0, 1]"),
        ({"blank_share": -0.1}, "blank_share must be a share"),
        ({"min_judged_pixels": 0}, "min_judged_pixels must be an integer >= 1"),
        ({"black_level": 300}, "black_level must be an integer within [0, 255]"),
        ({"black_level": 200, "white_level": 100}, "black_level (200) must be below white_level (100)"),
        ({"frozen_s": 0.0}, "frozen_s must be a number > 0"),
        ({"max_depth_m": float("nan")}, "max_depth_m must be a number > 0"),
        ({"max_depth_m": float("inf")}, "max_depth_m must be a finite number of metres"),
        ({"max_clock_offset_s": "1"}, "max_clock_offset_s must be a number > 0"),
    ],
)
def test_bad_limits_are_named(values: dict, message: str) -> None:
    with pytest.raises(ValueError, match=r"^" + message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        SensorChecks(**values)


def test_every_reason_comes_from_a_hand_built_frame() -> None:
    half = W // 2
    left, right = _depth(), _depth()
    left[:, :half] = np.nan
    right[:, half:] = 0.0
    frozen = _rows(99)
    cases = {
        "depth": [(_rows(30 + k), _depth(np.nan)) for k in range(12)],
        "left": [(_rows(30 + k), left) for k in range(12)],
        "right": [(_rows(30 + k), right) for k in range(12)],
        "black": [(np.zeros((H, W, 3), np.uint8), _depth())] * 3,
        "white": [(np.full((H, W, 3), 255, np.uint8), _depth())] * 3,
        "frozen": [(frozen, _depth())] * 20,
        "frozen depth": [(_rows(30 + k), _depth()) for k in range(20)],
    }
    seen = set()
    for frames in cases.values():
        follower = _follower()
        _drive(follower, _good(30, 0) + frames, 0)
        seen.add(follower.sensor_fault[0])
    follower = _follower()
    _drive(follower, _good(3, 0), 0, now_offset=5.0)
    seen.add(follower.sensor_fault[0])
    assert seen == set(REASONS) and len(REASONS) == 8
    with pytest.raises(ValueError, match="checks must be a SensorChecks"):
        RuntimeConfig(checks={"frozen_s": 1.0})  # type: ignore[arg-type]


def test_a_depth_cut_beyond_the_sensors_range_is_refused_wherever_it_is_set() -> None:
    from segmin.nav_eval.ros2.params import node_params
    from segmin.nav_eval.sim.config import load_nav_config

    navigator = Navigator(NavigatorConfig(method="segmind", depth_threshold=25.0))
    with pytest.raises(
        ValueError, match=r"depth_threshold \(25 m\) is beyond the sensor's range, max_depth_m \(20 m\)"
    ):
        RowFollower(None, navigator)
    assert RowFollower(None, navigator, RuntimeConfig(checks=SensorChecks(max_depth_m=30.0)))
    with pytest.raises(ValueError, match=r"^parameter follower.navigator.depth_threshold: depth_threshold \(25 m\) is"):
        node_params({"follower.navigator.depth_threshold": 25.0})
    with pytest.raises(
        ValueError, match=r"depth threshold for 'high_trees': .* \(follower.runtime.checks.max_depth_m\)"
    ):
        load_nav_config(None, ["follower.runtime.checks.max_depth_m=9"])
