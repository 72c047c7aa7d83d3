"""The robot runtime (`RowFollower`): its rates, its fusion window and its timing faults."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest

from segmin.nav_eval.runtime.follower import RowFollower, RuntimeConfig
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from segmin.nav_eval.runtime.protocols import NavigatorInputs

H, W = 8, 64


class FrameIndexSegmenter:
    """A 'segmenter' whose mask marks the frame it came from: column (frame index) is vegetation.

    The frame index is encoded in pixel [0, 0] of the RGB image, so the fused mask shows which
    frames a command fused.
    """

    def __init__(self) -> None:
        self.calls: list[int] = []

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        index = int(rgb[0, 0, 0])
        self.calls.append(index)
        mask = np.zeros((H, W), dtype=bool)
        mask[:, index % W] = True
        return mask


def _rgb(i: int) -> np.ndarray:
    rgb = np.full((H, W, 3), 128, dtype=np.uint8)  # grey: a black image is a sensor fault
    rgb[0, 0, 0] = i
    return rgb


def _follower(fuse: int = 3, method: str = "segmin", **runtime) -> tuple[RowFollower, FrameIndexSegmenter]:
    segmenter = FrameIndexSegmenter()
    navigator = Navigator(NavigatorConfig(method=method, depth_threshold=5.0, fuse_frames=fuse, smooth_window=1))
    return RowFollower(segmenter, navigator, RuntimeConfig(**runtime)), segmenter


DEPTH = np.full((H, W), 2.0, dtype=np.float32)


def _depth(i: int) -> np.ndarray:
    """DEPTH as a depth camera delivers it: a reading that changes a little every frame (a
    repeated depth frame is a sensor fault), all within the depth cut as DEPTH."""
    depth = DEPTH.copy()
    depth[0, 0] += 1e-4 * i
    return depth


def _drive(follower: RowFollower, frames: int, hz: float = 30.0, start: int = 0):
    return [follower.step(_rgb(i), _depth(i), i / hz) for i in range(start, start + frames)]


def test_30_hz_frames_give_20_hz_masks_and_5_hz_commands_fusing_the_last_3() -> None:
    # With a window of 4 every 20 Hz deadline feeds a command, so all of them are segmented.
    follower, segmenter = _follower(fuse=4)
    outputs = _drive(follower, 61)  # 2 s of frames at 30 Hz
    assert len(segmenter.calls) == 41  # deadlines 0, 0.05, ..., 2.0 s
    fresh = [o for o in outputs if o.fresh]
    assert [round(o.command_t, 6) for o in fresh] == [round(k / 5, 6) for k in range(11)]
    # Deadline s_k is served by the latest frame at or before it: frame floor(30 s_k).
    assert segmenter.calls == [int(np.floor(30 * k / 20 + 1e-9)) for k in range(41)]

    # The paper's window of 3: each command fuses the masks of its last 3 deadlines, and the
    # fourth deadline of each command period, which no command fuses, is not segmented.
    follower, segmenter = _follower(fuse=3)
    outputs = _drive(follower, 61)
    assert len(segmenter.calls) == 1 + 10 * 3
    for out in outputs:
        if out.fresh and out.command_t > 0:
            k = round(out.command_t * 20)
            frames = {int(np.floor(30 * j / 20 + 1e-9)) for j in (k - 2, k - 1, k)}
            assert set(np.flatnonzero(out.fused[0])) == frames, out.command_t
    # Between commands the command in force is returned unchanged.
    assert outputs[1].command is outputs[0].command and not outputs[1].fresh


class _WatchedFuture(Future):
    """A finished future that records when its mask was first asked for."""

    def __init__(self, mask: np.ndarray, asked: list[int], index: int) -> None:
        super().__init__()
        self.set_result(mask)
        self.asked, self.index = asked, index

    def result(self, timeout=None):
        if self.index not in self.asked:
            self.asked.append(self.index)
        return super().result(timeout)


def test_mask_futures_are_waited_for_only_at_the_next_command_with_the_same_commands() -> None:
    """A background segmenter's masks between commands join the window at the command, in order:
    the commands are those of masks given at once, and the follower never waits earlier."""
    follower, segmenter = _follower(fuse=3)
    immediate = [follower.step(_rgb(i), _depth(i), i / 30, mask=segmenter.segment(_rgb(i))) for i in range(61)]
    follower, segmenter = _follower(fuse=3)
    asked: list[int] = []
    for i, reference in enumerate(immediate):
        future = _WatchedFuture(segmenter.segment(_rgb(i)), asked, i)
        out = follower.step(_rgb(i), _depth(i), i / 30, mask=future)
        assert out.fresh == reference.fresh, i
        same = (out.command.v, out.command.omega, out.command.target_column)
        assert same == (reference.command.v, reference.command.omega, reference.command.target_column), i
        if out.fresh:
            assert np.array_equal(out.fused, reference.fused), i
        assert all(j <= i for j in asked)
        assert out.fresh or not asked or asked[-1] < i, f"frame {i} waited for a mask no command needed yet"
    assert sorted(asked) == asked and len(asked) == 1 + 10 * 3  # every fused mask, in deadline order


def test_the_runtime_matches_navigator_step_on_the_same_masks() -> None:
    follower, _ = _follower(fuse=3)
    outputs = _drive(follower, 31)
    reference = Navigator(NavigatorConfig(method="segmin", depth_threshold=5.0, fuse_frames=1, smooth_window=1))
    for out in (o for o in outputs if o.fresh):
        expected = reference.step(out.fused, DEPTH)
        assert (out.command.v, out.command.omega, out.command.target_column) == (
            expected.v,
            expected.omega,
            expected.target_column,
        )


def test_a_gap_in_frames_stops_the_robot_and_restarts_the_runtime() -> None:
    follower, _ = _follower()
    outputs = _drive(follower, 30)
    last_t = outputs[-1].t
    assert follower.command_at(last_t + 0.1).v == outputs[-1].command.v > 0
    stop = follower.command_at(last_t + 0.6)  # frame_timeout_s = 0.5 by default
    assert (stop.v, stop.omega, stop.valid) == (0.0, 0.0, False)
    after = follower.step(_rgb(40), _depth(40), last_t + 1.0)
    assert after.stopped == "frame_timeout" and after.fresh
    # The EMA restarted from rest: one step of lambda = 0.5 towards the raw command.
    fresh = Navigator(NavigatorConfig(method="segmin", depth_threshold=5.0, fuse_frames=3, smooth_window=1))
    assert after.command.v == fresh.step(after.fused, DEPTH).v


def test_stale_masks_are_not_fused() -> None:
    # A 2 Hz camera: the commands at 0.2 s and 0.4 s use frame 0's mask, 0.4 s of age is stale.
    follower, _ = _follower(max_mask_age_s=0.3, frame_timeout_s=1.0)
    follower.step(_rgb(0), _depth(0), 0.0)
    out = follower.step(_rgb(1), _depth(1), 0.5)
    assert out.stopped == "stale_masks" and not out.command.valid and out.command_t == pytest.approx(0.4)
    again = follower.step(_rgb(2), _depth(2), 0.6)  # fresh masks again (0.5 s and 0.6 s)
    assert again.fresh and again.command.valid


def test_bad_timestamps_are_clear_errors() -> None:
    follower, _ = _follower()
    follower.step(_rgb(0), _depth(0), 1.0)
    with pytest.raises(ValueError, match="not after the previous frame"):
        follower.step(_rgb(1), _depth(1), 0.9)
    with pytest.raises(ValueError, match="not after the previous frame"):
        follower.step(_rgb(1), _depth(1), 1.0)
    with pytest.raises(ValueError, match="finite"):
        follower.step(_rgb(1), _depth(1), float("nan"))
    with pytest.raises(ValueError, match="depth is 3x8"):
        follower.step(_rgb(1), np.ones((8, 3), np.float32), 1.1)


def test_the_control_loop_time_must_be_a_finite_number_too() -> None:
    """A NaN clock never times out: command_at would keep the last command in force for ever."""
    follower, _ = _follower()
    _drive(follower, 10)
    for bad in (float("nan"), float("inf")):
        with pytest.raises(ValueError, match="command time must be finite"):
            follower.command_at(bad)
    with pytest.raises(ValueError, match="command time must be a number of seconds, got 'soon'"):
        follower.command_at("soon")


class _Recorder(Navigator):
    """SegMin with declared `inputs` that records what each command was given."""

    def __init__(self, inputs: NavigatorInputs) -> None:
        super().__init__(NavigatorConfig(method="segmin", depth_threshold=5.0, fuse_frames=1, smooth_window=1))
        self.inputs = inputs
        self.given: list[tuple] = []

    def command(self, fused, depth, attitude=None, rgb=None):
        self.given.append((attitude, rgb))
        return super().command(fused, depth, attitude, rgb)


@pytest.mark.parametrize("declared", [NavigatorInputs(), NavigatorInputs(rgb=True, attitude=True)])
def test_a_navigator_is_given_what_it_declares_and_nothing_more(declared: NavigatorInputs) -> None:
    navigator = _Recorder(declared)
    follower = RowFollower(FrameIndexSegmenter(), navigator)
    for i in range(7):
        follower.step(_rgb(i), _depth(i), i / 30, attitude=(0.01, -0.02))
    assert navigator.given
    for attitude, rgb in navigator.given:
        assert (attitude == (0.01, -0.02)) if declared.attitude else attitude is None
        assert (rgb is not None and rgb.shape == (H, W, 3)) if declared.rgb else rgb is None


def test_declared_depth_is_required_whatever_the_method() -> None:
    follower = RowFollower(FrameIndexSegmenter(), _Recorder(NavigatorInputs(depth=True)))
    with pytest.raises(ValueError, match="segmin needs depth"):
        follower.step(_rgb(0), None, 0.0)


def test_a_follower_without_a_segmenter_needs_the_masks() -> None:
    follower = RowFollower(None, Navigator(NavigatorConfig(method="segmin", depth_threshold=5.0)))
    with pytest.raises(ValueError, match="came without a mask, and this follower has no segmenter"):
        follower.step(_rgb(0), _depth(0), 0.0)


def test_depth_is_optional_for_segmin_and_required_for_segmind() -> None:
    follower, _ = _follower()
    out = follower.step(_rgb(5), None, 0.0)
    assert out.fresh and out.command.valid and out.command.target_column is not None
    follower, _ = _follower(method="segmind")
    with pytest.raises(ValueError, match="segmind needs depth"):
        follower.step(_rgb(5), None, 0.0)


def test_rates_must_divide_evenly() -> None:
    with pytest.raises(ValueError, match="multiple of command_hz"):
        RuntimeConfig(segment_hz=20, command_hz=6)
    with pytest.raises(ValueError, match="frame_timeout_s"):
        RuntimeConfig(frame_timeout_s=0)
