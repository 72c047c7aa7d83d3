"""Loading PyTorch files without running code from them, and saying why a file was refused.

Every file segmin reads with torch (checkpoints, backbone state dicts) is plain tensors, numbers
and strings, so it loads with `torch.load(..., weights_only=True)`. When that refuses a file,
torch's message advises re-running with `weights_only=False` or allow-listing the pickled class:
both would run code from a file someone sent, which segmin never does, so that advice is never
passed on; the reason is given in segmin's words instead.
"""

from __future__ import annotations

import pickle
import re
from pathlib import Path
from typing import Any

import torch

_PICKLED_GLOBAL = re.compile(r"GLOBAL ([\w.]+)")
_FIRST_SENTENCE = re.compile(r"(?<=\.)\s")


def load_failure_reason(exc: BaseException) -> str:
    """Why `torch.load(weights_only=True)` (or a loader built on it) failed, without torch's advice."""
    if isinstance(exc, pickle.UnpicklingError):  # the weights-only unpickler refused pickled objects
        found = _PICKLED_GLOBAL.search(str(exc))
        what = f" ({found.group(1)})" if found else ""
        return (
            f"it holds pickled Python objects{what}; segmin loads only tensors, numbers and strings, never pickled code"
        )
    lines = str(exc).strip().splitlines()
    first = _FIRST_SENTENCE.split(lines[0], maxsplit=1)[0] if lines else ""
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def load_tensors(path: str | Path, what: str) -> Any:
    """`torch.load(path, weights_only=True)` on the CPU; ValueError "PATH: not a readable WHAT (why)"."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # truncated zip, foreign pickle, random bytes: torch raises several types
        raise ValueError(f"{path}: not a readable {what} ({load_failure_reason(exc)})") from exc
