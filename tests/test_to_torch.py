"""`segmin models to-torch`: an exported model back in the PyTorch network, ready to train from."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from benchmarks.train import write_bench_dataset
from segmin.app.cli import main as segmin_main
from segmin.export.onnx import DeployWrapper
from segmin.export.pipeline import variant_path
from segmin.export.to_torch import network_from_onnx
from segmin.export.verify import make_session, run_session
from segmin.models.lraspp import build_model


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Eight 320 x 240 formatted-layout frames of green blobs on soil (calibration input)."""
    return write_bench_dataset(tmp_path_factory.mktemp("to_torch"), frames=8)


def test_the_written_state_dict_trains_from_what_the_onnx_model_computes(exported, dataset, tmp_path, capsys) -> None:
    onnx_path, _ = exported
    out = tmp_path / "init" / "model.pt"
    assert (
        segmin_main(["models", "to-torch", "--model", str(onnx_path), "--frames", str(dataset), "--out", str(out)]) == 0
    )
    assert f"backbone_weights={out}" in capsys.readouterr().out
    network = build_model(str(out)).eval()  # what training does with backbone_weights=FILE
    rng = np.random.default_rng(7)
    unseen = [rng.integers(0, 256, (100, 140, 3), dtype=np.uint8) for _ in range(3)]
    resized = np.stack([cv2.resize(image, (64, 64), interpolation=cv2.INTER_AREA) for image in unseen])
    with torch.no_grad():
        got = DeployWrapper(network)(torch.from_numpy(resized)).numpy()
    assert np.abs(got - run_session(make_session(onnx_path), resized)).max() < 1e-4
    # The BatchNorm statistics were measured, not left as the pass-through the folded weights need.
    norms = [m for m in network.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert norms and all(not torch.allclose(m.running_var, torch.ones_like(m.running_var), atol=1e-3) for m in norms)


def test_in_train_mode_the_calibration_batch_gives_the_eval_output(exported, dataset) -> None:
    """Batch statistics equal to the measured ones must leave the output as it was: gamma and beta
    undo the normalisation exactly, so fine-tuning starts from the shipped model, not a rescaled one."""
    network, frames = network_from_onnx(exported[0], dataset, 8, batch=8)
    assert len(frames) == 8
    wrapper = DeployWrapper(network)
    with torch.no_grad():
        evaluated = wrapper.eval()(torch.from_numpy(frames))
        trained = wrapper.train()(torch.from_numpy(frames))
    assert (evaluated - trained).abs().max() < 1e-3


def test_the_measured_statistics_are_those_of_the_shipped_computation(exported, dataset) -> None:
    """Each BatchNorm's running mean and variance are its input's over the frames, as the converted
    network (which computes the ONNX model's function) feeds it. While they are measured, the
    BatchNorms before it must pass their input through exactly (running_var 1 - eps: var + eps = 1);
    with running_var 1 the statistics measured were up to 5 % of a channel's spread off, which the
    outputs do not show (the measured gamma and beta undo whatever was measured)."""
    network, frames = network_from_onnx(exported[0], dataset, 8, batch=8)
    norms = {name: m for name, m in network.named_modules() if isinstance(m, torch.nn.BatchNorm2d)}
    inputs: dict[str, list[torch.Tensor]] = {name: [] for name in norms}
    handles = [
        m.register_forward_pre_hook(lambda _m, args, name=name: inputs[name].append(args[0].double()))
        for name, m in norms.items()
    ]
    try:
        with torch.no_grad():
            DeployWrapper(network.eval())(torch.from_numpy(frames))
    finally:
        for handle in handles:
            handle.remove()
    worst = 0.0
    for name, norm in norms.items():
        x = torch.cat(inputs[name]).transpose(0, 1).flatten(1)
        mean, var = x.mean(1), x.var(1, unbiased=False)
        spread = torch.sqrt(var + norm.eps)
        worst = max(
            worst,
            float(((norm.running_mean.double() - mean).abs() / spread).max()),
            float(((norm.running_var.double() - var).abs() / (var + norm.eps)).max()),
        )
    assert worst < 1e-4  # float32 rounding: 2e-6


def test_bad_models_and_outputs_are_one_line_and_nothing_is_replaced(exported, dataset, tmp_path, capsys) -> None:
    onnx_path, _ = exported
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"not a model")
    out = tmp_path / "model.pt"
    base = ["models", "to-torch", "--frames", str(dataset), "--out", str(out)]
    for model, problem in (
        (variant_path(onnx_path, "fp16"), "a fp16 model; convert the fp32 file"),
        (garbage, "not a readable ONNX model"),
        ("apples", "not a shipped model name"),
    ):
        assert segmin_main([*base, "--model", str(model)]) == 2
        err = capsys.readouterr().err.strip()
        assert problem in err and "\n" not in err
    assert segmin_main([*base, "--model", str(onnx_path), "--count", "0"]) == 2
    assert "--count 0" in capsys.readouterr().err
    out.write_bytes(b"keep")
    assert segmin_main([*base, "--model", str(onnx_path)]) == 2
    assert "use --force" in capsys.readouterr().err and out.read_bytes() == b"keep"
    assert segmin_main([*base, "--model", str(onnx_path), "--force"]) == 0
    assert out.read_bytes() != b"keep"
    # A folder as --out is named before the conversion, not by a temporary file after it.
    folder = tmp_path / "weights"
    folder.mkdir()
    assert segmin_main([*base[:-1], str(folder), "--model", str(onnx_path), "--force"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--out {folder} is a folder" in err and "\n" not in err and list(folder.iterdir()) == []
