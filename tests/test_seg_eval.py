"""`segmin eval-seg` (nav_eval.seg_eval): a perfect and an empty model, mean vs pooled figures, bad input."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from export_helpers import field_image

from segmin.app.cli import main
from segmin.common.seg_metrics import PixelCounts
from segmin.data.agriseg_loader import find_frames
from segmin.data.real_sets import shipped_real_data
from segmin.nav_eval.seg_eval.predictor import Predictor
from segmin.nav_eval.seg_eval.results import write_results
from segmin.nav_eval.seg_eval.score import evaluate

CROP = (0, 255, 0)


def write_set(
    folder: Path, count: int = 3, size: tuple[int, int] = (48, 64), empty_last: bool = False, toy: bool = False
) -> Path:
    """A flat images/ + masks/ set; crop pixels are pure green so a fake model can read them off."""
    rng = np.random.default_rng(3)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    (folder / "masks").mkdir(parents=True, exist_ok=True)
    height, width = size
    for i in range(count):
        if toy:
            image, mask = field_image(rng, height, width)
        else:
            mask = np.zeros((height, width), bool)
            if not (empty_last and i == count - 1):
                mask[height // 3 :, 5 + 7 * i : 25 + 7 * i] = True
            image = np.full((height, width, 3), (128, 64, 0), np.uint8)
            image[mask] = CROP
        cv2.imwrite(str(folder / "images" / f"photo_{i}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / "masks" / f"photo_{i}.png"), mask.astype(np.uint8) * 255)
    return folder


def fake_predictor(size: tuple[int, int], *, background: bool = False) -> Predictor:
    """A "model" that returns the ground truth (green pixels), or nothing at all."""

    def probabilities(batch: np.ndarray) -> np.ndarray:
        if background:
            return np.zeros(batch.shape[1:3], np.float32)
        return (batch[0, :, :, 1] > 200).astype(np.float32)

    return Predictor(Path("fake.onnx"), "onnx", size, 0.5, probabilities)


def one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("segmin: error: ")
    return err


# ----------------------------------------------------------------------------- figures


def test_a_model_that_returns_the_ground_truth_scores_one(tmp_path: Path) -> None:
    data = write_set(tmp_path / "set", count=3, empty_last=True)
    summary, sheet = evaluate(fake_predictor((48, 64)), find_frames(data), data)
    figures = summary.figures()
    assert figures["mean_iou"] == 1.0 and figures["pooled_iou"] == 1.0
    assert figures["precision"] == 1.0 and figures["recall"] == 1.0 and figures["pixel_accuracy"] == 1.0
    assert figures["images_without_crop"] == 1  # the empty image: IoU 1.0, recall undefined
    assert math.isnan(summary.images[-1].counts.recall) and summary.images[-1].counts.iou == 1.0
    assert sheet is not None and sheet.shape[0] > 3 * 48 and sheet.dtype == np.uint8


def test_the_ground_truth_survives_resizing_to_the_model_and_back(tmp_path: Path) -> None:
    data = write_set(tmp_path / "set", count=2, size=(96, 128))
    summary, _ = evaluate(fake_predictor((48, 64)), find_frames(data), data)
    assert summary.images[0].width == 128 and summary.images[0].height == 96  # scored at the mask size
    assert summary.figures()["mean_iou"] > 0.9


def test_an_all_background_model(tmp_path: Path) -> None:
    data = write_set(tmp_path / "set", count=2)
    summary, sheet = evaluate(fake_predictor((48, 64), background=True), find_frames(data), data)
    figures = summary.figures()
    assert figures["mean_iou"] == 0.0 and figures["pooled_iou"] == 0.0 and figures["recall"] == 0.0
    assert math.isnan(figures["precision"]) and figures["images_without_prediction"] == 2
    assert "precision (pooled)    n/a" in "\n".join(summary.summary_lines())
    paths = write_results(summary, sheet, tmp_path / "out")
    saved = json.loads(Path(paths["json"]).read_text())
    assert saved["summary"]["precision"] is None and saved["rows"][0]["precision"] is None
    assert "n/a" in Path(paths["csv"]).read_text().splitlines()[1]
    with pytest.raises(ValueError, match="use --force"):
        write_results(summary, sheet, tmp_path / "out")


def test_a_probability_exactly_at_the_threshold_is_vegetation() -> None:
    """The mask is `probability >= threshold`, as the robot's segmenter has it."""
    levels = np.array([[0.25, 0.5, 0.5 - 2**-20, 0.75]], np.float32)
    predictor = Predictor(Path("fake.onnx"), "onnx", (1, 4), 0.5, lambda batch: levels)
    probs, mask = predictor.predict(np.zeros((1, 4, 3), np.uint8))  # the model's size: no resizing
    assert np.array_equal(probs, levels)
    assert mask.tolist() == [[False, True, False, True]]


def test_the_real_photos_ship_with_the_package() -> None:
    root = shipped_real_data()
    frames = find_frames(root)
    assert len(frames) == 8 and (root / "README.md").is_file()
    assert "CC BY 4.0" in (root / "README.md").read_text()


def write_pairs(folder: Path, pairs: list[tuple[np.ndarray, np.ndarray]]) -> Path:
    """A flat set whose photos show the prediction (green) and whose masks are the truth, for `fake_predictor`."""
    (folder / "images").mkdir(parents=True)
    (folder / "masks").mkdir(parents=True)
    for i, (prediction, truth) in enumerate(pairs):
        image = np.zeros((*prediction.shape, 3), np.uint8)
        image[prediction] = CROP
        cv2.imwrite(str(folder / "images" / f"photo_{i}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / "masks" / f"photo_{i}.png"), truth.astype(np.uint8) * 255)
    return folder


def crop_rows(*rows: int) -> np.ndarray:
    mask = np.zeros((8, 8), bool)
    mask[list(rows)] = True
    return mask


def test_mean_iou_over_photos_differs_from_the_pooled_iou(tmp_path: Path) -> None:
    data = write_pairs(
        tmp_path / "set",
        [
            (crop_rows(0, 1), crop_rows(0)),  # photo_0: TP 8, FP 8, FN 0, TN 48 -> IoU 0.5, P 0.5, R 1
            (crop_rows(0), crop_rows(0, 1, 2, 3)),  # photo_1: TP 8, FP 0, FN 24, TN 32 -> IoU 0.25, P 1, R 0.25
            (crop_rows(), crop_rows()),  # photo_2: TN 64 -> IoU 1.0, P and R n/a
        ],
    )
    summary, _ = evaluate(fake_predictor((8, 8)), find_frames(data), data)  # model size = photo size: no resizing
    assert [r.counts for r in summary.images] == [
        PixelCounts(tp=8, fp=8, fn=0, tn=48),
        PixelCounts(tp=8, fp=0, fn=24, tn=32),
        PixelCounts(tn=64),
    ]
    figures = summary.figures()
    assert figures["mean_iou"] == 7 / 12  # (0.5 + 0.25 + 1.0) / 3
    # pooled: TP 16, FP 8, FN 24, TN 144
    assert figures["pooled_iou"] == 1 / 3  # 16 / 48
    assert (figures["precision"], figures["recall"], figures["pixel_accuracy"]) == (2 / 3, 0.4, 5 / 6)
    assert (figures["mean_precision"], figures["mean_recall"]) == (0.75, 0.625)  # photo_2 left out of both
    assert figures["images_without_prediction"] == 1 and figures["images_without_crop"] == 1
    lines = summary.summary_lines()
    assert "  mean IoU over images  0.583" in lines and "  pooled IoU            0.333" in lines

    paths = write_results(summary, None, tmp_path / "out")
    saved = json.loads(Path(paths["json"]).read_text())
    assert saved["summary"]["mean_iou"] == 7 / 12 and saved["summary"]["pooled_iou"] == 1 / 3
    assert [row["iou"] for row in saved["rows"]] == [0.5, 0.25, 1.0] and saved["rows"][2]["precision"] is None
    table = list(csv.DictReader(Path(paths["csv"]).read_text().splitlines()))
    assert [(r["iou"], r["precision"], r["recall"]) for r in table] == [
        ("0.5", "0.5", "1"),
        ("0.25", "1", "0.25"),
        ("1", "n/a", "n/a"),
    ]


def test_truth_closing_scores_against_the_canopy_region(tmp_path: Path) -> None:
    leaves = np.zeros((16, 16), bool)
    leaves[:, 2:14:2] = True  # six shoots one pixel apart: the exact mask calls the gaps background
    band = np.zeros((16, 16), bool)
    band[:, 2:13] = True  # a model that paints the canopy region, gaps included
    data = write_pairs(tmp_path / "set", [(band, leaves)])
    exact, _ = evaluate(fake_predictor((16, 16)), find_frames(data), data)
    assert exact.images[0].counts == PixelCounts(tp=96, fp=80, fn=0, tn=80)
    closed, _ = evaluate(fake_predictor((16, 16)), find_frames(data), data, truth_closing=2)
    assert closed.images[0].counts == PixelCounts(tp=176, fp=0, fn=0, tn=80)
    assert "truth closed with a 2 px disc" in closed.summary_lines()[0]
    saved = json.loads(Path(write_results(closed, None, tmp_path / "out")["json"]).read_text())
    assert saved["truth_closing"] == 2
    with pytest.raises(ValueError, match="truth closing radius must be an integer from 0 to 112 px"):
        evaluate(fake_predictor((16, 16)), find_frames(data), data, truth_closing=-1)


# ----------------------------------------------------------------------------- command


def test_eval_seg_on_a_tiny_export_and_its_checkpoint(tmp_path: Path, exported, checkpoint, capsys) -> None:
    data = write_set(tmp_path / "toy", count=3, size=(72, 96), toy=True)
    onnx_path, _ = exported
    assert main(["eval-seg", "--model", str(onnx_path), "--data", str(data), "--out", str(tmp_path / "onnx")]) == 0
    out = capsys.readouterr().out
    for figure in ("mean IoU over images", "pooled IoU", "precision (pooled)", "recall (pooled)", "pixel accuracy"):
        assert figure in out
    for name in ("results.csv", "results.json", "contact_sheet.png"):
        assert (tmp_path / "onnx" / name).stat().st_size > 0
    sheet = cv2.imread(str(tmp_path / "onnx" / "contact_sheet.png"))
    assert sheet is not None and sheet.shape[0] > 3 * 200
    onnx_result = json.loads((tmp_path / "onnx" / "results.json").read_text())
    assert onnx_result["kind"] == "onnx" and onnx_result["input_size"] == [64, 64] and len(onnx_result["rows"]) == 3

    assert main(["eval-seg", "--model", str(checkpoint), "--data", str(data), "--out", str(tmp_path / "pt")]) == 0
    pt_result = json.loads((tmp_path / "pt" / "results.json").read_text())
    assert pt_result["kind"] == "checkpoint"
    # Same preprocessing, same network: the exported graph and the checkpoint agree.
    assert abs(pt_result["summary"]["mean_iou"] - onnx_result["summary"]["mean_iou"]) < 0.01

    assert main(["eval-seg", "--model", str(onnx_path), "--data", str(data), "--out", str(tmp_path / "onnx")]) == 2
    assert "use --force" in one_error_line(capsys)
    assert (
        main(
            [
                "eval-seg",
                "--model",
                str(onnx_path),
                "--data",
                str(data),
                "--out",
                str(tmp_path / "onnx"),
                "--force",
                "--threshold",
                "0.3",
            ]
        )
        == 0
    )
    assert json.loads((tmp_path / "onnx" / "results.json").read_text())["threshold"] == 0.3
    assert (
        main(["eval-seg", "--model", str(onnx_path), "--data", str(data), "--out", str(tmp_path / "x"), "--size", "96"])
        == 2
    )
    assert "fixed 64x64 input" in one_error_line(capsys)


def _bad_folder(tmp_path: Path, kind: str) -> tuple[Path, str]:
    folder = tmp_path / kind
    if kind == "empty":
        folder.mkdir()
        return folder, "no dataset found"
    write_set(folder, count=2)
    if kind == "unpaired":
        (folder / "masks" / "photo_1.png").unlink()
        return folder, "photo_1.png: image of frame 1 has no mask"
    (folder / "images" / "photo_0.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really a png" + b"IEND\xaeB`\x82")
    return folder, "photo_0.png: unreadable image"


@pytest.mark.parametrize("kind", ["empty", "unpaired", "unreadable"])
def test_bad_folders_fail_with_one_line(kind: str, tmp_path: Path, checkpoint, capsys) -> None:
    folder, message = _bad_folder(tmp_path, kind)
    assert main(["eval-seg", "--model", str(checkpoint), "--data", str(folder), "--out", str(tmp_path / "out")]) == 2
    err = one_error_line(capsys)
    assert message in err and str(folder) in err
    assert not (tmp_path / "out" / "results.json").exists()


def test_bad_models_fail_with_one_line(tmp_path: Path, capsys) -> None:
    data = write_set(tmp_path / "set", count=1)
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"not a model")
    text = tmp_path / "model.txt"
    text.write_text("hello")
    fake_checkpoint = tmp_path / "fake.pt"
    fake_checkpoint.write_bytes(b"not a checkpoint")
    for model, message in (
        (tmp_path / "missing.onnx", "model file not found"),
        (garbage, "not a loadable ONNX model"),
        (text, "unknown model type '.txt'"),
        (fake_checkpoint, "not a readable segmin checkpoint"),
    ):
        assert main(["eval-seg", "--model", str(model), "--data", str(data), "--out", str(tmp_path / "out")]) == 2
        err = one_error_line(capsys)
        assert message in err and str(model) in err
    assert (
        main(["eval-seg", "--model", str(garbage), "--data", str(tmp_path / "nowhere"), "--out", str(tmp_path / "out")])
        == 2
    )
    assert "evaluation data folder not found" in one_error_line(capsys)
    out = str(tmp_path / "out")
    assert main(["eval-seg", "--model", str(garbage), "--data", str(data), "--out", out, "--truth-closing", "-2"]) == 2
    assert "--truth-closing must be an integer from 0 to 112 px, got -2" in one_error_line(capsys)
    # A typo'd radius is refused before the model loads, not out of memory minutes later.
    assert (
        main(["eval-seg", "--model", str(garbage), "--data", str(data), "--out", out, "--truth-closing", "100000"]) == 2
    )
    assert "--truth-closing must be an integer from 0 to 112 px, got 100000" in one_error_line(capsys)
    assert not (tmp_path / "out").exists()
    # training takes only multiples of 32 (train.config), so eval-seg refuses any other side, naming --size
    for size in ("33", "16"):
        out = str(tmp_path / "out")
        assert main(["eval-seg", "--model", str(garbage), "--data", str(data), "--out", out, "--size", size]) == 2
        assert f"--size={size}: must be a positive multiple of 32" in one_error_line(capsys)
