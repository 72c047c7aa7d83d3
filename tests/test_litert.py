"""LiteRT export (`segmin export --format tflite`) and the runtime's `LiteRtSegmenter`.

One tiny checkpoint (conftest's, 64 px) is converted once per module by litert-torch, fp32 and
INT8 (the conversion is the slow part, about 15 s on 2 cores); the tests read that export.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from export_helpers import SIZE, write_frames

from segmin.app.cli import main as segmin_main
from segmin.app.pipeline.config import load_pipeline_config
from segmin.common.config import ConfigError
from segmin.export import litert_file
from segmin.export import metadata as md
from segmin.export.onnx import DeployWrapper
from segmin.export.pipeline import ExportOptions, export_checkpoint, report_path, variant_path
from segmin.export.verify import MAX_ABS_DIFF, MIN_MASK_AGREEMENT, compare, load_frames
from segmin.models.checkpoint import load_model
from segmin.nav_eval.runtime import LiteRtSegmenter, OnnxSegmenter, Segmenter
from segmin.nav_eval.runtime.segmenter import load_segmenter, runtime_model_file
from segmin.nav_eval.runtime.shipped_models import ENV_MODELS_DIR


@pytest.fixture(scope="module")
def litert_export(tmp_path_factory, checkpoint: Path, frames_dir: Path) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("litert") / "model.tflite"
    args = ["export", "--format", "tflite", "--checkpoint", str(checkpoint), "--out", str(out)]
    assert segmin_main([*args, "--calib-data", str(frames_dir), "--int8", "--calib-frames", "6"]) == 0
    return out, json.loads(report_path(out).read_text())


def _torch_probs(checkpoint: Path, frames: np.ndarray) -> np.ndarray:
    model, _ = load_model(checkpoint)
    with torch.inference_mode():
        return DeployWrapper(model).eval()(torch.from_numpy(frames)).numpy()


def test_fp32_round_trip_matches_pytorch(litert_export, checkpoint, tmp_path) -> None:
    out, report = litert_export
    # Frames the export never saw, at another size: the segmenter resizes them as the robot does.
    frames = load_frames(write_frames(tmp_path / "fresh", count=3, height=50, width=120, seed=7), (SIZE, SIZE))
    segmenter = LiteRtSegmenter(out, threads=1)
    assert isinstance(segmenter, Segmenter)
    probs = np.stack([segmenter.probabilities(frame)[None] for frame in frames])
    torch_probs = _torch_probs(checkpoint, frames)
    agreement = compare(probs, torch_probs, threshold=0.5)
    assert agreement.max_abs_diff <= MAX_ABS_DIFF
    assert agreement.mask_agreement >= MIN_MASK_AGREEMENT
    assert probs.std() > 0.01 and 0.02 < (probs >= 0.5).mean() < 0.98  # an output that depends on the image
    assert np.array_equal(segmenter.segment(frames[0]), torch_probs[0, 0] >= 0.5)
    assert report["fp32"]["verification_vs_torch"]["max_abs_diff"] <= MAX_ABS_DIFF


def test_metadata_is_the_onnx_exports_with_the_litert_format(litert_export, checkpoint) -> None:
    out, report = litert_export
    meta = litert_file.read_metadata(out)
    assert meta[md.KEY_FORMAT] == md.FORMAT_LITERT
    assert md.parse_input_size(meta[md.KEY_INPUT_SIZE]) == (SIZE, SIZE)
    assert (meta[md.KEY_INPUT_LAYOUT], meta[md.KEY_INPUT_DTYPE], meta[md.KEY_CHANNEL_ORDER]) == ("NHWC", "uint8", "RGB")
    assert float(meta[md.KEY_THRESHOLD]) == 0.5
    assert "ImageNet" in meta[md.KEY_NORMALISATION] and meta[md.KEY_PRECISION] == "fp32"
    assert meta[md.KEY_EXPORTER].startswith("litert-torch 0.10") and md.KEY_OPSET not in meta
    assert meta[md.KEY_CHECKPOINT].startswith(f"{checkpoint.name} sha256:")
    assert meta["verification"].startswith("6 frames, ")
    assert {k: v for k, v in meta.items() if k != "verification"} == report["metadata"]
    assert LiteRtSegmenter(out).metadata == meta


def test_int8_file_is_full_integer_loadable_and_reported(litert_export) -> None:
    out, report = litert_export
    int8 = variant_path(out, "int8")
    assert int8.stat().st_size < out.stat().st_size / 2
    assert litert_file.read_metadata(int8)[md.KEY_PRECISION] == "int8"
    segmenter = LiteRtSegmenter(int8, threads=1)
    assert segmenter._runner.output["dtype"] == np.int8  # full integer: the output tensor is int8 too
    rgb = np.random.default_rng(3).integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    probs = segmenter.probabilities(rgb)
    assert probs.dtype == np.float32 and probs.min() >= 0.0 and probs.max() <= 1.0
    assert np.abs(probs - LiteRtSegmenter(out).probabilities(rgb)).max() < 0.1
    entry = report["int8"]
    assert entry["path"] == str(int8) and entry["calibration_frames"] == 6
    assert entry["vs_fp32"]["mask_iou"] > 0.9
    assert entry["recommendation"].startswith("calibrated on 6 frames, INT8 median ")


def test_a_tflite_without_segmin_metadata_is_one_line_naming_it(litert_export, tmp_path, capsys) -> None:
    from ai_edge_litert.tools import flatbuffer_utils

    out, _ = litert_export
    model = flatbuffer_utils.read_model_from_bytearray(bytearray(out.read_bytes()))
    model.metadata = [m for m in model.metadata if m.name not in (b"segmin", "segmin")]
    bare = tmp_path / "bare.tflite"
    bare.write_bytes(bytes(flatbuffer_utils.convert_object_to_bytearray(model)))
    with pytest.raises(ValueError, match=r"bare.tflite: not a segmin LiteRT model \(metadata lacks segmin_format, "):
        LiteRtSegmenter(bare)
    not_tflite = tmp_path / "junk.tflite"
    not_tflite.write_bytes(b"not a flatbuffer at all")
    frames = write_frames(tmp_path / "frames", count=2)
    for path, problem in ((bare, "metadata lacks segmin_format"), (not_tflite, "no TFL3 flatbuffer identifier")):
        rgb = ["--rgb", str(frames), "--fps", "10", "--method", "segmin", "--depth-threshold", "5"]
        args = ["replay", "--model", str(path), *rgb, "--out", str(tmp_path / "out")]
        assert segmin_main(args) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err and problem in err, err
    # An ONNX file's metadata is not a LiteRT file's: the format check names both.
    meta = {**litert_file.read_metadata(out), md.KEY_FORMAT: md.FORMAT}
    relabelled = tmp_path / "relabelled.tflite"
    relabelled.write_bytes(litert_file.with_metadata(out.read_bytes(), meta))
    with pytest.raises(ValueError, match="relabelled.tflite: unsupported model format 'segmin-onnx-v1'"):
        LiteRtSegmenter(relabelled)


def test_too_few_calibration_frames_for_int8_are_refused_before_writing(checkpoint, tmp_path, capsys) -> None:
    one = write_frames(tmp_path / "one", count=1)
    out = tmp_path / "out" / "model.tflite"
    args = ["export", "--format", "tflite", "--checkpoint", str(checkpoint), "--out", str(out), "--int8"]
    assert segmin_main([*args, "--calib-data", str(one)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("segmin: error: --calib-frames 32: only 1 frame(s) found in ")
    assert not out.parent.exists() or not any(out.parent.iterdir())


def test_onnx_only_options_and_wrong_suffixes_are_refused(checkpoint, tmp_path) -> None:
    base = {"checkpoint": checkpoint, "format": "tflite"}
    with pytest.raises(ValueError, match=r"--out .*model.onnx: the output file name must end in .tflite"):
        ExportOptions(out=tmp_path / "model.onnx", **base)
    with pytest.raises(ValueError, match="--exporter, --opset, --fp16: ONNX options, not used with --format tflite"):
        ExportOptions(out=tmp_path / "m.tflite", exporter="legacy", opset=17, fp16=True, **base)
    with pytest.raises(ValueError, match="format='coreml'"):
        ExportOptions(checkpoint=checkpoint, out=tmp_path / "m.tflite", format="coreml")
    assert ExportOptions(checkpoint=checkpoint, out=tmp_path / "m.onnx").exporter == "dynamo"


def test_shipped_name_resolves_to_a_tflite_in_the_models_folder(litert_export, tmp_path, monkeypatch) -> None:
    out, _ = litert_export
    monkeypatch.setenv(ENV_MODELS_DIR, str(tmp_path))
    with pytest.raises(
        ValueError,
        match=r"model vineyards: a shipped model name, but this install has no "
        r"vineyards.tflite yet .*segmin export --checkpoint vineyards --format tflite",
    ):
        LiteRtSegmenter("vineyards")
    shutil.copy(out, tmp_path / "vineyards.tflite")
    assert LiteRtSegmenter("vineyards").path == tmp_path / "vineyards.tflite"
    assert isinstance(load_segmenter(tmp_path / "vineyards.tflite"), LiteRtSegmenter)


def test_a_shipped_onnx_model_exports_to_litert(tmp_path, frames_dir, monkeypatch, capsys) -> None:
    """The shipped models exist only as ONNX: `segmin export --checkpoint NAME` converts the network back
    to PyTorch (BatchNorm measured on --frames) and exports that; the card travels along."""
    monkeypatch.delenv(ENV_MODELS_DIR, raising=False)
    source = OnnxSegmenter("vineyards")
    out = tmp_path / "vineyards.tflite"
    with pytest.raises(ValueError, match="--checkpoint .*vineyards.onnx: an ONNX model; pass --calib-data DIR"):
        export_checkpoint(ExportOptions(checkpoint=Path(source.path), out=out, format="tflite"))
    args = ["export", "--checkpoint", "vineyards", "--format", "tflite", "--calib-data", str(frames_dir)]
    assert segmin_main([*args, "--out", str(out)]) == 0
    assert capsys.readouterr().out.startswith(f"{out}: verified on 6 frames")
    meta = litert_file.read_metadata(out)
    assert meta[md.KEY_INPUT_SIZE] == source.metadata[md.KEY_INPUT_SIZE]
    assert meta[md.KEY_MODEL_CARD] == source.metadata[md.KEY_MODEL_CARD]
    assert meta[md.KEY_CHECKPOINT].startswith("vineyards.onnx sha256:")
    rgb = load_frames(frames_dir, (96, 72), limit=1)[0]
    assert np.abs(LiteRtSegmenter(out).probabilities(rgb) - source.probabilities(rgb)).max() < 1e-3


def test_pipeline_export_formats_are_checked_and_keep_the_onnx_hash() -> None:
    plain = load_pipeline_config("micro")
    both = load_pipeline_config("micro", ["export.formats=[onnx, tflite]"])
    assert both.export.formats == ["onnx", "tflite"]
    assert plain.export.onnx_settings() == both.export.onnx_settings()  # adding tflite re-exports no ONNX
    assert plain.export.onnx_settings() != load_pipeline_config("micro", ["export.int8=true"]).export.onnx_settings()
    with pytest.raises(ConfigError, match=r"export.formats\[1\]: 'coreml' is not one of \['onnx', 'tflite'\]"):
        load_pipeline_config("micro", ["export.formats=[onnx, coreml]"])
    with pytest.raises(ValueError, match=r"export.formats \['tflite'\]: must include onnx"):
        load_pipeline_config("micro", ["export.formats=[tflite]"])


def test_int8_keeps_hard_swish_float_so_xnnpack_runs_the_whole_graph(litert_export, capsys) -> None:
    """XNNPACK has no int8 hard-swish: quantised, each one ran outside XNNPACK between 16
    partitions and the INT8 file was slower than fp32. The bench names what XNNPACK leaves out."""
    from benchmarks.litert import op_census

    out, _ = litert_export
    int8 = variant_path(out, "int8")
    census = op_census(int8)
    assert census["HARD_SWISH float32"] == op_census(out)["HARD_SWISH float32"] > 0
    assert census["HARD_SWISH int8"] == 0 and census["CONV_2D int8"] > 0 and census["DEPTHWISE_CONV_2D int8"] > 0
    from benchmarks.cli import main as benchmarks_main

    args = ["litert", "--models", str(out), str(int8), "--threads", "1", "--rounds", "1", "--runs", "2"]
    assert benchmarks_main(args) == 0
    printed = capsys.readouterr().out
    for path in (out, int8):  # only the uint8 -> float input cast is LiteRT's
        assert (
            f"{path}: " in printed
            and f"{path.stat().st_size / 1e6:.1f} MB, XNNPACK partitions 1, ops left out: CAST x1\n" in printed
        )
    assert "1 thread(s), 1 alternating rounds; before: load " in printed and f"1.00x  {out}" in printed


def test_the_bench_finds_ops_left_out_of_xnnpack(litert_export, frames_dir, tmp_path) -> None:
    """The partition count and the ops left out, on a file quantised with hard-swish int8 too."""
    from benchmarks.litert import op_census, xnnpack_partitions
    from segmin.export.litert import quantize_int8

    out, _ = litert_export
    all_int8 = tmp_path / "all_int8.tflite"
    quantize_int8(out, all_int8, load_frames(frames_dir, (SIZE, SIZE), limit=2), float_ops=())
    partitions, left = xnnpack_partitions(litert_file.make_interpreter(all_int8, threads=1))
    hard_swish = op_census(all_int8)["HARD_SWISH int8"]
    assert hard_swish == op_census(out)["HARD_SWISH float32"] > 0  # the full network has 20
    assert left == {"HARD_SWISH": hard_swish, "CAST": 1} and partitions > hard_swish // 2


def test_the_pipelines_litert_stage_exports_from_the_checkpoints_training_frames(
    checkpoint, frames_dir, tmp_path
) -> None:
    """`export.formats: [onnx, tflite]`: the stage writes a verified LiteRT file from the frames the
    checkpoint was trained on, as the ONNX export does (INT8 off here: the export tests cover it)."""
    from segmin.app.pipeline.stages import litert_stage
    from segmin.models.checkpoint import read_checkpoint, save_checkpoint

    payload = read_checkpoint(checkpoint)
    payload["model_info"]["train_data"] = f"{write_frames(tmp_path / 'train_frames', count=4)} domains=all"
    trained = tmp_path / "best.pt"
    save_checkpoint(trained, {k: v for k, v in payload.items() if k != "format"})
    config = load_pipeline_config("micro", ["export.formats=[onnx, tflite]"])
    logged: list[str] = []
    outputs = litert_stage(config, trained, tmp_path / "litert" / "vineyards.tflite", logged.append)
    assert outputs["litert"] == str(tmp_path / "litert" / "vineyards.tflite")
    assert "litert_int8" not in outputs
    assert outputs["verification"]["frames"] == 4 and outputs["verification"]["max_abs_diff"] <= MAX_ABS_DIFF
    assert LiteRtSegmenter(outputs["litert"]).metadata[md.KEY_TRAIN_DATA].startswith(str(tmp_path / "train_frames"))
    assert logged == [f"export: {trained} -> {tmp_path / 'litert' / 'vineyards.tflite'}"]


def test_a_failed_verification_writes_no_file(litert_export, checkpoint, frames_dir, tmp_path, monkeypatch) -> None:
    """The file is converted, stamped and verified in a temporary file; one that misses the bounds
    (here: a bound of 0) is never renamed to --out. The conversion is the fixture's file, copied."""
    from segmin.export import litert

    out, _ = litert_export
    monkeypatch.setattr(litert, "convert_graph", lambda model, path, size: shutil.copy(out, path))
    target = tmp_path / "model.tflite"
    options = ExportOptions(checkpoint=checkpoint, out=target, calib_data=frames_dir, format="tflite", max_abs_diff=0.0)
    with pytest.raises(
        ValueError, match=r"model.tflite: export failed verification, no file written: .*max \|p_tflite"
    ):
        export_checkpoint(options)
    assert list(tmp_path.iterdir()) == []


def test_eval_seg_scores_a_litert_file_as_its_checkpoint(litert_export, checkpoint, tmp_path) -> None:
    from test_seg_eval import write_set

    out, _ = litert_export
    data = write_set(tmp_path / "toy", count=3, size=(72, 96), toy=True)
    results = {}
    for name, model in (("litert", out), ("checkpoint", checkpoint)):
        args = ["eval-seg", "--model", str(model), "--data", str(data), "--out", str(tmp_path / name)]
        assert segmin_main([*args, "--no-progress"]) == 0
        results[name] = json.loads((tmp_path / name / "results.json").read_text())
    assert results["litert"]["kind"] == "litert" and results["litert"]["input_size"] == [SIZE, SIZE]
    assert abs(results["litert"]["summary"]["mean_iou"] - results["checkpoint"]["summary"]["mean_iou"]) < 0.01


@pytest.mark.parametrize("name", ["vineyards", "trees"])
def test_a_shipped_name_runs_its_int8_litert_file_where_litert_is_installed(name, monkeypatch, caplog) -> None:
    """The fastest measured configuration is the runtime's default for a shipped name; without
    LiteRT the ONNX file runs, and one log line says how to get the fast one."""
    from segmin.nav_eval.runtime import segmenter as runtime

    monkeypatch.delenv(ENV_MODELS_DIR, raising=False)
    fast = runtime.runtime_model_file(name)
    assert fast.name == f"{name}.int8.tflite" and isinstance(load_segmenter(name), LiteRtSegmenter)
    monkeypatch.setattr(runtime, "litert_installed", lambda: False)
    with caplog.at_level("INFO", logger=runtime.__name__):
        slow = load_segmenter(name)
    assert isinstance(slow, OnnxSegmenter) and slow.path.name == f"{name}.onnx"
    assert "pip install segmin[litert] runs the faster INT8 LiteRT file" in caplog.text
    assert load_segmenter(str(slow.path)).path == slow.path  # a file is run as given


@pytest.mark.parametrize("name", ["vineyards", "trees"])
def test_the_shipped_int8_file_carries_the_onnx_metadata_and_its_masks(name, frames_dir, monkeypatch) -> None:
    monkeypatch.delenv(ENV_MODELS_DIR, raising=False)
    onnx, int8 = OnnxSegmenter(name), LiteRtSegmenter(runtime_model_file(name))
    for key in (md.KEY_INPUT_SIZE, md.KEY_THRESHOLD, md.KEY_MODEL_CARD):
        assert int8.metadata[key] == onnx.metadata[key], key
    frames = load_frames(frames_dir, (160, 120), limit=4)
    a = np.stack([onnx.segment(f) for f in frames])
    b = np.stack([int8.segment(f) for f in frames])
    assert np.mean(a == b) >= 0.97  # INT8 against fp32 on frames it was not calibrated on
