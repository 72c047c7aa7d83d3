"""eval-seg's steering figures, drivable strips and uniform frames (nav_eval.seg_eval.steering, strips, blank_frames)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_seg_eval import one_error_line, write_set

from segmin.app.cli import main
from segmin.data.agriseg_loader import find_frames
from segmin.nav_eval.seg_eval.blank_frames import BLANK_FRAMES, blank_frame_shares
from segmin.nav_eval.seg_eval.predictor import Predictor
from segmin.nav_eval.seg_eval.score import evaluate
from segmin.nav_eval.seg_eval.steering import photo_steering, segmin_target, steering_figures, to_steering_width


def two_rows(height: int = 120, width: int = 448, gap: tuple[int, int] = (180, 260)) -> np.ndarray:
    """Crop on both sides of a free gap of columns [gap) (a row seen from inside)."""
    mask = np.zeros((height, width), bool)
    mask[20:, : gap[0]] = True
    mask[20:, gap[1] :] = True
    return mask


def test_the_target_is_the_centre_of_the_gap_at_224_px_whatever_the_photo_width() -> None:
    # The gap's centre at 448 px is column 219.5, i.e. 109.5 at 224 (0-based centres: (x + 0.5) / 2 - 0.5).
    assert segmin_target(two_rows()).column == pytest.approx(109.5, abs=0.5)
    assert segmin_target(two_rows(width=224, gap=(90, 130))).column == pytest.approx(109.5, abs=0.5)
    assert to_steering_width(two_rows()).shape == (60, 224)


def test_a_row_end_painted_across_the_gap_moves_the_target_out_of_the_corridor() -> None:
    truth = two_rows()
    hedge = truth.copy()
    hedge[20:110, 150:300] = True  # a dark hedge closing the row, painted as crop over the gap
    hedge[:, 420:] = False  # and the far right edge left unpainted (a backlit row)
    steering = photo_steering(hedge, truth)
    assert steering.truth_target == pytest.approx(109.5, abs=0.5)
    assert not steering.in_corridor and steering.at_edge and steering.error_px > 90
    assert steering.corridor[0] <= 109 <= steering.corridor[1]
    assert photo_steering(truth, truth).error_px == 0 and photo_steering(truth, truth).in_corridor


def test_the_corridor_is_the_clearly_free_run_that_holds_the_truth_minimum() -> None:
    truth = two_rows(width=224, gap=(80, 140))
    truth[20:, 180:190] = False  # a second, narrower gap: not the one the truth steers into
    steering = photo_steering(truth, truth)
    start, stop = steering.corridor
    # The smoothing widens the 60-column gap's free plateau by a few columns at most.
    assert 70 <= start <= 85 and 135 <= stop <= 150
    into_second_gap = truth.copy()
    into_second_gap[20:, 60:160] = True
    moved = photo_steering(into_second_gap, truth)
    assert 175 <= moved.model_target <= 195 and not moved.in_corridor


def test_an_empty_truth_has_every_column_in_its_corridor() -> None:
    empty = np.zeros((50, 100), bool)
    prediction = two_rows(50, 100, (40, 60))
    steering = photo_steering(prediction, empty)
    assert steering.in_corridor and steering.corridor == (0, 223)


def test_the_set_summary() -> None:
    truth = two_rows()
    photos = [photo_steering(truth, truth), photo_steering(np.roll(truth, 40, axis=1), truth)]
    figures = steering_figures(photos)
    assert figures["target_error_median_px"] == pytest.approx(10.0, abs=0.6)
    assert figures["target_error_worst_px"] == pytest.approx(20.0, abs=1.0)
    assert figures["targets_outside_corridor"] == 1 and figures["targets_at_edge"] == 0
    assert "targets_outside_strip" not in figures


def test_a_strip_says_whether_the_target_is_on_the_drivable_ground() -> None:
    truth = two_rows()
    strip = np.zeros(truth.shape, bool)
    strip[60:, 190:250] = True
    prediction = truth.copy()
    prediction[20:, 180:260] = True  # the real gap painted over
    prediction[20:, 100:130] = False  # and a false gap on the left: the model steers there
    on = photo_steering(truth, truth, strip)
    off = photo_steering(prediction, truth, strip)
    assert on.in_strip and not off.in_strip
    painted = truth.copy()
    painted[90:, 190:220] = True  # a quarter of the strip (its near left half) painted as crop
    assert photo_steering(painted, truth, strip).crop_on_strip == pytest.approx(0.25, abs=0.01)
    figures = steering_figures([on, off])
    assert figures["strip_photos"] == 2 and figures["targets_outside_strip"] == 1


# ----------------------------------------------------------------------------- strips on disk


def pure_green_predictor(size: tuple[int, int]) -> Predictor:
    """The ground truth of `write_set` (pure green pixels) and nothing on any uniform frame but green."""

    def probabilities(batch: np.ndarray) -> np.ndarray:
        return ((batch[0, :, :, 1] > 200) & (batch[0, :, :, 0] < 50)).astype(np.float32)

    return Predictor(Path("green.onnx"), "onnx", size, 0.5, probabilities)


def write_strips(data: Path, polygons: dict[str, list[list[float]]]) -> None:
    (data / "strips").mkdir(exist_ok=True)
    for stem, polygon in polygons.items():
        (data / "strips" / f"{stem}.json").write_text(json.dumps({"polygon": polygon}))


def test_eval_seg_reports_steering_strips_and_uniform_frames(tmp_path: Path, capsys) -> None:
    data = write_set(tmp_path / "set", count=3, size=(48, 64))
    write_strips(data, {"photo_0": [[40, 47], [63, 47], [63, 20], [45, 20]]})
    strip_mask = np.zeros((48, 64), np.uint8)
    strip_mask[30:, 0:4] = 255
    cv2.imwrite(str(data / "strips" / "photo_1.png"), strip_mask)
    frames = find_frames(data)
    summary, sheet = evaluate(pure_green_predictor((48, 64)), frames, data)
    figures = summary.figures()
    assert figures["target_error_median_px"] == 0 and figures["targets_outside_corridor"] == 0
    assert figures["strip_photos"] == 2 and figures["crop_on_strip_mean"] == pytest.approx(0.0)
    rows = {r.name: r.row() for r in summary.images}
    assert rows["photo_0"]["target_in_strip"] is True and rows["photo_1"]["target_in_strip"] is False
    assert "target_in_strip" not in rows["photo_2"]
    assert set(summary.blank_frames) == set(BLANK_FRAMES) and figures["blank_frames_worst"] == 0
    assert sheet is not None


def test_uniform_frames_painted_as_crop_are_counted() -> None:
    def paints_dark(batch: np.ndarray) -> np.ndarray:
        return (batch[0].max(axis=2) < 10).astype(np.float32)  # a model that calls darkness crop

    shares = blank_frame_shares(Predictor(Path("dark.onnx"), "onnx", (32, 32), 0.5, paints_dark))
    assert shares["black"] == 1.0 and all(v == 0 for k, v in shares.items() if k != "black")


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (
            lambda d: write_strips(d, {"photo_0": [[0, 0], [70, 0], [0, 40]]}),
            "strip point (70, 0) lies outside the 64x48 image",
        ),
        (lambda d: write_strips(d, {"photo_9": [[0, 0], [10, 0], [0, 10]]}), "no photo named 'photo_9' in the set"),
        (
            lambda d: write_strips(d, {"photo_0": [[0, 0], [10, 0]]}),
            "polygon must be at least three finite [x, y] points",
        ),
        (
            lambda d: cv2.imwrite(str(d / "strips" / "photo_0.png"), np.full((10, 10), 255, np.uint8)),
            "strip mask size 10x10 does not match its photo's 64x48",
        ),
    ],
)
def test_bad_strip_labels_fail_with_one_line_naming_the_file(tmp_path: Path, make, message, checkpoint, capsys) -> None:
    data = write_set(tmp_path / "set", count=2, size=(48, 64))
    (data / "strips").mkdir()
    make(data)
    out = tmp_path / "out"
    assert main(["eval-seg", "--model", str(checkpoint), "--data", str(data), "--out", str(out)]) == 2
    err = one_error_line(capsys)
    assert message in err and str(data / "strips") in err
    assert not (out / "results.json").exists()


def test_labels_that_do_not_match_their_photos_fail_with_one_line(tmp_path: Path, checkpoint, capsys) -> None:
    data = write_set(tmp_path / "size", count=2, size=(48, 64))
    cv2.imwrite(str(data / "masks" / "photo_1.png"), np.zeros((40, 64), np.uint8))
    assert main(["eval-seg", "--model", str(checkpoint), "--data", str(data), "--out", str(tmp_path / "a")]) == 2
    err = one_error_line(capsys)
    assert "photo_1.png: mask size 64x40 does not match image" in err
    extra = write_set(tmp_path / "names", count=2, size=(48, 64))
    cv2.imwrite(str(extra / "masks" / "photo_7.png"), np.zeros((48, 64), np.uint8))
    assert main(["eval-seg", "--model", str(checkpoint), "--data", str(extra), "--out", str(tmp_path / "b")]) == 2
    assert "photo_7.png" in one_error_line(capsys)
    assert not (tmp_path / "a" / "results.json").exists() and not (tmp_path / "b" / "results.json").exists()


def test_strip_labels_refuse_photos_that_share_a_stem(tmp_path: Path) -> None:
    from segmin.data.agriseg_loader import DatasetError, Frame
    from segmin.nav_eval.seg_eval.strips import find_strips

    (tmp_path / "strips").mkdir()
    (tmp_path / "strips" / "000001.png").write_bytes(b"")
    frames = [
        Frame(domain, "train", 1, tmp_path / domain / "000001.png", tmp_path / domain / "m.png")
        for domain in ("vineyard_a", "vineyard_b")
    ]
    with pytest.raises(DatasetError, match="share the stem '000001'"):
        find_strips(tmp_path, frames)
    assert find_strips(tmp_path, frames[:1]) == {frames[0].image_path: tmp_path / "strips" / "000001.png"}
