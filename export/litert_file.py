"""A segmin LiteRT (.tflite) file: its metadata, and running it with the LiteRT interpreter.

Torch-free on purpose, like `export.metadata`: the robot-side `LiteRtSegmenter` and the export
checks both use it, and a robot computer has only `ai-edge-litert` (the `litert` extra), numpy
and OpenCV.

Metadata: the same key/value strings an ONNX export carries in `metadata_props` (see
`export.metadata`), stored as one JSON object in the flatbuffer's own `metadata` map under the
name `segmin` (the schema's place for producer data, which LiteRT keeps through quantisation
and ignores when it runs the model). Read with the schema module `ai-edge-litert` ships, so no
other flatbuffer library or the deprecated TFLite Support metadata writer is needed.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

METADATA_NAME = "segmin"  # the flatbuffer metadata entry holding segmin's metadata (a JSON object)


def _read_bytes(path: str | os.PathLike[str]) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the LiteRT model ({exc.strerror or exc})") from None


def _model(path: str | os.PathLike[str], data: bytes):
    """The flatbuffer's root table; ValueError naming the file when it is not a LiteRT model."""
    from ai_edge_litert import schema_py_generated as schema

    # A .tflite flatbuffer carries the file identifier "TFL3" at bytes 4..8.
    if len(data) < 8 or data[4:8] != b"TFL3":
        raise ValueError(f"{path}: not a LiteRT (.tflite) model (no TFL3 flatbuffer identifier)")
    return schema.Model.GetRootAs(data, 0)


def read_metadata(path: str | os.PathLike[str]) -> dict[str, str]:
    """segmin's metadata of a .tflite file ({} when the file has none); ValueError for a bad file."""
    data = _read_bytes(path)
    model = _model(path, data)
    for i in range(model.MetadataLength()):
        entry = model.Metadata(i)
        if entry.Name() != METADATA_NAME.encode():
            continue
        buffer = model.Buffers(entry.Buffer())
        # Small buffers sit inside the flatbuffer; a converter may put big ones after it (offset/size).
        raw = data[buffer.Offset() : buffer.Offset() + buffer.Size()] if buffer.Offset() > 1 else buffer.DataAsNumpy()
        try:
            meta = json.loads(bytes(raw).decode("utf-8"))
        except (TypeError, ValueError) as exc:  # DataAsNumpy gives 0 for an empty buffer
            raise ValueError(f"{path}: segmin metadata entry is not a JSON object ({exc})") from None
        if not isinstance(meta, dict):
            raise ValueError(f"{path}: segmin metadata entry is not a JSON object")
        return {str(k): str(v) for k, v in meta.items()}
    return {}


def with_metadata(data: bytes, meta: dict[str, str]) -> bytes:
    """The .tflite flatbuffer `data` with segmin's metadata entry set to `meta` (replaced if present)."""
    from ai_edge_litert import schema_py_generated as schema
    from ai_edge_litert.tools import flatbuffer_utils

    model = flatbuffer_utils.read_model_from_bytearray(bytearray(data))  # buffers stored by offset inlined
    model.metadata = [m for m in (model.metadata or []) if m.name not in (METADATA_NAME, METADATA_NAME.encode())]
    buffer = schema.BufferT()
    buffer.data = np.frombuffer(json.dumps(meta, sort_keys=True).encode("utf-8"), dtype=np.uint8)
    model.buffers.append(buffer)
    entry = schema.MetadataT()
    entry.name = METADATA_NAME
    entry.buffer = len(model.buffers) - 1
    model.metadata.append(entry)
    return bytes(flatbuffer_utils.convert_object_to_bytearray(model))


def stamp(path: str | os.PathLike[str], meta: dict[str, str]) -> None:
    """Merge `meta` into the segmin metadata of the .tflite file at `path` (rewritten in place)."""
    current = read_metadata(path)
    current.update(meta)
    Path(path).write_bytes(with_metadata(_read_bytes(path), current))


def make_interpreter(path: str | os.PathLike[str], threads: int = 2):
    """A LiteRT interpreter (XNNPACK CPU delegate, `threads` threads) with tensors allocated."""
    from ai_edge_litert.interpreter import Interpreter

    try:
        interpreter = Interpreter(model_path=str(path), num_threads=int(threads))
        interpreter.allocate_tensors()
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"{path}: not a loadable LiteRT model ({str(exc).splitlines()[0][:300]})") from None
    return interpreter


class Runner:
    """One interpreter's input and output, with a quantised output turned back into probabilities.

    A full-integer model's output is int8 (probability = scale * (q - zero_point)); consumers get
    float32 either way, as from the ONNX file.
    """

    def __init__(self, interpreter: Any) -> None:
        self.interpreter = interpreter
        (self.input,) = interpreter.get_input_details()
        (self.output,) = interpreter.get_output_details()
        scale, zero_point = self.output["quantization"]
        self._dequantize = (float(scale), int(zero_point)) if scale else None

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        """float32 probabilities of one uint8 1 x H x W x 3 batch."""
        self.interpreter.set_tensor(self.input["index"], batch)
        self.interpreter.invoke()
        out = self.interpreter.get_tensor(self.output["index"])
        if self._dequantize is None:
            return out.astype(np.float32, copy=False)
        scale, zero_point = self._dequantize
        return ((out.astype(np.float32) - zero_point) * scale).astype(np.float32, copy=False)


def run_frames(runner: Runner, frames: np.ndarray) -> np.ndarray:
    """Probabilities (N x 1 x H x W float32) of uint8 N x H x W x 3 frames, one frame a call
    (the converted graph has a fixed batch of 1)."""
    return np.concatenate([runner(frames[i : i + 1]) for i in range(len(frames))])
