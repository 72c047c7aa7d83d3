"""`segmin replay`: the robot runtime (`RowFollower`) over a recorded sequence, offline.

Input: a folder of RGB frames (any image OpenCV reads) or a video file, with optional aligned
depth named like the RGB frames (same stem). Depth units by format: uint16 PNG = millimetres
(0 = no reading), float32 .npy = metres (values above 1000 are refused: millimetres saved as
float). A folder plays in natural name order (f_2 before f_10), said in a note; names that
leave the order open (two files of one stem, f_01 beside f_1) are refused. Timestamps come from
`--fps` (frame i at i / fps), from `--timestamps` (one number of seconds per line, one per
frame) or, for a video, from the file's own frame rate. Reading the sequence is `sequence.py`.

Output (in `--out`, which must be empty unless `--force`): `commands.csv` (one row per command:
t, v, omega, target_column, valid), `overlay.mp4` (per command: the frame with the mask and the
chosen column, the depth cut, the column histogram and the command; GIF without an MP4
encoder) and `commands.png` (target column and commands over time). The plot needs the [sim]
extra's matplotlib; on the bare robot install it is skipped and the summary says so, the CSV
and the video are still written.

Bad input stops the replay with one line naming the frame or the argument (ValueError or
FileNotFoundError): frames out of time order, a frame of another size than the first one,
depth of another size than the RGB frame, implausible float depth (see above), a
missing or unreadable depth or RGB file, a video OpenCV cannot open, a timestamp count that does
not match the frames, rates that do not divide evenly. Non-finite pixels in .npy depth are "no
reading", as the navigator treats them; the frames that had some are counted in the summary.
Without depth, SegMin and SegZeros run on the mask alone (said in the summary); SegMinD and
SegCorridor need depth and are refused.

The runtime is configured by a `FollowerConfig` (nav_eval.runtime.follower_config: `--follower`
and `KEY=VALUE`), built into its navigator by the runtime's `make_navigator`, as nav-eval and
the ROS 2 node build theirs. SegCorridor needs the camera: a bag's CameraInfo (`camera`) or the
config's own intrinsics, and levels its depth points with the IMU's roll and pitch when given
one (`imu`: a bag's, `replay.imu.ImuTrack`, each frame with the newest sample at or before its
stamp, as the node and the simulator do); without one it assumes level ground (said in the summary).

No torch, pybullet or matplotlib at import: this runs on the bare robot install.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.atomic import write_text
from segmin.common.outputs import check_output_dir
from segmin.nav_eval.replay.imu import ImuTrack
from segmin.nav_eval.replay.sequence import RecordedSequence, read_sequence
from segmin.nav_eval.replay.video import overlay, write_video
from segmin.nav_eval.runtime.camera import CameraGeometry
from segmin.nav_eval.runtime.follower import FollowerOutput, RowFollower, RuntimeConfig
from segmin.nav_eval.runtime.follower_config import FollowerConfig, make_navigator
from segmin.nav_eval.runtime.methods import DEPTH_METHODS
from segmin.nav_eval.runtime.navigator import NavigatorConfig
from segmin.nav_eval.runtime.sensor_faults import REASONS


@dataclass
class ReplayResult:
    """What a replay produced: the command rows, the written files and the summary lines."""

    commands: list[tuple[float, float, float, float | None, bool]]
    files: list[Path]
    notes: list[str] = field(default_factory=list)
    frames: int = 0


@dataclass
class FrameSource:
    """A sequence to replay from elsewhere than a folder or a video (a ROS bag: `replay.bags`).

    `frames` yields (name, t, rgb, depth metres or None, had non-finite depth) like
    `iter_sequence`; `notes` is read once they ran (what the source skipped, say).
    """

    count: int
    frames: Iterator[tuple[str, float, np.ndarray, np.ndarray | None, bool]]
    has_depth: bool
    notes: Callable[[], list[str]] = list


def _sequence(
    rgb: str | Path | None,
    depth: str | Path | None,
    fps: float | None,
    timestamps: str | Path | None,
    source: FrameSource | None,
) -> RecordedSequence:
    """The frames to replay: a bag's `source`, else the folder or video `rgb` (with `depth`)."""
    if source is not None:
        return RecordedSequence(count=source.count, frames=source.frames)
    if rgb is None:
        raise ValueError("give --rgb (a folder of frames or a video) or --bag")
    return read_sequence(
        Path(rgb), None if depth is None else Path(depth), fps, None if timestamps is None else Path(timestamps)
    )


def check_out_dir(out: Path, force: bool) -> None:
    """Refuse a file in the way, and a non-empty output folder unless `force` (nothing is
    overwritten silently); before the model runs."""
    check_output_dir(out, "--out")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise ValueError(f"--out {out}: folder is not empty (use --force to overwrite its replay outputs)")


def _paper_follower(
    method: str | None, depth_threshold: float | None, mask_closing: int, runtime: RuntimeConfig | None
) -> FollowerConfig:
    """The follower config of replay's keywords for the paper's methods (no config given)."""
    if method is None or depth_threshold is None:
        raise TypeError("replay needs a follower config, or a method and a depth threshold")
    navigator = NavigatorConfig(method=method, depth_threshold=depth_threshold, mask_closing=mask_closing)
    return FollowerConfig(navigator, runtime or RuntimeConfig())


def replay(
    model: str | Path,
    rgb: str | Path | None,
    out: str | Path,
    *,
    follower: FollowerConfig | None = None,
    camera: CameraGeometry | None = None,
    method: str | None = None,
    depth_threshold: float | None = None,
    mask_closing: int = 0,
    depth: str | Path | None = None,
    fps: float | None = None,
    timestamps: str | Path | None = None,
    force: bool = False,
    runtime: RuntimeConfig | None = None,
    threads: int = 2,
    segmenter: Any = None,
    source: FrameSource | None = None,
    imu: ImuTrack | None = None,
    live: Any = None,
) -> ReplayResult:
    """Run the runtime over the sequence and write the outputs (see the module docstring).

        The runtime is `follower` on `camera` (SegCorridor's; None: the config's intrinsics), or
        for the paper's methods `method`, `depth_threshold`, `mask_closing` and `runtime`. The
        sequence is `rgb` (with `depth`, `fps`, `timestamps`), or `source` (rgb None then); `imu`
    gives the attitude at each frame to a navigator that levels its points (SegCorridor); `live`
    (a `live.publisher.LiveView`) is given every step, for `--live`."""
    if str(model) == "oracle":
        raise ValueError(
            "--model oracle needs the simulator's exact masks; replay takes an exported .onnx or .tflite file"
        )
    follower = follower or _paper_follower(method, depth_threshold, mask_closing, runtime)
    method, depth_threshold = follower.method, follower.navigator.depth_threshold
    has_depth = source.has_depth if source is not None else depth is not None
    if not has_depth and method in DEPTH_METHODS:
        raise ValueError(f"--method {method} needs --depth (depth frames); without depth use segmin (mask alone)")
    navigator = make_navigator(follower, camera)  # SegCorridor without a camera: refused before any frame
    out = Path(out)
    check_out_dir(out, force)
    sequence = _sequence(rgb, depth, fps, timestamps, source)
    if segmenter is None:
        from segmin.nav_eval.runtime.segmenter import load_segmenter

        segmenter = load_segmenter(model, threads=threads)
    runner = RowFollower(segmenter, navigator, follower.runtime)
    result = ReplayResult(commands=[], files=[], frames=sequence.count)
    if sequence.order is not None:
        result.notes.append(sequence.order)
    video: list[np.ndarray] = []
    non_finite, restarts = 0, 0
    fault_stops: Counter[str] = Counter()  # commands stopped by a sensor fault, by reason
    levels = imu if navigator.inputs.attitude else None  # the paper's methods take no attitude
    for name, t, image, d, bad in sequence.frames:
        non_finite += bad
        try:
            output = runner.step(image, d, t, attitude=None if levels is None else levels.at(t))
        except ValueError as exc:
            raise ValueError(f"frame {name}: {exc}") from None
        restarts += output.stopped == "frame_timeout"
        if live is not None:
            live.step(t, image, output, navigator)
        if output.fresh:
            cmd = output.command
            if output.stopped in REASONS:
                fault_stops[output.stopped] += 1
            result.commands.append((t, cmd.v, cmd.omega, cmd.target_column, cmd.valid))
            video.append(overlay_panel(image, output, depth_threshold))
    if not result.commands:  # an empty table and no video are no replay: say so rather than "wrote"
        raise ValueError(f"no frame of the {sequence.count} reached the runtime: nothing written")
    _write_outputs(out, result, video, runner.config.command_hz)
    if source is not None:
        result.notes.extend(source.notes())
    result.notes.extend(_input_notes(method, has_depth, navigator.inputs.attitude, levels))
    if non_finite:
        result.notes.append(f"{non_finite} depth frame(s) had non-finite pixels, used as 'no reading'")
    result.notes.extend(_stop_notes(fault_stops, restarts, runner.config.frame_timeout_s))
    return result


def _stop_notes(fault_stops: Counter[str], restarts: int, frame_timeout_s: float) -> list[str]:
    """What stopped the runtime during the replay: sensor faults (commands by reason), gaps between frames."""
    notes = []
    if fault_stops:
        counts = ", ".join(f"{reason} {count}" for reason, count in fault_stops.items())
        notes.append(f"sensor faults stopped the robot (commands by reason: {counts})")
    if restarts:
        notes.append(
            f"{restarts} gap(s) longer than {frame_timeout_s} s between frames: the runtime stopped and restarted there"
        )
    return notes


def _input_notes(method: str, has_depth: bool, wants_attitude: bool, imu: ImuTrack | None) -> list[str]:
    """What the replay ran without: depth (the mask alone), the IMU (level ground: no IMU, or
    frames without a fresh sample)."""
    notes = []
    if not has_depth:
        notes.append(f"no depth: {method} ran on the mask alone (every vegetation pixel counts as near)")
    if wants_attitude and imu is None:
        notes.append(f"no IMU: {method} assumed level ground (its depth points are not levelled)")
    return notes + (imu.notes() if imu is not None else [])


def _write_outputs(out: Path, result: ReplayResult, video: list[np.ndarray], command_hz: float) -> None:
    """commands.csv, overlay.mp4 and (with matplotlib) commands.png, named in `result`."""
    result.files.append(_write_csv(out / "commands.csv", result.commands))
    result.files.append(write_video(out / "overlay.mp4", video, fps=command_hz))
    plot = _try_plot(out / "commands.png", result.commands)
    if plot is None:
        result.notes.append(
            "commands.png skipped: the plot needs the [sim] extra's matplotlib "
            "(pip install 'segmin[sim]'); commands.csv and the video are written"
        )
    else:
        result.files.append(plot)


def _write_csv(path: Path, rows: list[tuple[float, float, float, float | None, bool]]) -> Path:
    lines = ["t,v,omega,target_column,valid"]
    for t, v, omega, column, valid in rows:
        lines.append(f"{t!r},{v!r},{omega!r},{'' if column is None else repr(column)},{int(valid)}")
    write_text(path, "\n".join(lines) + "\n")
    return path


def read_commands_csv(path: str | Path) -> list[tuple[float, float, float, float | None, bool]]:
    """The rows of a commands.csv, exactly as written (floats round-trip through repr)."""
    rows = []
    for line in Path(path).read_text().splitlines()[1:]:
        t, v, omega, column, valid = line.split(",")
        rows.append((float(t), float(v), float(omega), None if column == "" else float(column), valid == "1"))
    return rows


def overlay_panel(rgb: np.ndarray, output: FollowerOutput, depth_threshold: float) -> np.ndarray:
    """One video frame: camera + mask + chosen column | depth cut, over the histogram and command."""
    import cv2

    cmd = output.command
    height, width = rgb.shape[:2]
    left = overlay(rgb, output.fused, cmd.target_column)
    cut = np.zeros((height, width, 3), dtype=np.uint8)
    if output.depth is not None:
        near = (output.depth > 0) & (output.depth <= depth_threshold)
        shade = np.clip(255 * (1 - output.depth / depth_threshold), 60, 255).astype(np.uint8)
        cut[near] = np.stack([shade[near]] * 3, axis=1)
        if output.fused is not None:
            cut[near & output.fused] = (0, 200, 0)
    bars = np.full((max(height // 2, 24), 2 * width, 3), 255, dtype=np.uint8)
    hist = np.asarray(cmd.histogram, dtype=float)
    if hist.size:
        top = hist.max() if hist.max() > 0 else 1.0
        xs = np.linspace(0, 2 * width - 1, hist.size).astype(int)
        for x, value in zip(xs, hist):
            bars[bars.shape[0] - int(round((bars.shape[0] - 12) * value / top)) :, x : x + 2] = (70, 70, 200)
    if cmd.target_column is not None:
        x = int(round(cmd.target_column * (2 * width - 1) / max(width - 1, 1)))
        bars[:, max(x - 1, 0) : x + 1] = (255, 0, 0)
    text = f"t {output.t:.2f}s v {cmd.v:.2f} w {cmd.omega:+.2f}" + ("" if cmd.valid else " STOP")
    cv2.putText(bars, text, (2, 10), cv2.FONT_HERSHEY_PLAIN, 0.7, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([np.concatenate([left, cut], axis=1), bars], axis=0)


def _try_plot(path: Path, rows: list[tuple[float, float, float, float | None, bool]]) -> Path | None:
    """The command plot, or None without matplotlib (the bare robot install)."""
    try:
        from segmin.nav_eval.replay.plot import plot_commands
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] == "matplotlib":
            return None
        raise
    plot_commands(path, rows)
    return path
