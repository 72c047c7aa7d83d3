"""Sensor faults that stop the robot: a blind or stalled camera must never look like an open row.

The navigators read only what the frames show. A depth frame without readings (NaN, 0, negative,
inf, beyond the sensor's range) leaves every vegetation pixel uncounted, so the paper's column
histogram reads "no vegetation" and the robot drives straight at full speed; a black image
segments to an empty mask with the same result; a frozen camera keeps steering on a view that no
longer exists; frames stamped on another clock make the runtime's timing meaningless. So
`RowFollower` runs these checks and stops the robot with a named reason while one holds
(`REASONS`), and drives again once good frames return:

- `depth_invalid` / `depth_invalid_left` / `depth_invalid_right`: at each command, on the part of
  the image the navigator uses (the fused mask's vegetation pixels, whose depth every navigator
  reads), the share with a valid reading falls under `min_valid_depth` overall, or under
  `min_valid_depth_side` on one image half (left: columns left of the centre). Both halves (or
  the whole without either half) failing is `depth_invalid`. A part with fewer than
  `min_judged_pixels` sampled vegetation pixels is not judged (it hardly moves the histogram).
- `image_black` / `image_white`: at least `blank_share` of the sampled pixels have every channel
  at or below `black_level` (or at or above `white_level`): a covered, unlit or blinded lens.
- `image_frozen`: the sampled pixels stay identical for longer than `frozen_s` while the robot is
  commanded to move (a real camera's noise changes some pixels every frame; a standing robot may
  see a still scene in a simulator). Once flagged it holds until the pixels change.
- `depth_frozen`: the same for the depth frame, judged on the same sampled pixels (NaN equal to
  NaN: a repeated frame without readings is repeated too): a driver that repeats its last depth
  frame while colour stays live would have the robot steer on stale depth. Judged on frames
  that carry an image and depth (a real depth camera's noise changes some readings every frame).
- `clock_offset`: a frame's stamp is further than `max_clock_offset_s` from the follower's clock
  (`RowFollower.step(now=...)`, the node's clock): a bag's own times played against the wall clock.

Checks read a regular grid of about `sample_pixels` pixels (strided), so they cost well under a
millisecond per frame at any camera size (the frozen-depth check adds one strided copy and one
comparison of about `sample_pixels` floats: about 0.05 ms per frame,
docs/results/history/benchmarks.md). numpy only (the bare robot install).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

# In the order a stop names them when several hold.
REASONS = (
    "clock_offset",
    "image_black",
    "image_white",
    "image_frozen",
    "depth_frozen",
    "depth_invalid",
    "depth_invalid_left",
    "depth_invalid_right",
)


@dataclass(frozen=True)
class SensorChecks:
    """The limits of the sensor checks (module docstring); a share of 0 switches its check off.

    The defaults keep the simulator's normal frames clear in the five test fields (its 2 % random
    dropouts and no return beyond 16 m: the lowest valid share of a run, overall or on a half, was
    0.83 with the exact masks and 0.74 with the shipped models; docs/results/history/closed-loop.md)
    and stop a blind camera within one command, a frozen one within 0.3 m at 0.5 m/s.
    """

    min_valid_depth: float = 0.5  # share of the used pixels with valid depth, whole image
    min_valid_depth_side: float = 0.3  # ... on the left or the right image half
    min_judged_pixels: int = 20  # sampled vegetation pixels a share needs to be judged
    max_depth_m: float = 20.0  # readings beyond the sensor's range are invalid
    black_level: int = 10  # a pixel is black when every channel is at most this
    white_level: int = 245  # ... white when every channel is at least this
    blank_share: float = 0.98  # share of black (white) pixels that makes the image black (white)
    frozen_s: float = (
        0.25  # identical pixels (image or depth) for longer than this, while moving: frozen (0.12 m at 0.5 m/s)
    )
    max_clock_offset_s: float = 0.5  # frame stamp vs the follower's clock
    sample_pixels: int = 4096  # about this many pixels read per check (a regular grid)

    def __post_init__(self) -> None:
        for name in ("min_valid_depth", "min_valid_depth_side", "blank_share"):
            value = getattr(self, name)
            if not _is_number(value) or not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be a share within [0, 1] (0: off), got {value!r}")
        for name in ("min_judged_pixels", "sample_pixels"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        for name in ("black_level", "white_level"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 255:
                raise ValueError(f"{name} must be an integer within [0, 255], got {value!r}")
        if self.black_level >= self.white_level:
            raise ValueError(f"black_level ({self.black_level}) must be below white_level ({self.white_level})")
        for name in ("max_depth_m", "frozen_s", "max_clock_offset_s"):
            value = getattr(self, name)
            if not _is_number(value) or math.isnan(value) or value <= 0:
                raise ValueError(f"{name} must be a number > 0, got {value!r}")
        if not math.isfinite(self.max_depth_m):  # an infinite reading must stay no reading
            raise ValueError(f"max_depth_m must be a finite number of metres, got {self.max_depth_m!r}")


def _is_number(value: object) -> bool:
    return not isinstance(value, bool) and isinstance(value, numbers.Real)


def check_depth_range(depth_threshold: float, checks: SensorChecks) -> None:
    """ValueError unless the navigator's depth cut lies within the sensor's range: past
    `max_depth_m` a reading is no reading, and it must never count as near vegetation."""
    if depth_threshold > checks.max_depth_m:
        raise ValueError(
            f"depth_threshold ({depth_threshold:g} m) is beyond the sensor's range, max_depth_m "
            f"({checks.max_depth_m:g} m): readings past the range would count as vegetation"
        )


def sample_step(shape: tuple[int, ...], pixels: int) -> int:
    """The stride of a regular grid holding about `pixels` pixels of an image of `shape`."""
    return max(1, math.isqrt(shape[0] * shape[1] // pixels))


def valid_depth(depth_m: np.ndarray, max_depth_m: float) -> np.ndarray:
    """Where depth (metres) is a reading: finite, > 0 and within the sensor's range.

    NaN compares false, so one pair of comparisons also drops NaN and +-inf (inf > max)."""
    return (depth_m > 0) & (depth_m <= max_depth_m)


def depth_fault(mask: np.ndarray, depth_m: np.ndarray, checks: SensorChecks) -> tuple[str, str] | None:
    """(reason, detail) when too few of the mask's vegetation pixels have valid depth, else None.

    `mask` is the fused mask (the pixels the navigator reads depth for), `depth_m` metres."""
    step = sample_step(mask.shape, checks.sample_pixels)
    used = mask[::step, ::step]
    valid = valid_depth(depth_m[::step, ::step], checks.max_depth_m) & used
    middle = math.ceil(mask.shape[1] / (2 * step))  # sampled columns left of the image centre
    shares = {}
    for part, columns in (("", slice(None)), ("_left", slice(0, middle)), ("_right", slice(middle, None))):
        count = int(np.count_nonzero(used[:, columns]))
        if count >= checks.min_judged_pixels:
            shares[part] = (int(np.count_nonzero(valid[:, columns])) / count, count)
    failed = [
        part
        for part, (share, _) in shares.items()
        if share < (checks.min_valid_depth if part == "" else checks.min_valid_depth_side)
    ]
    sides = [part for part in failed if part]
    if not failed:
        return None
    part = sides[0] if len(sides) == 1 else ""
    share, count = shares[part]  # the whole is judged whenever a half is
    limit = "min_valid_depth" if part == "" else "min_valid_depth_side"
    where = "the image" if part == "" else f"the {part[1:]} image half"
    return (
        f"depth_invalid{part}",
        f"{share:.0%} of the {count} sampled vegetation pixels of {where} have valid depth "
        f"({limit} {getattr(checks, limit):g}, valid: > 0 and <= max_depth_m {checks.max_depth_m:g} m)",
    )


def blank_image_fault(sample: np.ndarray, checks: SensorChecks) -> tuple[str, str] | None:
    """(reason, detail) for a sampled H x W x 3 uint8 image that is all black or all white, else None."""
    pixels = sample.shape[0] * sample.shape[1]
    red, green, blue = sample[..., 0], sample[..., 1], sample[..., 2]
    # Channel by channel: numpy's reduction over a strided last axis of 3 took 14x as long.
    brightest = np.maximum(np.maximum(red, green), blue)
    darkest = np.minimum(np.minimum(red, green), blue)
    for reason, count, level in (
        ("image_black", np.count_nonzero(brightest <= checks.black_level), checks.black_level),
        ("image_white", np.count_nonzero(darkest >= checks.white_level), checks.white_level),
    ):
        if count >= checks.blank_share * pixels and checks.blank_share > 0:
            side = "<=" if reason == "image_black" else ">="
            return (
                reason,
                f"{count / pixels:.0%} of the sampled pixels have every channel {side} {level} "
                f"(blank_share {checks.blank_share:g})",
            )
    return None


def clock_fault(t: float, now: float, checks: SensorChecks) -> tuple[str, str] | None:
    """(reason, detail) when a frame stamped `t` is further than the limit from the clock `now`."""
    offset = now - t
    if abs(offset) <= checks.max_clock_offset_s:
        return None
    way = "behind" if offset > 0 else "ahead of"
    hint = (
        "; frames from a bag or a simulator? run the node on their clock (use_sim_time true)" if abs(offset) > 1 else ""
    )
    return (
        "clock_offset",
        f"frame stamps are {abs(offset):.3f} s {way} the follower's clock "
        f"(max_clock_offset_s {checks.max_clock_offset_s:g}){hint}",
    )


class FrozenStream:
    """One stream's frozen check (`image_frozen`, `depth_frozen`): its last sample and since when
    it has not changed while the robot moved."""

    def __init__(self, reason: str, what: str) -> None:
        self.reason, self.what = reason, what
        self._last: np.ndarray | None = None
        self._unchanged_since = 0.0

    def judge(self, sample: np.ndarray, t: float, moving: bool, frozen_s: float, active: dict[str, str]) -> None:
        """Update `active` with this stream's fault for `sample` at `t` (NaN equals NaN)."""
        changed = self._last is None or not np.array_equal(sample, self._last, equal_nan=sample.dtype.kind == "f")
        if changed:
            self._last = sample.copy()
            self._unchanged_since = t
            active.pop(self.reason, None)
        elif self.reason in active:
            return  # held until the pixels change
        elif not moving:
            self._unchanged_since = t  # a standing robot may see a still scene
        elif t - self._unchanged_since > frozen_s:
            active[self.reason] = (
                f"the sampled {self.what} have not changed for {t - self._unchanged_since:.2f} s while driving "
                f"(frozen_s {frozen_s:g})"
            )


class SensorFaults:
    """The faults that hold now (reason -> detail), updated per frame and per command.

    Image and clock faults (and a frozen depth stream) are judged on every frame that carries
    them, the depth faults at each command (on the fused mask and the newest depth)."""

    def __init__(self, checks: SensorChecks) -> None:
        self.checks = checks
        self.reset()

    def reset(self) -> None:
        """Forget every fault and the frozen-frame memory (a restart)."""
        self.active: dict[str, str] = {}
        self._frozen_image = FrozenStream("image_frozen", "pixels")
        self._frozen_depth = FrozenStream("depth_frozen", "depth pixels")

    @property
    def reason(self) -> str | None:
        """The first fault that holds, in `REASONS` order, or None."""
        return next((reason for reason in REASONS if reason in self.active), None)

    def on_frame(
        self, rgb: np.ndarray | None, t: float, now: float | None, moving: bool, depth: np.ndarray | None = None
    ) -> None:
        """Judge a frame's image and depth (when it has an image: a frame without one is no
        camera frame) and stamp (when the clock `now` is given: a frame without it is not judged
        on the clock); `moving`: the command in force moves the robot."""
        self._set("clock_offset", None if now is None else clock_fault(t, now, self.checks))
        if rgb is None:
            return
        image = np.asarray(rgb)
        step = sample_step(image.shape, self.checks.sample_pixels)
        sample = image[::step, ::step]
        blank = blank_image_fault(sample, self.checks) if sample.ndim == 3 and sample.dtype == np.uint8 else None
        self._set("image_black", blank if blank is not None and blank[0] == "image_black" else None)
        self._set("image_white", blank if blank is not None and blank[0] == "image_white" else None)
        self._frozen_image.judge(sample, t, moving, self.checks.frozen_s, self.active)
        if depth is None:
            self.active.pop("depth_frozen", None)
        else:
            depth_sample = np.asarray(depth)[::step, ::step]  # the image's grid (depth is aligned to it)
            self._frozen_depth.judge(depth_sample, t, moving, self.checks.frozen_s, self.active)

    def on_command(self, mask: np.ndarray, depth_m: np.ndarray | None) -> None:
        """Judge the depth the command reads (None: a navigator run without depth, nothing to judge)."""
        found = None if depth_m is None else depth_fault(mask, depth_m, self.checks)
        for reason in ("depth_invalid", "depth_invalid_left", "depth_invalid_right"):
            self._set(reason, found if found is not None and found[0] == reason else None)

    def _set(self, reason: str, found: tuple[str, str] | None) -> None:
        if found is None:
            self.active.pop(reason, None)
        else:
            self.active[reason] = found[1]
