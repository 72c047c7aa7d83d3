"""The checkpoint file format shared by training (writer) and export (reader).

A checkpoint is a plain dict of tensors and primitives, so it always loads with
`torch.load(..., weights_only=True)` (no pickled code runs from a file someone sent you).
Keys:
  format          "segmin-checkpoint-v1"
  model           SegmentationNet state dict
  model_info      {"architecture" (a name in models.lraspp.ARCHITECTURES), "backbone_weights" (what the backbone started from),
                   "input_size": [h, w], "threshold", "family", "train_data"}
  epoch, metrics  training progress and the last validation metrics
  training_state  optional: optimizer/scheduler/RNG states for exact resume (train/ owns it)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from segmin.common.atomic import atomic_path
from segmin.models.architectures import ARCHITECTURE, ARCHITECTURES
from segmin.models.lraspp import SegmentationNet, build_model
from segmin.models.safe_load import load_tensors

FORMAT = "segmin-checkpoint-v1"


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> None:
    """Write a checkpoint dict atomically (adds the format tag)."""
    payload = {"format": FORMAT, **payload}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load and check a checkpoint dict; errors name the file and what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    payload = load_tensors(path, "segmin checkpoint")
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path}: not a segmin checkpoint (missing format tag {FORMAT!r})")
    for key in ("model", "model_info"):
        if key not in payload:
            raise ValueError(f"{path}: checkpoint has no {key!r} entry")
    if not isinstance(payload["model"], dict):
        raise ValueError(f"{path}: 'model' is a {type(payload['model']).__name__}, expected a state dict")
    check_model_info(payload["model_info"], path)
    return payload


def check_model_info(info: Any, path: str | Path) -> None:
    """The `model_info` entry has the shape export and the segmenters rely on; ValueError naming
    the file and the field (a hand-edited or foreign file must not fail later with a KeyError)."""
    if not isinstance(info, dict):
        raise ValueError(f"{path}: model_info is a {type(info).__name__}, expected a mapping")
    if info.get("architecture") not in ARCHITECTURES:
        raise ValueError(
            f"{path}: model_info.architecture {info.get('architecture')!r} is not one of {', '.join(ARCHITECTURES)}"
        )
    size = info.get("input_size")
    if not (
        isinstance(size, (list, tuple))
        and len(size) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)
    ):
        raise ValueError(f"{path}: model_info.input_size is {size!r}, expected [height, width] > 0")
    threshold = info.get("threshold", 0.5)
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not 0.0 < threshold < 1.0:
        raise ValueError(f"{path}: model_info.threshold is {threshold!r}, expected a number in (0, 1)")


def load_model(path: str | Path) -> tuple[SegmentationNet, dict[str, Any]]:
    """Rebuild the network from a checkpoint (eval mode, CPU) and return it with its model_info."""
    payload = read_checkpoint(path)
    model = build_model("none", architecture=payload["model_info"]["architecture"])
    try:
        model.load_state_dict(payload["model"])
    except RuntimeError as exc:
        raise ValueError(f"{path}: weights do not fit the model ({exc})") from exc
    model.eval()
    return model, dict(payload["model_info"])


def model_info(
    *,
    backbone_weights: str,
    input_size: tuple[int, int],
    family: str,
    train_data: str,
    threshold: float = 0.5,
    architecture: str = ARCHITECTURE,
) -> dict[str, Any]:
    """The `model_info` entry a checkpoint carries into export metadata."""
    return {
        "architecture": architecture,
        "backbone_weights": backbone_weights,
        "input_size": [int(input_size[0]), int(input_size[1])],
        "threshold": float(threshold),
        "family": family,
        "train_data": train_data,
    }
