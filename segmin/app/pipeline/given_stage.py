"""A chain stage that is not trained in the run: a model made before stands in for it.

`FamilyPlan.start_from` names the model and the stage. The stage's outputs look like a trained
stage's (a segmin checkpoint, its held-out figures), so the stage after it fine-tunes from it and a
gated candidate is judged against it exactly as against a stage trained in the run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from segmin.app.pipeline.config import StartFrom
from segmin.common.outputs import make_dirs

GIVEN_CHECKPOINT = "given.pt"


def given_model_file(start: StartFrom) -> Path:
    """The file `start.model` names (a shipped name resolved to its ONNX), checked to exist."""
    from segmin.nav_eval.runtime.shipped_models import resolve_model

    model = Path(start.model)
    path = model if model.suffix.lower() == ".pt" else resolve_model(start.model)
    if not path.is_file():
        raise FileNotFoundError(f"start_from.model {start.model}: no such file")
    return path


def given_stage(start: StartFrom, train_config: Any, frames_root: Path, folder: Path, log) -> dict[str, Any]:
    """Write `start.model` as the stage's checkpoint and score it on the held-out frames.

    An ONNX model (a shipped name or a file) is converted back to PyTorch: the exporter folded
    each BatchNorm into its convolution, so their statistics are measured again on
    `start.calibration_frames` of the stage's own training frames (`frames_root`, the stage's
    domains), the distribution the model was trained on. A .pt (a segmin checkpoint or a whole
    network's state dict) is taken as it is and must fit the stage's architecture exactly.
    """
    from segmin.app.pipeline.cache import file_digest
    from segmin.app.pipeline.stages import held_out_eval
    from segmin.common.machine import machine_summary

    make_dirs(folder)
    checkpoint = folder / GIVEN_CHECKPOINT
    source = _write_checkpoint(start, train_config, frames_root, checkpoint, log)
    held_out = held_out_eval(train_config, checkpoint, folder / "held-out", log)
    return {
        "checkpoint": str(checkpoint),
        "epochs": 0,
        "kept": "given",
        "kept_val_iou": None,
        "best_val_iou": None,  # no validation epochs: its held-out figures are in `held_out`
        "best_val_pixel_acc": None,
        "backbone_weights": source,  # where the stage's model came from, for the card's chain
        # Which file exactly: a shipped name names whatever is shipped when the run starts.
        "model_sha256": file_digest(given_model_file(start)),
        "image_size": train_config.image_size,
        "architecture": train_config.architecture,
        "seed": None,
        "held_out": held_out,
        "machine": machine_summary(),
    }


def _write_checkpoint(start: StartFrom, train_config: Any, frames_root: Path, out: Path, log) -> str:
    """The given model as a segmin checkpoint at `out`; returns what it was made from."""
    from segmin.models.checkpoint import save_checkpoint
    from segmin.models.lraspp import build_model
    from segmin.train.run import checkpoint_model_info

    state = _read_state(Path(start.model)) if Path(start.model).suffix.lower() == ".pt" else None
    if state is None:
        state = _converted(start, train_config, frames_root, log)
    # Whole: a partial fit would leave layers at random and be scored as if it were the model.
    network = build_model("none", architecture=train_config.architecture)
    try:
        network.load_state_dict(state)
    except RuntimeError as exc:
        raise ValueError(
            f"start_from.model {start.model}: does not fit the stage's {train_config.architecture} "
            f"({str(exc).splitlines()[0]})"
        ) from exc
    info = checkpoint_model_info(train_config)
    save_checkpoint(out, {"model": network.state_dict(), "model_info": info, "epoch": 0, "metrics": {}})
    return str(start.model)


def _read_state(path: Path) -> dict[str, Any]:
    """A .pt's network weights: a segmin checkpoint's or a whole network's state dict."""
    from segmin.models.safe_load import load_tensors

    if not path.is_file():
        raise FileNotFoundError(f"start_from.model {path}: no such file")
    state = load_tensors(path, "PyTorch state dict")
    if isinstance(state, dict) and isinstance(state.get("model"), dict):  # a segmin checkpoint
        state = state["model"]
    if not isinstance(state, dict):
        raise ValueError(f"start_from.model {path}: expected a state dict, got {type(state).__name__}")
    return state


def _converted(start: StartFrom, train_config: Any, frames_root: Path, log) -> dict[str, Any]:
    """An ONNX model's network as a state dict, with BatchNorm measured on the stage's frames."""
    from segmin.export.to_torch import check_conversion, network_from_onnx

    path = given_model_file(start)
    network, frames = network_from_onnx(
        path, frames_root, start.calibration_frames, domains=list(train_config.data.domains)
    )
    worst = check_conversion(network, path, frames)
    log(
        f"start_from: {path} as the stage's model, BatchNorm from {len(frames)} of its training frames "
        f"(largest probability difference to the ONNX model {worst:.1e})"
    )
    return network.state_dict()
