"""`segmin replay`: the runtime over a recorded sequence, its outputs and its bad-input errors.

The fixture is a short sequence rendered by a RowEnv run in the analytic stand-in world
(tiny frames, 30 Hz), written as RGB PNGs and uint16 millimetre depth PNGs.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from test_nav_eval_sim import FakeRenderer, FakeWorld, _config

from segmin.app.cli import main
from segmin.data.frames import DatasetError
from segmin.data.readers import read_depth as read_dataset_depth
from segmin.nav_eval.replay.run import read_commands_csv, replay
from segmin.nav_eval.replay.sequence import natural_key, read_sequence
from segmin.nav_eval.replay.video import write_video
from segmin.nav_eval.runtime.follower import RowFollower
from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig
from segmin.nav_eval.runtime.segmenter import OnnxSegmenter
from segmin.nav_eval.sim.row_env import RowEnv

FRAMES = 24  # 0.8 s at 30 Hz: 4 commands at 5 Hz


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> tuple[Path, Path, list[tuple[np.ndarray, np.ndarray]]]:
    folder = tmp_path_factory.mktemp("sequence")
    rgb_dir, depth_dir = folder / "rgb", folder / "depth"
    rgb_dir.mkdir()
    depth_dir.mkdir()
    world = FakeWorld()
    env = RowEnv(world, FakeRenderer(world, size=48), _config())
    env.reset(seed=0)
    frames = []
    for i in range(FRAMES):
        frame = env.frame()
        depth_mm = np.clip(np.round(frame.depth * 1000), 0, 65535).astype(np.uint16)
        cv2.imwrite(str(rgb_dir / f"{i:04d}.png"), cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(depth_dir / f"{i:04d}.png"), depth_mm)
        frames.append((frame.rgb, depth_mm))
        env.step((0.4, 0.0))
    return rgb_dir, depth_dir, frames


@pytest.fixture(scope="module")
def model(exported: tuple[Path, dict]) -> Path:
    return exported[0]


def test_replay_writes_all_outputs_and_the_commands_of_the_runtime(sequence, model, tmp_path) -> None:
    rgb_dir, depth_dir, frames = sequence
    code = main(
        [
            "replay",
            "--model",
            str(model),
            "--rgb",
            str(rgb_dir),
            "--depth",
            str(depth_dir),
            "--fps",
            "30",
            "--method",
            "segmind",
            "--depth-threshold",
            "5",
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert code == 0
    out = tmp_path / "out"
    assert (out / "commands.csv").is_file() and (out / "commands.png").is_file()
    assert (out / "overlay.mp4").is_file() or (out / "overlay.gif").is_file()
    rows = read_commands_csv(out / "commands.csv")
    follower = RowFollower(
        OnnxSegmenter(model, threads=2), Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0))
    )
    expected = []
    for i, (rgb, depth) in enumerate(frames):
        o = follower.step(rgb, depth, i / 30)
        if o.fresh:
            expected.append((i / 30, o.command.v, o.command.omega, o.command.target_column, o.command.valid))
    assert len(rows) == 4 and rows == expected
    # Without --force a second replay into the same folder is refused.
    assert (
        main(
            [
                "replay",
                "--model",
                str(model),
                "--rgb",
                str(rgb_dir),
                "--fps",
                "30",
                "--method",
                "segmin",
                "--depth-threshold",
                "5",
                "--out",
                str(out),
            ]
        )
        == 2
    )


class _CrownWithAHole:
    """A segmenter that sees one crown across the image, with a 4 px hole (a bare branch) right of centre."""

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        mask = np.zeros(rgb.shape[:2], dtype=bool)
        mask[4:40] = True
        mask[10:34, 36:40] = False
        return mask


@pytest.mark.parametrize("mask_closing", [0, 12])  # px at 224 px of width: 2.6 px on these 48 px frames
def test_mask_closing_reaches_the_replayed_navigator(sequence, model, tmp_path, monkeypatch, mask_closing) -> None:
    """Without closing, SegMin steers at the hole (column 37.5); closed, every column is alike and
    it steers straight (the mean of all the tied columns: the image centre, 23.5)."""
    rgb_dir, _, _ = sequence
    monkeypatch.setattr("segmin.nav_eval.runtime.segmenter.OnnxSegmenter", lambda *_, **__: _CrownWithAHole())
    argv = ["replay", "--model", str(model), "--rgb", str(rgb_dir), "--fps", "30", "--method", "segmin"]
    argv += ["--depth-threshold", "5", "--mask-closing", str(mask_closing), "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    targets = {row[3] for row in read_commands_csv(tmp_path / "out" / "commands.csv")}
    assert targets == ({23.5} if mask_closing else {37.5})


def test_a_mask_closing_beyond_the_frame_is_refused_naming_the_flag(sequence, model, tmp_path, capsys) -> None:
    """100000 ran out of memory at the first frame; a disc wider than the 224 px reference frame closes nothing more."""
    rgb_dir, _, _ = sequence
    argv = ["replay", "--model", str(model), "--rgb", str(rgb_dir), "--fps", "30", "--method", "segmin"]
    argv += ["--depth-threshold", "5", "--mask-closing", "100000", "--out", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["segmin: error: --mask-closing must be an integer from 0 to 112 px, got 100000"]
    assert not (tmp_path / "out").exists()


def test_a_depth_cut_beyond_the_sensors_range_is_refused_naming_the_flag(sequence, model, tmp_path, capsys) -> None:
    rgb_dir, _, _ = sequence
    argv = ["replay", "--model", str(model), "--rgb", str(rgb_dir), "--fps", "30", "--method", "segmind"]
    assert main([*argv, "--depth-threshold", "25", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("segmin: error: --depth-threshold 25: depth_threshold (25 m) is beyond")
    assert "max_depth_m (20 m)" in err[0]
    assert not (tmp_path / "out").exists()


def test_without_depth_segmin_runs_on_the_mask_and_segmind_is_refused(sequence, model, tmp_path, capsys) -> None:
    rgb_dir, _, _ = sequence
    assert (
        main(
            [
                "replay",
                "--model",
                str(model),
                "--rgb",
                str(rgb_dir),
                "--fps",
                "30",
                "--method",
                "segmin",
                "--depth-threshold",
                "5",
                "--out",
                str(tmp_path / "a"),
            ]
        )
        == 0
    )
    assert "ran on the mask alone" in capsys.readouterr().out
    assert (
        main(
            [
                "replay",
                "--model",
                str(model),
                "--rgb",
                str(rgb_dir),
                "--fps",
                "30",
                "--method",
                "segmind",
                "--depth-threshold",
                "5",
                "--out",
                str(tmp_path / "b"),
            ]
        )
        == 2
    )
    assert "segmind needs --depth" in capsys.readouterr().err


def _copy(sequence, tmp_path: Path) -> tuple[Path, Path]:
    rgb_dir, depth_dir, _ = sequence
    rgb, depth = tmp_path / "rgb", tmp_path / "depth"
    rgb.mkdir()
    depth.mkdir()
    for p in rgb_dir.iterdir():
        (rgb / p.name).write_bytes(p.read_bytes())
    for p in depth_dir.iterdir():
        (depth / p.name).write_bytes(p.read_bytes())
    return rgb, depth


def _run(model, rgb, depth=None, **kw):
    return replay(
        model,
        rgb,
        kw.pop("out"),
        method=kw.pop("method", "segmind" if depth else "segmin"),
        depth_threshold=5.0,
        depth=depth,
        **kw,
    )


def test_bad_inputs_are_one_line_errors_naming_the_frame(sequence, model, tmp_path) -> None:
    rgb, depth = _copy(sequence, tmp_path)
    out = tmp_path / "out"
    stamps = tmp_path / "t.txt"
    stamps.write_text(
        "\n".join(str(t) for t in [i / 30 for i in range(5)] + [0.1] + [i / 30 for i in range(6, FRAMES)])
    )
    with pytest.raises(ValueError, match=r"frame 0005.png: .*not after the previous frame"):
        _run(model, rgb, depth, timestamps=stamps, out=out)
    stamps.write_text("0.0\n0.1\n")
    with pytest.raises(ValueError, match="2 timestamps for 24 frames"):
        _run(model, rgb, depth, timestamps=stamps, out=out)
    with pytest.raises(ValueError, match="needs --fps or --timestamps"):
        _run(model, rgb, depth, out=out)
    with pytest.raises(ValueError, match="multiple of command_hz"):
        from segmin.nav_eval.runtime.follower import RuntimeConfig

        _run(model, rgb, depth, fps=30, out=out, runtime=RuntimeConfig(segment_hz=20, command_hz=3))
    with pytest.raises(ValueError, match="oracle"):
        replay("oracle", rgb, out, method="segmin", depth_threshold=5.0, fps=30)
    small = cv2.imread(str(depth / "0003.png"), cv2.IMREAD_UNCHANGED)[:20]
    cv2.imwrite(str(depth / "0003.png"), small)
    with pytest.raises(ValueError, match=r"0003.png is 48x20, the RGB frame 0003.png is 48x48"):
        _run(model, rgb, depth, fps=30, out=out)
    (depth / "0003.png").unlink()
    with pytest.raises(FileNotFoundError, match="no depth frame for 0003.png"):
        _run(model, rgb, depth, fps=30, out=out)
    (depth / "0003.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="cannot read .*0003.png"):
        _run(model, rgb, depth, fps=30, out=out)
    (rgb / "0002.png").write_bytes(b"broken")
    with pytest.raises(ValueError, match="cannot read .*0002.png"):
        _run(model, rgb, None, fps=30, out=out)
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"no video here")
    with pytest.raises(ValueError, match="OpenCV cannot open"):
        _run(model, video, None, out=out)
    assert not out.exists()  # nothing written by a refused replay


def test_non_finite_npy_depth_is_no_reading_and_counted(sequence, model, tmp_path) -> None:
    rgb, _ = _copy(sequence, tmp_path)
    depth = tmp_path / "depth_npy"
    depth.mkdir()
    for i, (_, mm) in enumerate(sequence[2]):
        d = mm.astype(np.float32) / 1000
        if i == 4:
            d[0, :5] = np.nan
        np.save(depth / f"{i:04d}.npy", d)
    result = _run(model, rgb, depth, fps=30, out=tmp_path / "out")
    assert any("1 depth frame(s) had non-finite pixels" in n for n in result.notes)
    assert all(np.isfinite(r[1]) and np.isfinite(r[2]) for r in result.commands)


def test_a_black_stretch_of_a_recording_stops_the_runtime_and_is_noted(sequence, model, tmp_path) -> None:
    rgb, _ = _copy(sequence, tmp_path)
    for i in range(8, FRAMES):  # a covered lens from 0.27 s on
        cv2.imwrite(str(rgb / f"{i:04d}.png"), np.zeros((48, 48, 3), np.uint8))
    result = _run(model, rgb, None, fps=30, out=tmp_path / "out")  # SegMin on the images alone
    assert [valid for *_, valid in result.commands] == [True, True, False, False]
    assert "sensor faults stopped the robot (commands by reason: image_black 2)" in result.notes


# ----------------------------------------------------------------------------- frame order and names


def _frames_named(folder: Path, names: list[str], size: int = 16) -> Path:
    folder.mkdir()
    for i, name in enumerate(names):
        cv2.imwrite(str(folder / name), np.full((size, size, 3), i, np.uint8))
    return folder


def _played(rgb: Path, depth: Path | None = None) -> list[str]:
    return [name for name, *_ in read_sequence(rgb, depth, 30.0, None).frames]


def test_unpadded_frame_numbers_play_in_natural_order_and_the_order_is_said(sequence, model, tmp_path) -> None:
    names = [f"f_{i}.png" for i in range(12)]
    rgb = _frames_named(tmp_path / "unpadded", names[::-1])
    assert _played(rgb) == names  # not f_0, f_1, f_10, f_11, f_2 ... (plain text order)
    assert natural_key("f_2") < natural_key("f_10") and natural_key("b0") > natural_key("a10")
    # Padded names keep their order; the note names the order used.
    padded, _ = _copy(sequence, tmp_path)
    assert _played(padded) == sorted(p.name for p in padded.iterdir())
    result = _run(model, padded, fps=30, out=tmp_path / "out")
    assert "24 frames in natural name order (numbers by value): 0000.png, 0001.png, 0002.png, ..., 0023.png" in (
        result.notes
    )


def test_names_that_leave_the_order_open_are_refused(tmp_path) -> None:
    rgb = _frames_named(tmp_path / "rgb", ["f_001.png", "f_002.png", "f_002.jpg"])
    with pytest.raises(ValueError, match=r"--rgb .*: f_002.jpg and f_002.png are the same frame \('f_002'\) twice"):
        read_sequence(rgb, None, 30.0, None)
    rgb = _frames_named(tmp_path / "rgb2", ["f_01.png", "f_1.png", "f_2.png"])
    with pytest.raises(ValueError, match="f_01.png and f_1.png carry the same number"):
        read_sequence(rgb, None, 30.0, None)
    rgb = _frames_named(tmp_path / "rgb3", ["f_1.png", "f_2.png"])
    depth = tmp_path / "depth"
    depth.mkdir()
    for stem in ("f_1", "f_2"):
        cv2.imwrite(str(depth / f"{stem}.png"), np.full((16, 16), 2000, np.uint16))
    np.save(depth / "f_2.npy", np.full((16, 16), 2.0, np.float32))
    with pytest.raises(ValueError, match=r"--depth .*: f_2.npy and f_2.png are the same frame"):
        read_sequence(rgb, depth, 30.0, None)


def test_a_frame_of_another_size_is_refused_without_depth(sequence, model, tmp_path) -> None:
    rgb, _ = _copy(sequence, tmp_path)
    image = cv2.imread(str(rgb / "0005.png"))
    cv2.imwrite(str(rgb / "0005.png"), cv2.resize(image, (40, 40)))
    with pytest.raises(ValueError, match=r"--rgb: 0005.png is 40x40, the frames before it are 48x48"):
        _run(model, rgb, fps=30, out=tmp_path / "out")
    assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match=r"video frames of 2 sizes"):  # the writer never drops frames silently
        write_video(tmp_path / "v.mp4", [np.zeros((8, 8, 3), np.uint8), np.zeros((8, 6, 3), np.uint8)])


def test_float_depth_in_millimetres_is_refused_naming_the_file_and_range(sequence, model, tmp_path) -> None:
    rgb, _ = _copy(sequence, tmp_path)
    depth = tmp_path / "depth_mm"
    depth.mkdir()
    for i, (_, mm) in enumerate(sequence[2]):
        np.save(depth / f"{i:04d}.npy", mm.astype(np.float32))  # millimetres, saved as float
    with pytest.raises(ValueError, match=r"0000.npy: float depth must be metres, but its values range from .* to "):
        _run(model, rgb, depth, fps=30, out=tmp_path / "out")
    args = ["--rgb", str(rgb), "--depth", str(depth), "--fps", "30", "--depth-threshold", "5"]
    assert main(["replay", "--model", str(model), *args, "--out", str(tmp_path / "out")]) == 2
    # The same check guards the float formats of datasets (EXR, float TIFF).
    tiff = tmp_path / "d.tiff"
    cv2.imwrite(str(tiff), np.full((4, 4), 17407.0, np.float32))
    with pytest.raises(DatasetError, match=r"d.tiff: float depth must be metres, but its values range from 17407"):
        read_dataset_depth(tiff)
    cv2.imwrite(str(tiff), np.full((4, 4), 17.4, np.float32))
    assert read_dataset_depth(tiff).max() == pytest.approx(17.4)
