"""A segmin ONNX model's weights back in the PyTorch network, so training can start from it.

Why: a shipped model exists only as ONNX (its training run is not shipped), and a team that wants
to fine-tune it on its own rows, or a next release candidate that continues from it, needs the
PyTorch network. The exporter folds every BatchNorm into the convolution before it
(`conv.weight * gamma / sqrt(var + eps)`, and a bias), so the BatchNorm's own parameters and
statistics are gone. They are put back in two steps: the folded weights go into the convolution
and the BatchNorm first passes its input through (plus the folded bias); then the statistics of
each BatchNorm's input are measured on frames and written back as running mean and variance, with
gamma and beta chosen to undo them exactly. The network computes what the ONNX model computes in
eval mode (checked on the same frames), and in train mode its batch statistics start where the
data puts them instead of at 0 and 1, which would scale every layer's output at the first step.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from onnx import numpy_helper
from torch import nn

from segmin.export import metadata as md
from segmin.export.onnx import DeployWrapper, load_segmin_model, read_metadata
from segmin.export.verify import load_frames, torch_reference, verify_against_torch
from segmin.models.checkpoint import model_info
from segmin.models.lraspp import SegmentationNet, build_model

_WRAPPER_PREFIX = "model."  # the exporter's wrapper module holds the SegmentationNet as `model`
_FOLDED_BIAS = ".weight_bias"  # the bias the exporter gives a convolution it folded a BatchNorm into


def network_from_onnx(
    path: Path, frames_root: Path, count: int = 64, *, batch: int = 16, domains: list[str] | None = None
) -> tuple[SegmentationNet, np.ndarray]:
    """The PyTorch network of the segmin ONNX model at `path`, BatchNorm statistics measured on up
    to `count` frames of `frames_root` (any dataset root or image folder, `export.verify.load_frames`;
    `domains` keeps a dataset root's frames to those), and those frames (uint8 N x H x W x 3 at the model's input size) for `check_conversion`.

    ValueError naming the file when it is not an fp32 segmin model whose weights fit the
    architecture its metadata names, or naming the folder when it has no frames.
    """
    props, tensors = _read_segmin_onnx(path)
    frames = load_frames(frames_root, md.parse_input_size(props[md.KEY_INPUT_SIZE]), limit=count, domains=domains)
    model = build_model("none", architecture=props.get(md.KEY_ARCHITECTURE, "lraspp_mobilenet_v3_large"))
    _load_folded(model, tensors, path)
    _measure_batchnorm_inputs(model, frames, batch)
    return model.eval(), frames


def model_from_onnx(
    path: Path, frames_root: Path, count: int = 64
) -> tuple[SegmentationNet, dict[str, Any], dict[str, str]]:
    """(network, checkpoint-style model_info, the ONNX metadata) of a segmin fp32 ONNX file, its
    conversion checked on `count` frames of `frames_root`: what `segmin export` exports a shipped
    model (which exists only as ONNX) to another format from."""
    network, frames = network_from_onnx(path, frames_root, count)
    check_conversion(network, path, frames)
    props = read_metadata(path)
    info = model_info(
        backbone_weights=props.get(md.KEY_BACKBONE, "unknown"),
        input_size=md.parse_input_size(props[md.KEY_INPUT_SIZE]),
        family=props.get(md.KEY_FAMILY, "unknown"),
        train_data=props.get(md.KEY_TRAIN_DATA, "unknown"),
        threshold=float(props[md.KEY_THRESHOLD]),
        architecture=props.get(md.KEY_ARCHITECTURE, "lraspp_mobilenet_v3_large"),
    )
    return network, info, props


def _read_segmin_onnx(path: Path) -> tuple[dict[str, str], dict[str, torch.Tensor]]:
    """(metadata, the network's weights by PyTorch name) of an fp32 segmin ONNX file."""
    graph_model = load_segmin_model(path)
    props = {p.key: p.value for p in graph_model.metadata_props}
    if props.get(md.KEY_PRECISION, "fp32") != "fp32":
        raise ValueError(f"{path}: a {props[md.KEY_PRECISION]} model; convert the fp32 file")
    tensors = {
        init.name.removeprefix(_WRAPPER_PREFIX): torch.from_numpy(numpy_helper.to_array(init).copy())
        for init in graph_model.graph.initializer
        if init.name.startswith(_WRAPPER_PREFIX)
    }
    return props, tensors


def check_conversion(model: SegmentationNet, path: Path, frames: np.ndarray) -> float:
    """The largest probability difference between the network and the ONNX model at `path` on
    `frames`; VerificationError (a ValueError) beyond the exporter's own bound."""
    return verify_against_torch(path, torch_reference(DeployWrapper(model.eval())), frames, 0.5).max_abs_diff


def _load_folded(model: SegmentationNet, tensors: dict[str, torch.Tensor], path: Path) -> None:
    """Folded convolutions in, each BatchNorm after one set to add the folded bias and nothing else."""
    state = model.state_dict()
    modules = dict(model.named_modules())
    loaded: dict[str, torch.Tensor] = {}
    for name, value in tensors.items():
        if name.endswith(_FOLDED_BIAS):
            conv = name.removesuffix(_FOLDED_BIAS)
            norm = _batchnorm_after(conv)
            if not isinstance(modules.get(norm), nn.BatchNorm2d):
                raise ValueError(f"{path}: {conv} has a folded bias but the network has no BatchNorm {norm}")
            eps = modules[norm].eps
            loaded |= {
                f"{norm}.weight": torch.ones_like(value),
                f"{norm}.bias": value,
                f"{norm}.running_mean": torch.zeros_like(value),
                f"{norm}.running_var": torch.full_like(value, 1.0 - eps),
            }
        elif name in state:
            loaded[name] = value
    wrong = [k for k, v in loaded.items() if k not in state or state[k].shape != v.shape]
    missing = [k for k in state if k not in loaded and not k.endswith("num_batches_tracked")]
    if wrong or missing:
        first = (wrong or missing)[0]
        raise ValueError(
            f"{path}: its weights do not fit the network its metadata names ({first} "
            f"{'does not match' if wrong else 'is missing'}; {len(wrong) + len(missing)} tensor(s) in all)"
        )
    model.load_state_dict(loaded, strict=False)


def _batchnorm_after(conv: str) -> str:
    """torchvision's Conv-BN pairs are Sequential items 0 and 1 (Conv2dNormActivation, LR-ASPP's cbr)."""
    parent, _, index = conv.rpartition(".")
    return f"{parent}.{int(index) + 1}"


@torch.no_grad()
def _measure_batchnorm_inputs(model: SegmentationNet, frames: np.ndarray, batch: int) -> None:
    """Each BatchNorm's input mean and variance over the frames become its running statistics,
    gamma and beta the values that leave its eval-mode output unchanged."""
    norms = {name: m for name, m in model.named_modules() if isinstance(m, nn.BatchNorm2d)}
    sums = {name: torch.zeros(3, m.num_features, dtype=torch.float64) for name, m in norms.items()}

    def hook(name: str):
        def record(_module: nn.Module, args: tuple[torch.Tensor, ...]) -> None:
            x = args[0].double().transpose(0, 1).flatten(1)
            sums[name] += torch.stack([torch.full_like(x[:, 0], x.shape[1]), x.sum(1), (x * x).sum(1)])

        return record

    handles = [m.register_forward_pre_hook(hook(name)) for name, m in norms.items()]
    wrapper = DeployWrapper(model.eval())  # the ONNX graph's own normalisation of uint8 frames
    try:
        for start in range(0, len(frames), batch):
            wrapper(torch.from_numpy(np.ascontiguousarray(frames[start : start + batch])))
    finally:
        for handle in handles:
            handle.remove()
    for name, norm in norms.items():
        count, total, squares = sums[name]
        mean = total / count
        var = (squares / count - mean * mean).clamp_min(0.0)
        scale = torch.sqrt(var + norm.eps)
        weight, bias, running_mean, running_var = norm.weight, norm.bias, norm.running_mean, norm.running_var
        if weight is None or bias is None or running_mean is None or running_var is None:
            raise ValueError(
                f"{name}: a BatchNorm takes the measured statistics only with affine=True and track_running_stats=True"
            )
        bias.copy_(bias.double() + mean)  # the folded bias, plus the mean taken out
        weight.copy_(scale)
        running_mean.copy_(mean)
        running_var.copy_(var)
