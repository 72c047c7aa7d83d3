"""Every RGB frame is read by data.readers.read_image: an unreadable file is a one-line error naming it."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from segmin.data.agriseg_loader import DatasetError, read_image


def _write_png(path: Path, truncate: bool = False) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, data = cv2.imencode(".png", np.full((8, 8, 3), 90, np.uint8))
    assert ok
    path.write_bytes(data.tobytes()[:40] if truncate else data.tobytes())
    return path


def test_read_image_is_rgb_and_names_a_truncated_file(tmp_path):
    good = _write_png(tmp_path / "good.png")
    assert read_image(good).shape == (8, 8, 3)
    bad = _write_png(tmp_path / "bad.png", truncate=True)
    with pytest.raises(DatasetError, match=r"bad\.png: truncated PNG") as info:
        read_image(bad)
    assert "\n" not in str(info.value)


def test_export_verification_frames_name_an_unreadable_file(tmp_path):
    from segmin.export.verify import load_frames

    _write_png(tmp_path / "a.png")
    _write_png(tmp_path / "b.png", truncate=True)
    with pytest.raises(ValueError, match=r"b\.png: truncated PNG"):
        load_frames(tmp_path, (8, 8))


def test_pipeline_onnx_timing_names_an_unreadable_frame(tmp_path):
    """Its reader was a bare cv2.imread: a bad frame used to end in a TypeError about None."""
    from segmin.app.pipeline.stages import onnx_latency_ms

    _write_png(tmp_path / "images" / "Image1" / "Image1.png")
    (tmp_path / "images" / "Image2").mkdir(parents=True)
    (tmp_path / "images" / "Image2" / "Image2.png").write_bytes(b"not a png")
    with pytest.raises(DatasetError, match=r"Image2\.png: truncated PNG"):
        onnx_latency_ms(tmp_path / "model.onnx", tmp_path, count=2)
