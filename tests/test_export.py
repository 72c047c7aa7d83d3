"""Export round trip on a tiny trained checkpoint: verified graph, metadata, variants, errors."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from export_helpers import SIZE, field_image, write_frames

from benchmarks.cli import main as benchmarks_main
from segmin.app.cli import main as segmin_main
from segmin.export import metadata as md
from segmin.export.onnx import DeployWrapper, read_metadata
from segmin.export.pipeline import ExportOptions, OutputExistsError, export_checkpoint, report_path, variant_path
from segmin.export.verify import (
    MAX_ABS_DIFF,
    MIN_MASK_AGREEMENT,
    VerificationError,
    compare,
    load_frames,
    make_session,
    run_session,
)
from segmin.models.checkpoint import load_model


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("export")


def _torch_probs(checkpoint: Path, frames: np.ndarray) -> np.ndarray:
    model, _ = load_model(checkpoint)
    with torch.inference_mode():
        return DeployWrapper(model).eval()(torch.from_numpy(frames)).numpy()


def test_round_trip_matches_pytorch_within_bounds(exported, checkpoint, workdir) -> None:
    out, report = exported
    assert out.is_file()
    # Fresh frames the export never saw, different size from the model: resized like the robot does.
    frames = load_frames(write_frames(workdir / "fresh", count=4, height=50, width=120, seed=7), (SIZE, SIZE))
    onnx_probs = run_session(make_session(out), frames)
    torch_probs = _torch_probs(checkpoint, frames)
    agreement = compare(onnx_probs, torch_probs, threshold=0.5)
    assert agreement.max_abs_diff <= MAX_ABS_DIFF
    assert agreement.mask_agreement >= MIN_MASK_AGREEMENT
    # The tiny model's output must depend on the image, or the comparison above proves little.
    assert onnx_probs.std() > 0.01
    assert 0.02 < (onnx_probs >= 0.5).mean() < 0.98
    verification = report["fp32"]["verification_vs_torch"]
    assert verification["frames"] == 6
    assert verification["max_abs_diff"] <= MAX_ABS_DIFF


def test_graph_takes_uint8_nhwc_with_dynamic_batch(exported) -> None:
    out, _ = exported
    session = make_session(out)
    (graph_input,) = session.get_inputs()
    assert graph_input.name == md.INPUT_NAME and graph_input.type == "tensor(uint8)"
    assert graph_input.shape[1:] == [SIZE, SIZE, 3] and isinstance(graph_input.shape[0], str)
    rng = np.random.default_rng(3)
    batch = rng.integers(0, 256, (5, SIZE, SIZE, 3), dtype=np.uint8)
    (probs,) = session.run(None, {graph_input.name: batch})
    assert probs.shape == (5, 1, SIZE, SIZE) and probs.dtype == np.float32
    assert np.all((probs >= 0) & (probs <= 1))
    (single,) = session.run(None, {graph_input.name: batch[2:3]})
    np.testing.assert_allclose(single[0], probs[2], atol=1e-5)
    # The pooling is exported as GlobalAveragePool, not a batch-dependent Gather over indices.
    ops = {node.op_type for node in onnx.load(str(out)).graph.node}
    assert "GlobalAveragePool" in ops and not ops & {"Gather", "Range", "ReduceMean"}


def test_metadata_present(exported) -> None:
    out, _ = exported
    meta = read_metadata(out)
    md.check_metadata(meta, str(out))
    assert meta[md.KEY_INPUT_SIZE] == f"{SIZE},{SIZE}"
    assert meta[md.KEY_CHANNEL_ORDER] == "RGB" and meta[md.KEY_INPUT_LAYOUT] == "NHWC"
    assert float(meta[md.KEY_THRESHOLD]) == 0.5
    assert meta[md.KEY_FAMILY] == "vineyards"
    assert meta[md.KEY_TRAIN_DATA] == "toy"
    assert meta[md.KEY_BACKBONE] == "none"
    import segmin

    assert meta[md.KEY_VERSION] == segmin.__version__
    commit = meta[md.KEY_GIT_COMMIT]
    assert commit == "unknown" or (len(commit) == 40 and all(c in "0123456789abcdef" for c in commit))
    assert meta[md.KEY_PRECISION] == "fp32" and meta[md.KEY_OPSET] == "18"
    assert "sha256:" in meta[md.KEY_CHECKPOINT]
    assert "verification" in meta
    onnx.checker.check_model(str(out), full_check=True)
    # No exporter stack traces (the building machine's paths) ride along in the nodes.
    assert not [node.name for node in onnx.load(str(out)).graph.node if node.metadata_props]


def test_fp16_and_int8_variants_run_and_are_reported(exported, frames_dir) -> None:
    out, report = exported
    fp16, int8 = variant_path(out, "fp16"), variant_path(out, "int8")
    frame = load_frames(frames_dir, (SIZE, SIZE), limit=2)
    fp32_probs = run_session(make_session(out), frame)
    for path, precision in ((fp16, "fp16"), (int8, "int8")):
        assert path.is_file()
        assert read_metadata(path)[md.KEY_PRECISION] == precision
        session = make_session(path)
        assert session.get_inputs()[0].type == "tensor(uint8)"
        assert session.get_outputs()[0].type == "tensor(float)"
        probs = run_session(session, frame)
        assert probs.shape == fp32_probs.shape
        assert np.abs(probs - fp32_probs).max() < 0.1
    fp16_graph = onnx.load(str(fp16))
    assert any(init.data_type == onnx.TensorProto.FLOAT16 for init in fp16_graph.graph.initializer)
    int8_graph = onnx.load(str(int8))
    assert any(node.op_type == "QuantizeLinear" for node in int8_graph.graph.node)
    assert report["fp16"]["vs_fp32"]["max_abs_diff"] < 1e-2
    assert 0.0 <= report["int8"]["vs_fp32"]["mask_iou"] <= 1.0
    assert report["int8"]["latency_ms"]["int8"]["median_ms"] > 0
    assert isinstance(report["int8"]["recommended"], bool)
    assert report["int8"]["calibration_frames"] == 6  # all of frames_dir, as asked
    assert report["int8"]["recommendation"].startswith("calibrated on 6 frames, ")
    on_disk = json.loads(report_path(out).read_text())
    assert on_disk["int8"]["recommendation"] == report["int8"]["recommendation"]


def test_int8_with_fewer_calibration_frames_than_asked_is_refused(workdir, checkpoint, frames_dir, capsys) -> None:
    """One photo for 32 calibration frames used to calibrate on that one and still print
    "recommended": the ranges of one frame miss what the others hold. Refused before any file
    is written; --calib-frames N accepts the N frames there are."""
    one = write_frames(workdir / "one_frame", count=1)
    out = workdir / "calib" / "model.onnx"
    args = ["export", "--checkpoint", str(checkpoint), "--out", str(out), "--calib-data", str(one), "--int8"]
    assert segmin_main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("segmin: error: --calib-frames 32: only 1 frame(s) found in ") and str(one) in err
    assert "--calib-frames 1" in err
    assert not out.parent.exists() or not any(out.parent.iterdir())
    with pytest.raises(ValueError, match="--calib-frames 7: only 6 frame"):
        export_checkpoint(
            ExportOptions(checkpoint=checkpoint, out=out, calib_data=frames_dir, int8=True, calib_frames=7)
        )
    # Without --int8 the calibration count is not asked for: one frame verifies the export.
    report = export_checkpoint(ExportOptions(checkpoint=checkpoint, out=out, calib_data=one, exporter="legacy"))
    assert report["fp32"]["verification_vs_torch"]["frames"] == 1 and "int8" not in report


def test_a_cut_architecture_exports_verifies_and_records_its_name(workdir, frames_dir) -> None:
    from export_helpers import make_checkpoint

    from segmin.export.onnx import read_metadata

    cut = make_checkpoint(workdir / "cut13.pt", architecture="lraspp_mobilenet_v3_large_cut13")
    out = workdir / "cut13.onnx"
    report = export_checkpoint(ExportOptions(checkpoint=cut, out=out, calib_data=frames_dir))
    assert report["fp32"]["verification_vs_torch"]["frames"] == 6
    assert read_metadata(out)["architecture"] == "lraspp_mobilenet_v3_large_cut13"


def test_refuses_overwrite_without_force(exported, checkpoint, frames_dir) -> None:
    out, _ = exported
    before = out.read_bytes()
    with pytest.raises(OutputExistsError, match="--force"):
        export_checkpoint(ExportOptions(checkpoint=checkpoint, out=out, calib_data=frames_dir))
    assert out.read_bytes() == before
    # Through the CLI: exit code 2 and a one-line message, file untouched.
    code = segmin_main(["export", "--checkpoint", str(checkpoint), "--out", str(out), "--calib-data", str(frames_dir)])
    assert code == 2 and out.read_bytes() == before


def test_force_overwrites_with_legacy_exporter(workdir, checkpoint, frames_dir, capsys, caplog) -> None:
    """Also: `segmin export` shows its progress lines (the segmin.export loggers at INFO)."""
    out = workdir / "legacy.onnx"
    out.write_bytes(b"old")
    variant_path(out, "int8").write_bytes(b"old int8 built from the old file")
    code = segmin_main(
        [
            "export",
            "--checkpoint",
            str(checkpoint),
            "--out",
            str(out),
            "--calib-data",
            str(frames_dir),
            "--exporter",
            "legacy",
            "--force",
            "--verify-frames",
            "3",
        ]
    )
    assert code == 0
    assert "verified on 3 frames" in capsys.readouterr().out
    meta = read_metadata(out)
    assert meta[md.KEY_EXPORTER] == "legacy" and meta[md.KEY_OPSET] == "17"
    assert not variant_path(out, "int8").exists()  # stale variant of the replaced file removed
    assert not [p for p in workdir.iterdir() if p.name.endswith(".tmp")]
    progress = [r.getMessage() for r in caplog.records if r.name == "segmin.export.pipeline"]
    assert progress[0].startswith(f"wrote {out} (verified: 3 frames")
    assert progress[1] == f"removed {variant_path(out, 'int8')} (a variant of the previous legacy.onnx)"


def test_failed_verification_leaves_no_file(workdir, checkpoint, frames_dir, monkeypatch) -> None:
    from segmin.export import pipeline

    def shifted_reference(wrapper):
        def probabilities(frames):
            return _torch_probs(checkpoint, frames) + 1e-3  # a PyTorch/ONNX mismatch of 1e-3

        return probabilities

    monkeypatch.setattr(pipeline, "torch_reference", shifted_reference)
    out = workdir / "bad.onnx"
    with pytest.raises(VerificationError, match="max \\|p_onnx - p_torch\\|"):
        export_checkpoint(ExportOptions(checkpoint=checkpoint, out=out, calib_data=frames_dir, exporter="legacy"))
    assert not out.exists()
    assert not report_path(out).exists()
    assert not [p for p in workdir.iterdir() if p.name.startswith(".bad.onnx")]


def test_corrupt_checkpoint_gives_clear_error(workdir, frames_dir, capsys) -> None:
    bad = workdir / "corrupt.pt"
    bad.write_bytes(os.urandom(256))
    out = workdir / "never.onnx"
    with pytest.raises(ValueError, match="corrupt.pt"):
        export_checkpoint(ExportOptions(checkpoint=bad, out=out, calib_data=frames_dir))
    code = segmin_main(["export", "--checkpoint", str(bad), "--out", str(out), "--calib-data", str(frames_dir)])
    assert code == 2
    assert "corrupt.pt" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        export_checkpoint(ExportOptions(checkpoint=workdir / "missing.pt", out=out, calib_data=frames_dir))


def test_bad_options_and_frame_sources(workdir, checkpoint, frames_dir) -> None:
    out = workdir / "never.onnx"
    with pytest.raises(FileNotFoundError, match="no_such_dir"):
        export_checkpoint(ExportOptions(checkpoint=checkpoint, out=out, calib_data=workdir / "no_such_dir"))
    empty = workdir / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no images"):
        export_checkpoint(ExportOptions(checkpoint=checkpoint, out=out, calib_data=empty))
    # Without --calib-data the checkpoint's training data ("toy") must be a folder: it is not.
    with pytest.raises(ValueError, match="--calib-data"):
        export_checkpoint(ExportOptions(checkpoint=checkpoint, out=out))
    with pytest.raises(ValueError, match="opset"):
        export_checkpoint(ExportOptions(checkpoint=checkpoint, out=out, calib_data=frames_dir, opset=16))
    with pytest.raises(ValueError, match=".onnx"):
        ExportOptions(checkpoint=checkpoint, out=workdir / "model.bin")
    with pytest.raises(ValueError, match="exporter"):
        ExportOptions(checkpoint=checkpoint, out=out, exporter="tflite")
    assert not out.exists()


def test_mask_iou_and_agreement_are_exact_and_threshold_inclusive() -> None:
    reference = np.zeros((1, 1, 2, 4), np.float32)
    reference[0, 0, 0] = 0.9  # the reference's crop: the 4 pixels of row 0
    probs = reference.copy()
    probs[0, 0, 0, 0] = 0.1  # one reference crop pixel missed (FN)
    probs[0, 0, 1, 0] = 0.5  # exactly at the threshold: crop (>=, as the robot's segmenter decides), a FP
    agreement = compare(probs, reference, 0.5)
    assert agreement.mask_iou == 0.6  # TP 3 / (TP 3 + FP 1 + FN 1)
    assert agreement.mask_agreement == 0.75  # (TP 3 + TN 3) / 8 pixels
    nothing = np.zeros_like(reference)
    empty = compare(nothing, nothing, 0.5)
    assert (empty.mask_iou, empty.mask_agreement) == (1.0, 1.0)  # both masks empty: perfect agreement


def test_verification_bounds_reject_disagreement() -> None:
    rng = np.random.default_rng(0)
    reference = rng.random((2, 1, 8, 8)).astype(np.float32)
    good = compare(reference + 5e-5, reference, 0.5)
    assert good.max_abs_diff <= MAX_ABS_DIFF
    flipped = reference.copy()
    flipped[0, 0, 0, :4] = 1.0 - flipped[0, 0, 0, :4]
    bad = compare(flipped, reference, 0.5)
    assert bad.max_abs_diff > MAX_ABS_DIFF and bad.mask_agreement < 1.0
    with pytest.raises(VerificationError, match="shape"):
        compare(reference[:1], reference, 0.5)
    with pytest.raises(VerificationError, match="NaN"):
        compare(np.full_like(reference, np.nan), reference, 0.5)


def _agriseg_root(root: Path) -> Path:
    """Two domains in the formatted AgriSeg layout; masks are white so they cannot pass as frames."""
    import cv2

    rng = np.random.default_rng(11)
    for domain, count in (("synth_a", 3), ("synth_b", 2)):
        subset = root / domain / f"{domain}_0"
        for n in range(1, count + 1):
            image, _mask = field_image(rng, 40, 40)
            (subset / "images" / f"Image{n}").mkdir(parents=True)
            (subset / "masks" / f"Image{n}").mkdir(parents=True)
            cv2.imwrite(str(subset / "images" / f"Image{n}" / f"Image{n}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            cv2.imwrite(str(subset / "masks" / f"Image{n}" / f"Segmentation{n}.png"), np.full((40, 40), 255, np.uint8))
    return root


def test_frames_from_agriseg_root_and_training_data(tmp_path) -> None:
    from segmin.export.pipeline import _frame_source, parse_train_data

    root = _agriseg_root(tmp_path / "agriseg")
    frames = load_frames(root, (SIZE, SIZE))
    assert frames.shape == (5, SIZE, SIZE, 3) and frames.dtype == np.uint8
    assert not np.any(np.all(frames == 255, axis=(1, 2, 3)))  # no mask was read as a frame
    assert load_frames(root, (SIZE, SIZE), domains=["synth_b"]).shape[0] == 2
    assert load_frames(root, (SIZE, SIZE), limit=2).shape[0] == 2
    # What train/ records in model_info["train_data"] leads back to the same frames.
    assert parse_train_data(f"{root} domains=['synth_b']; val {root} domains=['synth_a']") == (root, ["synth_b"])
    assert parse_train_data(f"{root} domains=all") == (root, None)
    assert parse_train_data(str(root)) == (root, None)
    options = ExportOptions(checkpoint=tmp_path / "x.pt", out=tmp_path / "m.onnx")
    assert _frame_source(options, {"train_data": f"{root} domains=['synth_a']"}) == (root, ["synth_a"])


def test_bench_smoke_on_the_exported_file(exported, checkpoint, tmp_path, capsys) -> None:
    """`python -m benchmarks export` code path at 64 px with a handful of runs (figures are not checked).

    One thread: on a shared machine, PyTorch's 2-thread OpenMP barriers can take a second a call.
    """
    out, _ = exported
    code = benchmarks_main(
        [
            "export",
            "--onnx",
            str(out),
            "--checkpoint",
            str(checkpoint),
            "--size",
            str(SIZE),
            "--runs",
            "8",
            "--threads",
            "1",
            "--no-int8",
            "--json",
            str(tmp_path / "bench.json"),
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    from benchmarks.perception_step import STEP_NAME

    assert "pytorch eager" in printed and STEP_NAME in printed
    summary = json.loads((tmp_path / "bench.json").read_text())
    for entry in summary["results"].values():
        assert entry["runs"] == 8 and 0 < entry["min_ms"] <= entry["median_ms"] <= entry["p95_ms"]
    roofline = summary["roofline"]
    assert roofline["conv_gflop"] > 0 and roofline["peak_gflops"] > 0
    assert roofline["floor_ms"] == pytest.approx(roofline["conv_gflop"] / roofline["peak_gflops"] * 1e3)
    assert "GFLOP of convolutions per frame" in printed
    from benchmarks.export import ExportBenchOptions, run_benchmark

    with pytest.raises(ValueError, match="pass --size"):
        run_benchmark(ExportBenchOptions(onnx=out, checkpoint=checkpoint, size=SIZE * 2, runs=2, int8=False))
    assert summary["targets"] == {
        "ort fp32 median <= 6 ms": summary["results"]["onnxruntime fp32"]["median_ms"] <= 6,
        "ort fp32 <= 0.35x eager": summary["results"]["onnxruntime fp32"]["ratio_to_eager"] <= 0.35,
        "full step median <= 7 ms": summary["results"][STEP_NAME]["median_ms"] <= 7,
    }
    for label, met in summary["targets"].items():
        assert f"target {label}: {'met' if met else 'NOT met'}" in printed


def test_conv_flops_counts_grouped_and_strided_convolutions(tmp_path) -> None:
    """Two hand-made convs: 3->8 3x3 stride 2 on 16x16, then depthwise 3x3 on the 8x8 result."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from segmin.export.roofline import conv_flops, floor_summary

    w1 = numpy_helper.from_array(np.zeros((8, 3, 3, 3), np.float32), "w1")
    w2 = numpy_helper.from_array(np.zeros((8, 1, 3, 3), np.float32), "w2")
    graph = helper.make_graph(
        [
            helper.make_node("Conv", ["x", "w1"], ["y"], strides=[2, 2], pads=[1, 1, 1, 1]),
            helper.make_node("Conv", ["y", "w2"], ["z"], group=8, pads=[1, 1, 1, 1]),
        ],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["batch", 3, 16, 16])],
        [helper.make_tensor_value_info("z", TensorProto.FLOAT, None)],
        [w1, w2],
    )
    path = tmp_path / "two_convs.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)]), str(path))
    per_frame = 2 * 8 * 3 * 9 * 8 * 8 + 2 * 8 * 1 * 9 * 8 * 8
    assert conv_flops(path) == per_frame
    assert conv_flops(path, batch=3) == 3 * per_frame
    summary = floor_summary(flops=2_000_000_000, ort_ms=20.0, eager_ms=40.0, peak_gflops=200.0)
    assert summary["floor_ms"] == pytest.approx(10.0) and summary["floor_ratio_to_eager"] == pytest.approx(0.25)
    assert summary["achieved_gflops"] == pytest.approx(100.0) and summary["fraction_of_peak"] == pytest.approx(0.5)


@pytest.mark.parametrize(
    "model_info, field",
    [
        ([1, 2, 3], "model_info is a list"),
        ({"architecture": "lraspp_mobilenet_v3_large", "input_size": "64"}, "input_size"),
        ({"input_size": [64, 64], "threshold": "abc"}, "threshold"),
    ],
)
def test_a_malformed_model_info_is_refused_naming_the_file(
    workdir, checkpoint, frames_dir, capsys, model_info, field
) -> None:
    """`model_info` a list crashed export with a traceback."""
    import torch

    from segmin.models.lraspp import ARCHITECTURE

    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    if isinstance(model_info, dict):
        model_info = {**payload["model_info"], **model_info, "architecture": ARCHITECTURE}
    payload["model_info"] = model_info
    bad = workdir / "bad_info.pt"
    torch.save(payload, bad)
    out = workdir / "bad_info.onnx"
    code = segmin_main(["export", "--checkpoint", str(bad), "--out", str(out), "--calib-data", str(frames_dir)])
    err = capsys.readouterr().err
    assert code == 2 and "bad_info.pt" in err and field in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
