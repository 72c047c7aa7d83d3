"""Navigator: exact scenes, control law numbers, degenerate frames, bad input and properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from segmin.nav_eval.runtime.methods import PAPER_METHODS as METHODS
from segmin.nav_eval.runtime.navigator import (
    Navigator,
    NavigatorConfig,
    column_histogram,
    control_law,
    moving_average,
    target_column,
)
from segmin.nav_eval.runtime.protocols import NavigatorInputs

H, W = 48, 64


def two_rows(width: int = W, height: int = H, row_width: int = 16) -> np.ndarray:
    """Vegetation on the left and right thirds, free corridor in the middle."""
    mask = np.zeros((height, width), dtype=bool)
    mask[:, :row_width] = True
    mask[:, width - row_width :] = True
    return mask


def depth_frame(value: float = 2.0) -> np.ndarray:
    return np.full((H, W), value, dtype=np.float32)


# --- exact scenes ----------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
def test_symmetric_rows_give_the_centre(method: str) -> None:
    assert target_column(two_rows(), depth_frame(), method=method, depth_threshold=5.0) == pytest.approx((W - 1) / 2)


@pytest.mark.parametrize("method", ["segmin", "segmind"])
@pytest.mark.parametrize("shift", [-7, -3, 1, 5, 9])
def test_shifting_the_scene_shifts_the_target(method: str, shift: int) -> None:
    rng = np.random.default_rng(3)
    mask = two_rows(row_width=20)
    mask[: H // 3, 20:44] |= rng.random((H // 3, 24)) < 0.3  # ragged canopy edge
    depth = (1.0 + 3.0 * rng.random((H, W))).astype(np.float32)
    base = target_column(mask, depth, method=method, depth_threshold=5.0)
    shifted = target_column(
        np.roll(mask, shift, axis=1), np.roll(depth, shift, axis=1), method=method, depth_threshold=5.0
    )
    assert shifted == pytest.approx(base + shift)


@pytest.mark.parametrize("method", METHODS)
def test_vegetation_beyond_the_threshold_is_ignored(method: str) -> None:
    mask = two_rows()
    mask[:10, 20:30] = True  # a bush inside the corridor
    far = depth_frame(2.0)
    far[:10, 20:30] = 7.0
    assert target_column(mask, far, method=method, depth_threshold=5.0) == pytest.approx((W - 1) / 2)
    near = depth_frame(2.0)
    assert target_column(mask, near, method=method, depth_threshold=5.0) != pytest.approx((W - 1) / 2)


def test_segmind_prefers_the_gap_whose_vegetation_is_farther() -> None:
    mask = np.ones((H, W), dtype=bool)
    depth = depth_frame(2.0)
    mask[:, 10:20] = False
    mask[:6, 10:20] = True  # gap A: little vegetation, but very near
    depth[:6, 10:20] = 0.5
    mask[:, 44:54] = False
    mask[:12, 44:54] = True  # gap B: more vegetation, far away
    depth[:12, 44:54] = 4.8
    segmin = target_column(mask, depth, method="segmin", depth_threshold=5.0, smooth_window=3)
    segmind = target_column(mask, depth, method="segmind", depth_threshold=5.0, smooth_window=3)
    assert 10 <= segmin <= 19
    assert 44 <= segmind <= 53


def test_segzeros_fails_when_a_canopy_closes_the_row_but_segmin_finds_it() -> None:
    mask = two_rows()
    mask[:8, :] = True  # canopy across the top of the image
    depth = depth_frame(3.0)
    assert target_column(mask, depth, method="segzeros", depth_threshold=8.0) is None
    assert target_column(mask, depth, method="segmin", depth_threshold=8.0) == pytest.approx((W - 1) / 2)
    navigator = Navigator(NavigatorConfig(method="segzeros", depth_threshold=8.0))
    command = navigator.step(mask, depth)
    assert not command.valid and command.v == 0.0 and command.omega == 0.0 and command.target_column is None


def test_ties_take_the_mean_of_all_minimum_columns() -> None:
    mask = np.ones((H, W), dtype=bool)
    mask[:, 10:20] = False
    mask[:, 40:50] = False
    target = target_column(mask, depth_frame(), method="segmin", depth_threshold=5.0, smooth_window=1)
    assert target == pytest.approx(np.mean(list(range(10, 20)) + list(range(40, 50))))


def test_invalid_depth_never_counts_as_near() -> None:
    mask = two_rows()
    mask[:, 20:40] = True  # vegetation in the corridor, but without a valid depth reading
    depth = depth_frame(2.0)
    depth[:, 20:25] = 0.0
    depth[:, 25:30] = np.nan
    depth[:, 30:35] = np.inf
    depth[:, 35:40] = -1.0
    for method in ("segmin", "segmind"):
        assert target_column(mask, depth, method=method, depth_threshold=5.0, smooth_window=1) == pytest.approx(
            (W - 1) / 2
        )


def test_uint16_millimetres_equal_float_metres() -> None:
    rng = np.random.default_rng(0)
    mask = rng.random((H, W)) < 0.5
    millimetres = rng.integers(0, 9000, size=(H, W)).astype(np.uint16)
    metres = millimetres.astype(np.float32) / 1000.0
    for method in METHODS:
        a = target_column(mask, millimetres, method=method, depth_threshold=5.0)
        b = target_column(mask, metres, method=method, depth_threshold=5.0)
        assert a == b or (a is not None and b is not None and a == pytest.approx(b))


def _columns(*columns: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """A mask and float32 depth whose column k holds vegetation at the depths `columns[k]` (NaN
    for a pixel without a reading) and bare ground 1 m away below it (never counted)."""
    height = max(len(c) for c in columns) + 2
    mask = np.zeros((height, len(columns)), bool)
    depth = np.ones((height, len(columns)), np.float32)
    for k, column in enumerate(columns):
        mask[: len(column), k] = True
        depth[: len(column), k] = column
    return mask, depth


def test_column_histogram_weights_and_counts_exact_numbers() -> None:
    """d_th 5 m: SegMinD weighs a pixel 1 - d/d_th (2.5 m: 0.5, so 4 pixels give 2.0; 5.0 m: 0),
    SegMin counts it; beyond the threshold (5.01 m) and without a reading nothing counts. At
    d_th 10 m the same pixels weigh more (2.5 m: 0.75)."""
    mask, depth = _columns(
        [2.5] * 4,
        [5.0] * 3,
        [5.01] * 2,
        [1.0, 4.0, 0.0, np.nan, np.inf, -1.0],
        [],
    )
    segmind = column_histogram(mask, depth, method="segmind", depth_threshold=5.0)
    segmin = column_histogram(mask, depth, method="segmin", depth_threshold=5.0)
    assert segmind.dtype == np.float64 and segmind.tolist() == pytest.approx([2.0, 0.0, 0.0, 1.0, 0.0], abs=1e-6)
    assert segmin.tolist() == [4.0, 3.0, 0.0, 2.0, 0.0]
    wide = column_histogram(mask, depth, method="segmind", depth_threshold=10.0)
    assert wide.tolist() == pytest.approx([3.0, 1.5, 0.998, 1.5, 0.0], abs=1e-6)


def _free_columns(*runs: tuple[int, int], width: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Vegetation 1 m away in every column but the [start, stop) runs (a SegZeros frame)."""
    mask = np.ones((8, width), bool)
    for start, stop in runs:
        mask[:, start:stop] = False
    return mask, np.ones((8, width), np.float32)


def test_segzeros_ignores_border_runs_at_start_up_then_tracks_its_run() -> None:
    """Aghi et al.'s rules (40 columns: border 0.2 x 40 = 8 columns, tolerance 0.02 x 40 = 0.8).
    At start-up the widest run would be the one along the image border; the rule takes the run
    inside. Then the run nearest the last target is kept even when another one is wider."""
    navigator = Navigator(NavigatorConfig(method="segzeros", depth_threshold=5.0, fuse_frames=1))
    start = navigator.step(*_free_columns((0, 12), (18, 24)))  # 12 columns at the border, 6 inside
    assert start.valid and start.target_column == 20.5
    tracked = navigator.step(*_free_columns((19, 25), (28, 40)))  # its run moved by 1; a wider one
    assert tracked.valid and tracked.target_column == 21.5
    lost = navigator.step(*_free_columns((8, 14), (28, 40)))  # the nearest run starts 6.5 columns away: lost
    assert not lost.valid and lost.target_column is None and lost.v == 0.0
    again = navigator.step(*_free_columns((10, 16), (30, 40)))  # start-up rule again: not the border run
    assert again.valid and again.target_column == 12.5
    navigator.reset()
    assert navigator.step(*_free_columns((0, 12), (18, 24))).target_column == 20.5
    border_only = Navigator(NavigatorConfig(method="segzeros", depth_threshold=5.0, fuse_frames=1))
    assert not border_only.step(*_free_columns((0, 12), (34, 40))).valid  # only border runs: no target yet
    no_border = Navigator(
        NavigatorConfig(method="segzeros", depth_threshold=5.0, fuse_frames=1, zeros_startup_border=0.0)
    )
    assert no_border.step(*_free_columns((0, 12), (18, 24))).target_column == 5.5


def test_empty_mask_drives_straight_at_full_speed() -> None:
    for method in ("segmin", "segmind"):
        navigator = Navigator(NavigatorConfig(method=method, depth_threshold=5.0, ema_lambda=1.0))
        command = navigator.step(np.zeros((H, W), bool), depth_frame())
        assert command.valid and command.v == pytest.approx(0.5) and command.omega == pytest.approx(0.0)


def test_moving_average_does_not_pull_the_borders_to_zero() -> None:
    assert np.allclose(moving_average(np.full(20, 7.0), 11), 7.0)
    ramp = np.arange(10, dtype=float)
    smoothed = moving_average(ramp, 3)
    assert smoothed[0] == pytest.approx(0.5) and smoothed[-1] == pytest.approx(8.5)
    assert smoothed.shape == ramp.shape


# --- fusion, control law and EMA -------------------------------------------------------------


def test_fusion_is_the_or_of_the_last_n_masks() -> None:
    navigator = Navigator(NavigatorConfig(method="segmin", depth_threshold=5.0, fuse_frames=3, smooth_window=1))
    empty = np.zeros((H, W), bool)
    bush = empty.copy()
    bush[:, :10] = True  # vegetation on the left pushes the target right
    depth = depth_frame()
    assert navigator.step(bush, depth).target_column == pytest.approx(36.5)
    assert navigator.step(empty, depth).target_column == pytest.approx(36.5)
    assert navigator.step(empty, depth).target_column == pytest.approx(36.5)
    assert navigator.step(empty, depth).target_column == pytest.approx((W - 1) / 2)  # the bush has left the window


@pytest.mark.parametrize("method", METHODS)
def test_the_paper_navigators_declare_depth_for_segmind_only_and_keep_no_statistics(method: str) -> None:
    navigator = Navigator(NavigatorConfig(method=method, depth_threshold=5.0))
    assert navigator.inputs == NavigatorInputs(depth=method == "segmind")
    navigator.step(two_rows(), depth_frame())
    assert navigator.statistics() == {}


def test_control_law_matches_hand_computed_values() -> None:
    config = NavigatorConfig(method="segmin", depth_threshold=5.0)
    # w = 224, centre 111.5; x_h = 161.5 -> d = 50: v = 0.5 (1 - 2500/12544), omega = -0.5
    v, omega = control_law(161.5, 224, config)
    assert v == pytest.approx(0.5 * (1 - 2500 / 12544))
    assert omega == pytest.approx(-0.5)
    # d = -150 would ask omega = 1.5: clipped to omega_max; v clipped at 0
    v, omega = control_law(-38.5, 224, config)
    assert omega == pytest.approx(1.0) and v == pytest.approx(0.0)
    zeros = NavigatorConfig(method="segzeros", depth_threshold=5.0)
    v, omega = control_law(161.5, 224, zeros)
    k = 2500 / 12544
    assert v == pytest.approx(0.5 * (1 - k)) and omega == pytest.approx(-1.0 * k)


def test_ema_matches_hand_computed_values() -> None:
    config = NavigatorConfig(method="segmin", depth_threshold=5.0, ema_lambda=0.5, smooth_window=1, fuse_frames=1)
    navigator = Navigator(config)
    mask = np.ones((H, W), bool)
    mask[:, 47:52] = False  # target column 49, d = 49 - 31.5 = 17.5
    u_v, u_omega = control_law(49.0, W, config)
    expected_v = expected_omega = 0.0
    for _ in range(4):
        command = navigator.step(mask, depth_frame())
        expected_v = 0.5 * expected_v + 0.5 * u_v
        expected_omega = 0.5 * expected_omega + 0.5 * u_omega
        assert command.v == pytest.approx(expected_v) and command.omega == pytest.approx(expected_omega)
    assert command.v == pytest.approx(u_v * (1 - 0.5**4))
    navigator.reset()
    assert navigator.step(mask, depth_frame()).v == pytest.approx(0.5 * u_v)


# --- bad input -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("mask", "depth", "message"),
    [
        (np.zeros((2, 3, 4), bool), np.zeros((2, 3)), "mask must be a 2-D"),
        (np.zeros((2, 3), bool), np.zeros(6), "depth must be a 2-D"),
        (np.zeros((0, 3), bool), np.zeros((0, 3)), "must not be empty"),
        (np.zeros((4, 3), bool), np.zeros((3, 4)), "same shape"),
        (np.zeros((4, 3), bool), np.zeros((4, 3), np.int32), "uint16 millimetres"),
        (np.array([["a"]]), np.zeros((1, 1)), "expected bool or an integer"),
    ],
)
def test_bad_frames_raise_value_errors(mask: np.ndarray, depth: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        target_column(mask, depth, method="segmin", depth_threshold=5.0)
    with pytest.raises(ValueError, match=message):
        Navigator(NavigatorConfig(method="segmin", depth_threshold=5.0)).step(mask, depth)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"method": "segmax"}, "method must be one of"),
        ({"depth_threshold": float("nan")}, "depth_threshold"),
        ({"depth_threshold": float("inf")}, "depth_threshold"),
        ({"depth_threshold": 0.0}, "depth_threshold"),
        ({"depth_threshold": -1.0}, "depth_threshold"),
        ({"smooth_window": 4}, "smooth_window"),
        ({"fuse_frames": 0}, "fuse_frames"),
        ({"ema_lambda": 0.0}, "ema_lambda"),
        ({"v_max": -0.1}, "v_max"),
        ({"omega_gain": float("nan")}, "omega_gain"),
    ],
)
def test_bad_config_raises_value_errors(kwargs: dict, message: str) -> None:
    base = {"method": "segmin", "depth_threshold": 5.0}
    with pytest.raises(ValueError, match=message):
        NavigatorConfig(**{**base, **kwargs})


def test_target_column_checks_its_arguments() -> None:
    with pytest.raises(ValueError, match="method"):
        target_column(two_rows(), depth_frame(), method="nope", depth_threshold=5.0)
    with pytest.raises(ValueError, match="depth_threshold"):
        target_column(two_rows(), depth_frame(), method="segmin", depth_threshold=float("nan"))


# --- properties ------------------------------------------------------------------------------


def frames_of_width(w: int) -> st.SearchStrategy:
    return st.tuples(
        arrays(bool, (6, w)),
        arrays(np.float32, (6, w), elements=st.floats(0.0, 12.0, width=32)),
    )


frames = st.integers(4, 40).flatmap(frames_of_width)


@settings(max_examples=150, deadline=None)
@given(frame=frames, method=st.sampled_from(METHODS), window=st.sampled_from([1, 3, 11]))
def test_target_is_inside_the_image(frame, method, window) -> None:
    mask, depth = frame
    target = target_column(mask, depth, method=method, depth_threshold=5.0, smooth_window=window)
    assert target is None or 0 <= target <= mask.shape[1] - 1


@settings(max_examples=150, deadline=None)
@given(frame=frames, method=st.sampled_from(METHODS), window=st.sampled_from([1, 3, 11]))
def test_mirroring_the_frame_mirrors_the_target(frame, method, window) -> None:
    mask, depth = frame
    w = mask.shape[1]
    target = target_column(mask, depth, method=method, depth_threshold=5.0, smooth_window=window)
    mirrored = target_column(mask[:, ::-1], depth[:, ::-1], method=method, depth_threshold=5.0, smooth_window=window)
    assert (target is None) == (mirrored is None)
    if target is None:
        return
    if method == "segzeros":
        # two equally wide corridors at the same distance from the centre: SegZeros takes the left one
        centre = (w - 1) / 2
        assert mirrored == pytest.approx(w - 1 - target) or abs(mirrored - centre) == pytest.approx(
            abs(target - centre)
        )
    else:
        assert mirrored == pytest.approx(w - 1 - target, abs=1e-6)


@settings(max_examples=60, deadline=None)
@given(
    sequence=st.lists(frames_of_width(24), min_size=1, max_size=6),
    method=st.sampled_from(METHODS),
    v_max=st.floats(0.1, 2.0),
    omega_max=st.floats(0.1, 3.0),
    gain=st.floats(0.0, 0.5),
)
def test_commands_stay_within_limits(sequence, method, v_max, omega_max, gain) -> None:
    config = NavigatorConfig(method=method, depth_threshold=5.0, v_max=v_max, omega_max=omega_max, omega_gain=gain)
    navigator = Navigator(config)
    for mask, depth in sequence:
        command = navigator.step(mask, depth)
        assert 0.0 <= command.v <= v_max + 1e-12
        assert abs(command.omega) <= omega_max + 1e-12
        assert math.isfinite(command.v) and math.isfinite(command.omega)


@settings(max_examples=60, deadline=None)
@given(frame=frames, method=st.sampled_from(["segmin", "segmind"]), lam=st.floats(0.05, 1.0))
def test_ema_converges_to_the_constant_command(frame, method, lam) -> None:
    mask, depth = frame
    config = NavigatorConfig(method=method, depth_threshold=5.0, ema_lambda=lam, fuse_frames=1)
    navigator = Navigator(config)
    target = target_column(mask, depth, method=method, depth_threshold=5.0)
    v_target, omega_target = control_law(target, mask.shape[1], config)
    for _ in range(400):
        command = navigator.step(mask, depth)
    assert command.v == pytest.approx(v_target, abs=1e-6)
    assert command.omega == pytest.approx(omega_target, abs=1e-6)


@pytest.mark.parametrize(
    "mask, message",
    [
        (np.full((H, W), 0.3, np.float32), "dtype is float32.*threshold it first"),
        (np.full((H, W), 0.3, np.float64), "probability map"),
        (np.arange(H * W, dtype=np.int32).reshape(H, W) % 7, "range over 0..6"),
        (np.where(np.eye(H, W, dtype=bool), 255, 128).astype(np.uint8), "0/255"),
        (np.full((H, W), -1, np.int16), "range over -1..-1"),
    ],
)
def test_a_mask_that_is_not_binary_is_refused_with_the_hint(mask, message) -> None:
    """A probability map was taken as a mask (every pixel > 0 counted as vegetation)."""
    with pytest.raises(ValueError, match=message):
        Navigator(NavigatorConfig(method="segmin", depth_threshold=5.0)).step(mask, depth_frame())


def test_binary_integer_masks_equal_bool_masks() -> None:
    mask = two_rows()
    expected = Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0)).step(mask, depth_frame())
    for values in (mask.astype(np.uint8), mask.astype(np.uint8) * 255, mask.astype(np.int64)):
        got = Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0)).step(values, depth_frame())
        assert got.target_column == expected.target_column and got.v == expected.v
    zeros = np.zeros((H, W), np.uint8)
    Navigator(NavigatorConfig(method="segmin", depth_threshold=5.0)).step(zeros, depth_frame())
