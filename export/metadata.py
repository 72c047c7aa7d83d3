"""The metadata contract of a segmin model file, shared by the writer (export) and readers (nav_eval).

Torch-free on purpose: `nav_eval.segmenter` imports this module to read a model file on a robot
computer that has only onnxruntime (or ai-edge-litert), numpy and OpenCV. Every value is a string
(ONNX `metadata_props`; a LiteRT file carries the same keys, see `export.litert_file`); the
helpers here format and parse the few structured ones.
"""

from __future__ import annotations

from collections.abc import Mapping

FORMAT = "segmin-onnx-v1"
FORMAT_LITERT = "segmin-litert-v1"
FORMAT_NAMES = {FORMAT: "ONNX", FORMAT_LITERT: "LiteRT"}

# Keys written into `metadata_props` (the names a consumer reads; keep them stable).
KEY_FORMAT = "segmin_format"
KEY_INPUT_SIZE = "input_size"  # "H,W" the graph expects (frames are resized to it)
KEY_INPUT_LAYOUT = "input_layout"  # "NHWC"
KEY_INPUT_DTYPE = "input_dtype"  # "uint8"
KEY_CHANNEL_ORDER = "channel_order"  # "RGB"
KEY_NORMALISATION = "normalisation"
KEY_OUTPUT = "output"
KEY_THRESHOLD = "threshold"
KEY_FAMILY = "crop_family"
KEY_TRAIN_DATA = "training_data"
KEY_BACKBONE = "backbone_weights"
KEY_ARCHITECTURE = "architecture"
KEY_VERSION = "segmin_version"
KEY_GIT_COMMIT = "git_commit"
KEY_PRECISION = "precision"  # fp32 | fp16 | int8
KEY_EXPORTER = "exporter"
KEY_OPSET = "opset"  # ONNX files only
KEY_CHECKPOINT = "source_checkpoint"
# A released model's card (`segmin models release`): the Markdown people read, and its figures as JSON.
KEY_MODEL_CARD = "model_card"
KEY_MODEL_CARD_JSON = "model_card_json"

REQUIRED_KEYS = (KEY_FORMAT, KEY_INPUT_SIZE, KEY_INPUT_LAYOUT, KEY_CHANNEL_ORDER, KEY_THRESHOLD)

INPUT_NAME = "rgb"
OUTPUT_NAME = "vegetation_probability"


def format_input_size(size: tuple[int, int] | list[int]) -> str:
    """(H, W) -> "H,W"."""
    height, width = (int(v) for v in size)
    return f"{height},{width}"


def parse_input_size(text: str) -> tuple[int, int]:
    """ "H,W" -> (H, W); ValueError naming the bad value."""
    parts = str(text).replace("x", ",").split(",")
    try:
        height, width = (int(p) for p in parts)
    except ValueError:
        raise ValueError(f"metadata {KEY_INPUT_SIZE}={text!r}: expected 'H,W' with two integers") from None
    if height <= 0 or width <= 0:
        raise ValueError(f"metadata {KEY_INPUT_SIZE}={text!r}: sizes must be positive")
    return height, width


def check_metadata(meta: Mapping[str, str], source: str, expected_format: str = FORMAT) -> None:
    """Raise ValueError naming `source` when `meta` is not the metadata of a segmin model file of
    `expected_format` (FORMAT: ONNX, FORMAT_LITERT: LiteRT)."""
    missing = [key for key in REQUIRED_KEYS if key not in meta]
    if missing:
        kind = FORMAT_NAMES[expected_format]
        raise ValueError(f"{source}: not a segmin {kind} model (metadata lacks {', '.join(missing)})")
    if meta[KEY_FORMAT] != expected_format:
        raise ValueError(f"{source}: unsupported model format {meta[KEY_FORMAT]!r} (expected {expected_format!r})")
    if meta[KEY_INPUT_LAYOUT] != "NHWC" or meta[KEY_CHANNEL_ORDER] != "RGB":
        raise ValueError(
            f"{source}: input layout {meta[KEY_INPUT_LAYOUT]!r} / channel order {meta[KEY_CHANNEL_ORDER]!r} "
            "not supported (expected NHWC / RGB)"
        )
    try:
        parse_input_size(meta[KEY_INPUT_SIZE])
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None
    try:
        threshold = float(meta[KEY_THRESHOLD])
    except ValueError:
        raise ValueError(f"{source}: metadata {KEY_THRESHOLD}={meta[KEY_THRESHOLD]!r} is not a number") from None
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"{source}: metadata threshold {threshold} is not in (0, 1)")
