"""Export a SegmentationNet to an ONNX graph that takes what a robot camera gives.

The graph input is uint8 RGB, N x H x W x 3 (N dynamic, H x W the training input size), and the
graph does the rest itself: NHWC -> NCHW, /255 and ImageNet normalisation (folded into one Mul and
one Add), the network, and a sigmoid. So an embedded consumer (onnxruntime on the robot computer,
TensorRT on a Jetson) needs no preprocessing code beyond a resize to the model size, and cannot
get the normalisation subtly wrong. Output: vegetation probability N x 1 x H x W, float32.

Exporter choice: torch 2.14's dynamo exporter (`torch.export` + onnxscript, opset 18) is the
default, with one translation override. Out of the box it lowers the squeeze-excitation and
LR-ASPP `AdaptiveAvgPool2d(1)` into ReduceMean + Reshape + a Gather over computed indices (an
`as_strided` decomposition whose indices depend on the batch size): 169 nodes after onnxruntime's
optimiser, with more NCHWc reorders than the legacy exporter's graph (145). Mapping
`aten.adaptive_avg_pool2d(x, 1)` to ONNX `GlobalAveragePool` gives the cleanest graph of the three
(155 nodes as exported, 126 after optimisation, no shape arithmetic except the final Resize): the
one we ship. The legacy TorchScript exporter (`exporter="legacy"`, opset 17) is deprecated but
kept for old consumers; `python -m benchmarks export --compare-exporters` times both.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import onnx
import torch
from torch import nn

import segmin
from segmin.common.provenance import git_commit
from segmin.data.model_input import IMAGENET_MEAN, IMAGENET_STD
from segmin.export import metadata as md

EXPORTERS = ("dynamo", "legacy")
DEFAULT_OPSET = {"dynamo": 18, "legacy": 17}


class DeployWrapper(nn.Module):
    """uint8 RGB NHWC frames in, vegetation probability N x 1 x H x W out (float32)."""

    scale: torch.Tensor  # buffers (registered below), declared so that their type is known
    bias: torch.Tensor

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model
        mean = torch.tensor(IMAGENET_MEAN, dtype=torch.float32)
        std = torch.tensor(IMAGENET_STD, dtype=torch.float32)
        # (x / 255 - mean) / std == x * scale + bias: one Mul and one Add in the graph.
        self.register_buffer("scale", (1.0 / (255.0 * std)).view(1, 3, 1, 1))
        self.register_buffer("bias", (-mean / std).view(1, 3, 1, 1))

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        images = rgb.permute(0, 3, 1, 2).to(torch.float32) * self.scale + self.bias
        return torch.sigmoid(self.model(images))


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def build_metadata(
    model_info: Mapping[str, Any],
    *,
    input_size: tuple[int, int],
    exporter: str,
    opset: int | None,
    precision: str = "fp32",
    checkpoint: str | Path | None = None,
    file_format: str = md.FORMAT,
) -> dict[str, str]:
    """The metadata of an exported file (all values strings, see export.metadata): ONNX
    `metadata_props`, or a LiteRT file's segmin entry (`file_format=md.FORMAT_LITERT`, no opset)."""
    meta = {
        md.KEY_FORMAT: file_format,
        md.KEY_INPUT_SIZE: md.format_input_size(input_size),
        md.KEY_INPUT_LAYOUT: "NHWC",
        md.KEY_INPUT_DTYPE: "uint8",
        md.KEY_CHANNEL_ORDER: "RGB",
        md.KEY_NORMALISATION: "in graph: x/255 then ImageNet mean/std "
        f"(mean {list(IMAGENET_MEAN)}, std {list(IMAGENET_STD)})",
        md.KEY_OUTPUT: "vegetation probability, N x 1 x H x W, float32 (sigmoid applied)",
        md.KEY_THRESHOLD: repr(float(model_info.get("threshold", 0.5))),
        md.KEY_FAMILY: str(model_info.get("family", "unknown")),
        md.KEY_TRAIN_DATA: str(model_info.get("train_data", "unknown")),
        md.KEY_BACKBONE: str(model_info.get("backbone_weights", "unknown")),
        md.KEY_ARCHITECTURE: str(model_info.get("architecture", "unknown")),
        md.KEY_VERSION: segmin.__version__,
        md.KEY_GIT_COMMIT: git_commit(),
        md.KEY_PRECISION: precision,
        md.KEY_EXPORTER: exporter,
    }
    if opset is not None:
        meta[md.KEY_OPSET] = str(opset)
    if checkpoint is not None:
        meta[md.KEY_CHECKPOINT] = f"{Path(checkpoint).name} sha256:{file_sha256(checkpoint)}"
    return meta


def set_metadata(model: onnx.ModelProto, meta: Mapping[str, str]) -> None:
    """Replace the model's metadata_props with `meta` (keys not in `meta` are kept)."""
    current = {prop.key: prop.value for prop in model.metadata_props}
    current.update({str(k): str(v) for k, v in meta.items()})
    del model.metadata_props[:]
    onnx.helper.set_model_props(model, current)
    model.producer_name = "segmin"
    model.producer_version = segmin.__version__
    model.doc_string = "segmin crop-row vegetation segmentation: uint8 RGB NHWC in, vegetation probability out"


def drop_node_metadata(model: onnx.ModelProto) -> None:
    """Remove the per-node `metadata_props` the dynamo exporter writes.

    Why: they hold the exporting machine's Python stack traces and file paths (about 0.3 MB of a
    5.4 MB release model), which no runtime reads and a shipped file should not carry.
    """
    for node in [*model.graph.node, *(node for function in model.functions for node in function.node)]:
        del node.metadata_props[:]


def load_segmin_model(path: str | Path) -> onnx.ModelProto:
    """The segmin ONNX model at `path`, weights included.

    ValueError naming the file when it is not one: a file onnx cannot parse (truncated, not ONNX)
    gives protobuf's DecodeError or an OSError, which would otherwise reach the user as a traceback;
    metadata that is not a segmin model's is named by `metadata.check_metadata`.
    """
    try:
        model = onnx.load(str(path))
    except Exception as exc:  # DecodeError, OSError: whatever onnx raises for a file that is not a model
        raise ValueError(f"{path}: not a readable ONNX model ({type(exc).__name__}: {exc})") from exc
    md.check_metadata({prop.key: prop.value for prop in model.metadata_props}, str(path))
    return model


def read_metadata(path: str | Path) -> dict[str, str]:
    """metadata_props of an ONNX file as a dict (weights are not loaded)."""
    model = onnx.load(str(path), load_external_data=False)
    return {prop.key: prop.value for prop in model.metadata_props}


def _global_average_pool(self, output_size):  # onnxscript translation of aten.adaptive_avg_pool2d
    from onnxscript import opset18 as op

    sizes = [int(v) for v in (output_size if isinstance(output_size, (list, tuple)) else [output_size])]
    if any(v != 1 for v in sizes):
        raise ValueError(f"adaptive_avg_pool2d with output size {sizes}: only 1 (global pooling) is mapped")
    return op.GlobalAveragePool(self)


def export_graph(
    model: nn.Module,
    path: str | Path,
    *,
    input_size: tuple[int, int],
    exporter: str = "dynamo",
    opset: int | None = None,
) -> int:
    """Write the wrapped model as ONNX (one file, no metadata yet) to `path`; returns the opset used.

    Writes `path` directly: callers wrap it in `segmin.common.atomic.atomic_path`.
    """
    if exporter not in EXPORTERS:
        raise ValueError(f"exporter={exporter!r}: expected one of {EXPORTERS}")
    opset = int(opset if opset is not None else DEFAULT_OPSET[exporter])
    if exporter == "dynamo" and opset < 18:
        raise ValueError(f"opset {opset}: the dynamo exporter needs opset >= 18 (use --exporter legacy for older)")
    if opset < 14:
        raise ValueError(f"opset {opset}: HardSwish/HardSigmoid of MobileNetV3 need opset >= 14")
    height, width = (int(v) for v in input_size)
    wrapper = DeployWrapper(model).eval()
    # Batch 2 in the example: torch.export specialises a size-1 dimension to a constant.
    example = torch.zeros(2, height, width, 3, dtype=torch.uint8)
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if exporter == "dynamo":
            batch = torch.export.Dim("batch", min=1, max=4096)
            program = torch.onnx.export(
                wrapper,
                (example,),
                None,
                dynamo=True,
                opset_version=opset,
                input_names=[md.INPUT_NAME],
                output_names=[md.OUTPUT_NAME],
                dynamic_shapes={"rgb": {0: batch}},
                custom_translation_table={
                    torch.ops.aten.adaptive_avg_pool2d.default: _global_average_pool,
                    torch.ops.aten._adaptive_avg_pool2d.default: _global_average_pool,
                },
                external_data=False,
                optimize=True,
                verbose=False,
            )
            # torch types export()'s result for both exporters; the dynamo one always returns a program.
            program.save(str(path), external_data=False)  # type: ignore[union-attr]
        else:
            torch.onnx.export(
                wrapper,
                (example,),
                str(path),
                dynamo=False,
                opset_version=opset,
                input_names=[md.INPUT_NAME],
                output_names=[md.OUTPUT_NAME],
                dynamic_axes={md.INPUT_NAME: {0: "batch"}, md.OUTPUT_NAME: {0: "batch"}},
                do_constant_folding=True,
            )
    return opset


def check_graph_io(model: onnx.ModelProto, input_size: tuple[int, int], source: str) -> None:
    """The exported graph must take uint8 N x H x W x 3 and give N x 1 x H x W."""
    inputs = [i for i in model.graph.input if i.name not in {init.name for init in model.graph.initializer}]
    if len(inputs) != 1 or len(model.graph.output) != 1:
        raise ValueError(
            f"{source}: expected one input and one output, got {len(inputs)} and {len(model.graph.output)}"
        )
    tensor = inputs[0].type.tensor_type
    if tensor.elem_type != onnx.TensorProto.UINT8:
        raise ValueError(f"{source}: input {inputs[0].name!r} is not uint8")
    dims = [d.dim_value if d.HasField("dim_value") else None for d in tensor.shape.dim]
    expected = [None, int(input_size[0]), int(input_size[1]), 3]
    if dims != expected:
        raise ValueError(f"{source}: input shape {dims} is not {expected} (dynamic batch, H, W, 3)")
