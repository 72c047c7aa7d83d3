"""OnnxSegmenter: what the navigator loads on the robot (onnxruntime + numpy + cv2 only)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from export_helpers import SIZE, field_image

from segmin.export import metadata as md
from segmin.export.onnx import DeployWrapper
from segmin.models.checkpoint import load_model
from segmin.nav_eval.runtime.protocols import Segmenter
from segmin.nav_eval.runtime.segmenter import OnnxSegmenter


@pytest.fixture(scope="module")
def model_path(exported) -> Path:
    return exported[0]


@pytest.fixture(scope="module")
def torch_wrapper(checkpoint):
    model, _ = load_model(checkpoint)
    return DeployWrapper(model).eval()


def _frame(height: int, width: int, seed: int = 0) -> np.ndarray:
    return field_image(np.random.default_rng(seed), height, width)[0]


def test_model_size_frame_matches_pytorch(model_path, torch_wrapper) -> None:
    segmenter = OnnxSegmenter(model_path, threads=2)
    assert isinstance(segmenter, Segmenter)
    assert segmenter.input_size == (SIZE, SIZE) and segmenter.threshold == 0.5
    rgb = _frame(SIZE, SIZE)
    probs = segmenter.probabilities(rgb)
    mask = segmenter.segment(rgb)
    with torch.inference_mode():
        reference = torch_wrapper(torch.from_numpy(rgb[None])).numpy()[0, 0]
    assert probs.dtype == np.float32 and probs.shape == (SIZE, SIZE)
    assert mask.dtype == np.bool_ and mask.shape == (SIZE, SIZE)
    assert np.abs(probs - reference).max() <= 1e-4
    assert (mask == (reference >= 0.5)).mean() >= 0.999
    assert 0 < mask.sum() < mask.size  # the tiny model sees both classes


@pytest.mark.parametrize("height,width", [(48, 80), (128, 96), (SIZE, 2 * SIZE)])
def test_other_frame_sizes_are_resized_both_ways(model_path, height, width) -> None:
    import cv2

    segmenter = OnnxSegmenter(model_path)
    rgb = _frame(height, width, seed=height)
    mask = segmenter.segment(rgb)
    probs = segmenter.probabilities(rgb)
    assert mask.shape == (height, width) and mask.dtype == np.bool_
    assert probs.shape == (height, width) and probs.dtype == np.float32
    assert probs.min() >= 0.0 and probs.max() <= 1.0
    # The mask is the model-size mask resized back with nearest neighbour.
    shrink = height >= SIZE and width >= SIZE
    small = cv2.resize(rgb, (SIZE, SIZE), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    model_mask = segmenter.segment(small)
    expected = cv2.resize(model_mask.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
    np.testing.assert_array_equal(mask, expected)


def test_threshold_override(model_path) -> None:
    rgb = _frame(SIZE, SIZE, seed=5)
    probs = OnnxSegmenter(model_path).probabilities(rgb)
    low, high = OnnxSegmenter(model_path, threshold=0.05), OnnxSegmenter(model_path, threshold=0.95)
    np.testing.assert_array_equal(low.segment(rgb), probs >= 0.05)
    np.testing.assert_array_equal(high.segment(rgb), probs >= 0.95)
    with pytest.raises(ValueError, match="threshold"):
        OnnxSegmenter(model_path, threshold=1.5)


def test_bad_frames_give_clear_errors(model_path) -> None:
    segmenter = OnnxSegmenter(model_path)
    rgb = _frame(SIZE, SIZE)
    with pytest.raises(ValueError, match="dtype is float32"):
        segmenter.segment(rgb.astype(np.float32))
    with pytest.raises(ValueError, match="3 channels"):
        segmenter.segment(np.dstack([rgb, rgb[..., :1]]))
    with pytest.raises(ValueError, match="3 channels"):
        segmenter.probabilities(rgb[..., 0])
    with pytest.raises(ValueError, match="numpy array"):
        segmenter.segment(rgb.tolist())


def test_bad_files_give_clear_errors(model_path, tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.onnx"):
        OnnxSegmenter(tmp_path / "missing.onnx")
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"this is not a protobuf" * 10)
    with pytest.raises(ValueError, match="garbage.onnx: not a loadable ONNX model"):
        OnnxSegmenter(garbage)

    model = onnx.load(str(model_path))
    props = {p.key: p.value for p in model.metadata_props}

    def save_with(meta: dict[str, str], name: str) -> Path:
        del model.metadata_props[:]
        onnx.helper.set_model_props(model, meta)
        path = tmp_path / name
        onnx.save(model, str(path))
        return path

    # An ONNX file that is not a segmin export (no metadata).
    with pytest.raises(ValueError, match="not a segmin ONNX model"):
        OnnxSegmenter(save_with({}, "plain.onnx"))
    # Metadata that does not describe the graph's input.
    with pytest.raises(ValueError, match="does not match metadata"):
        OnnxSegmenter(save_with({**props, md.KEY_INPUT_SIZE: "32,32"}, "lying.onnx"))
    with pytest.raises(ValueError, match="channel order"):
        OnnxSegmenter(save_with({**props, md.KEY_CHANNEL_ORDER: "BGR"}, "bgr.onnx"))
    with pytest.raises(ValueError, match="input_size"):
        OnnxSegmenter(save_with({**props, md.KEY_INPUT_SIZE: "big"}, "nosize.onnx"))


def test_fp16_and_int8_files_load_in_the_segmenter(model_path) -> None:
    from segmin.export.pipeline import variant_path

    rgb = _frame(SIZE, SIZE, seed=9)
    fp32 = OnnxSegmenter(model_path).probabilities(rgb)
    for tag in ("fp16", "int8"):
        probs = OnnxSegmenter(variant_path(model_path, tag)).probabilities(rgb)
        assert probs.shape == fp32.shape and np.abs(probs - fp32).max() < 0.1


def test_full_perception_control_step(model_path) -> None:
    from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig

    segmenter = OnnxSegmenter(model_path)
    navigator = Navigator(NavigatorConfig(method="segmind", depth_threshold=5.0))
    rgb = _frame(SIZE, SIZE, seed=2)
    depth = np.full((SIZE, SIZE), 3.0, np.float32)
    command = navigator.step(segmenter.segment(rgb), depth)
    assert np.isfinite(command.v) and np.isfinite(command.omega)
    assert command.histogram.shape == (SIZE,)


def test_background_segmentation_gives_the_masks_of_segment(model_path) -> None:
    """The closed loop segments on a helper thread (prepare here, onnxruntime there): same masks."""
    from types import SimpleNamespace

    from segmin.nav_eval.sim.segmentation import BackgroundSegmenter, ModelFrameSegmenter

    segmenter = OnnxSegmenter(model_path, threads=1)
    frames = [_frame(SIZE + 8 * k, SIZE, seed=20 + k) for k in range(4)]
    with BackgroundSegmenter(ModelFrameSegmenter(segmenter)) as background:
        futures = [background.submit(SimpleNamespace(rgb=rgb)) for rgb in frames]
        masks = [future.result() for future in futures]
    for rgb, mask in zip(frames, masks):
        assert mask.dtype == np.bool_ and mask.shape == rgb.shape[:2]
        assert np.array_equal(mask, segmenter.segment(rgb))
    with pytest.raises(ValueError, match="dtype"):
        segmenter.prepare(frames[0].astype(np.float32))
