"""Training-side checkpoint contents: exact-resume state packed as tensors and plain data.

The file format itself is `models.checkpoint` (always `weights_only=True` loadable). What train
adds under `training_state`: optimizer, scheduler and AMP scaler state dicts, the epoch being
trained and how many steps of it are done, the best IoU so far, the metrics history, and the
RNG states of torch / CUDA / numpy / python, stored as tensors and lists (no pickled objects).
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from segmin.models.checkpoint import model_info, read_checkpoint, save_checkpoint


def rng_state() -> dict[str, Any]:
    # The dict form: numpy's stub types the default (legacy tuple) form as this dict.
    np_state = np.random.get_state(legacy=False)
    py_state = random.getstate()
    return {
        "torch": torch.get_rng_state(),
        "cuda": list(torch.cuda.get_rng_state_all()) if torch.cuda.is_available() else [],
        "numpy": {
            "keys": torch.from_numpy(np.asarray(np_state["state"]["key"], dtype=np.int64)),
            "pos": int(np_state["state"]["pos"]),
            "has_gauss": int(np_state["has_gauss"]),
            "gauss": float(np_state["gauss"]),
        },
        "python": {
            "version": int(py_state[0]),
            "state": torch.tensor(py_state[1], dtype=torch.int64),
            "gauss": py_state[2],
        },
    }


def set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    if state.get("cuda") and torch.cuda.is_available() and len(state["cuda"]) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(state["cuda"])
    n = state["numpy"]
    np.random.set_state(("MT19937", n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["gauss"]))
    p = state["python"]
    random.setstate((p["version"], tuple(int(v) for v in p["state"].tolist()), p["gauss"]))


def cpu_state_dict(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The plain (non-DDP) model's state dict on CPU."""
    module = getattr(module, "module", module)
    return {k: v.detach().cpu().clone() for k, v in module.state_dict().items()}


def write_training_checkpoint(
    path: str | Path,
    *,
    model: torch.nn.Module,
    info: dict[str, Any],
    epoch: int,
    metrics: dict[str, float],
    config: dict[str, Any],
    training_state: dict[str, Any] | None = None,
) -> None:
    payload: dict[str, Any] = {
        "model": cpu_state_dict(model),
        "model_info": info,
        "epoch": int(epoch),
        "metrics": {k: float(v) for k, v in metrics.items()},
        "config": config,
    }
    if training_state is not None:
        payload["training_state"] = training_state
    save_checkpoint(path, payload)


def read_training_state(path: str | Path) -> dict[str, Any]:
    """The payload of a checkpoint written with training state (for `--resume`)."""
    payload = read_checkpoint(path)
    if "training_state" not in payload:
        raise ValueError(f"{path}: checkpoint has no training_state (only last.pt can be resumed)")
    return payload


__all__ = [
    "cpu_state_dict",
    "model_info",
    "read_training_state",
    "rng_state",
    "set_rng_state",
    "write_training_checkpoint",
]
