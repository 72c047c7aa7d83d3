"""Models shipped with segmin, by name: `OnnxSegmenter("vineyards")`, `--model trees`.

Why names: a team should be able to put a robot in a row on day one, offline, with nothing but
`pip install segmin`. The trained ONNX files live in the package (`released/<name>.onnx`), each
with its model card beside it (`<name>.md` for people, `<name>.card.json` for `segmin models
list`; the same card is in the ONNX metadata) and its real-photo contact sheet (`<name>.real.jpg`). `segmin models release --run RUN_DIR` puts a
pipeline run's models there.

Everything a model argument accepts goes through `resolve_model`: an existing file is used as it
is; a shipped name resolves to its file; anything else is one clear error. Torch-free, like the
rest of the runtime. `SEGMIN_MODELS_DIR` points the registry at another folder (tests, or a
robot that keeps its models outside the Python environment).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from segmin.common.figures import format_figure

SHIPPED_NAMES: tuple[str, ...] = ("vineyards", "trees")
ENV_MODELS_DIR = "SEGMIN_MODELS_DIR"
PACKAGE_MODELS_DIR = Path(__file__).with_name("released")
CARD_SUFFIX = ".card.json"
# The real-photo contact sheet shipped beside a card (photo | errors | truth), so the card's figures can be seen.
SHEET_SUFFIX = ".real.jpg"


def models_dir() -> Path:
    """The registry folder: $SEGMIN_MODELS_DIR when set, else the package's `released/`."""
    override = os.environ.get(ENV_MODELS_DIR)
    return Path(override) if override else PACKAGE_MODELS_DIR


@dataclass(frozen=True)
class ShippedModel:
    """One shipped name: its files in the registry folder, present or not."""

    name: str
    onnx: Path
    card_markdown: Path
    card_json: Path

    @property
    def present(self) -> bool:
        return self.onnx.is_file()

    def card(self) -> dict[str, Any] | None:
        """The card's figures (`segmin models list`), or None when no card was released."""
        if not self.card_json.is_file():
            return None
        try:
            card = json.loads(self.card_json.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise ValueError(f"{self.card_json}: not a readable model card ({exc})") from None
        if not isinstance(card, dict):
            raise ValueError(f"{self.card_json}: not a model card (expected a JSON object)")
        problem = _wrong_field(card)
        if problem is not None:
            raise ValueError(f"{self.card_json}: not a model card ({problem})")
        return card


# The card fields readers format (`headline`, the pipeline report) and the JSON type each must
# have: a card edited by hand with a wrong type would otherwise be a traceback there.
_NUMBER, _OBJECT, _LIST, _COUNT = (int, float), (dict,), (list,), (int,)
_EXPECTED: dict[tuple[type, ...], str] = {
    _NUMBER: "a number or null",
    _OBJECT: "a JSON object or null",
    _LIST: "a list or null",
}
_CARD_FIELDS = {"synthetic_val_iou": _NUMBER, "real_photos": _OBJECT, "latency": _OBJECT, "closed_loop": _LIST}
_SECTION_FIELDS = {"real_photos": ("mean_iou", "pooled_iou", "precision", "recall"), "latency": ("median", "p95")}


def _wrong_field(card: dict[str, Any]) -> str | None:
    """The first card field of a wrong type, as "field NAME: expected ..., got ...", or None."""
    checks: list[tuple[str, Any, tuple[type, ...]]] = [(name, card.get(name), t) for name, t in _CARD_FIELDS.items()]
    for section, keys in _SECTION_FIELDS.items():
        if isinstance(card.get(section), dict):
            checks += [(f"{section}.{key}", card[section].get(key), _NUMBER) for key in keys]
    loop = card.get("closed_loop")
    for i, entry in enumerate(loop if isinstance(loop, list) else []):
        if not isinstance(entry, dict):
            return f"field closed_loop[{i}]: expected a JSON object, got {json.dumps(entry)}"
        checks += [(f"closed_loop[{i}].{key}", entry.get(key), _COUNT) for key in ("runs", "successes")]
    for name, value, types in checks:
        if (value is None and types is not _COUNT) or (isinstance(value, types) and not isinstance(value, bool)):
            continue
        return f"field {name}: expected {_EXPECTED.get(types, 'a whole number')}, got {json.dumps(value)}"
    return None


def shipped_model(name: str) -> ShippedModel:
    """The registry entry of a shipped name; ValueError listing the names for any other."""
    if name not in SHIPPED_NAMES:
        raise ValueError(f"model {name!r}: not a shipped model name (shipped: {', '.join(SHIPPED_NAMES)})")
    root = models_dir()
    return ShippedModel(name, root / f"{name}.onnx", root / f"{name}.md", root / f"{name}{CARD_SUFFIX}")


MODEL_SUFFIXES = (".onnx", ".tflite")


def looks_like_name(spec: str | os.PathLike[str]) -> bool:
    """A bare word (no folder, no model file suffix): meant as a shipped model name, not a path."""
    text = os.fspath(spec)
    return bool(text) and os.sep not in text and "/" not in text and not text.lower().endswith(MODEL_SUFFIXES)


def resolve_model(spec: str | os.PathLike[str], what: str = "--model", suffix: str = ".onnx") -> Path:
    """The model file `spec` means: an existing file, or a shipped name's file with `suffix`
    (".onnx", the shipped files; ".tflite", a LiteRT export of a shipped model put beside them).

    Errors (one line each, naming `what`): a shipped name whose file this install does not have
    yet, a bare word that is neither a file nor a shipped name, a path that does not exist.
    """
    path = Path(spec)
    if path.is_file():
        return path
    text = os.fspath(spec)
    if text in SHIPPED_NAMES:
        entry = shipped_model(text)
        wanted = entry.onnx.with_suffix(suffix)
        if wanted.is_file():
            return wanted
        if suffix == ".onnx":
            how = "release one with `segmin models release --run RUN_DIR`"
        else:
            how = (
                f"shipped models come as ONNX: write one with `segmin export --checkpoint {text} "
                f"--format tflite --calib-data DIR --out {wanted.name}` and put it there, or pass its path"
            )
        raise ValueError(
            f"{what} {text}: a shipped model name, but this install has no {wanted.name} yet "
            f"(looked in {wanted.parent}; {how})"
        )
    if looks_like_name(text):
        raise ValueError(
            f"{what} {text!r}: no such file, and not a shipped model name (shipped: {', '.join(SHIPPED_NAMES)})"
        )
    kind = "ONNX" if suffix == ".onnx" else "LiteRT"
    raise FileNotFoundError(f"{what} {text}: {kind} model not found")


def headline(card: dict[str, Any]) -> str:
    """One line of a card's figures (`segmin models list`); what the run did not measure says so."""
    real = card.get("real_photos") or {}
    latency = card.get("latency") or {}
    loop = card.get("closed_loop") or []
    runs, successes = sum(r["runs"] for r in loop), sum(r["successes"] for r in loop)
    return ", ".join(
        [
            f"{card.get('architecture')} {format_size(card.get('input_size'))}",
            f"val IoU {format_figure(card.get('synthetic_val_iou'))}",
            f"real IoU {format_figure(real.get('mean_iou'))} (precision {format_figure(real.get('precision'))})",
            f"closed loop {successes}/{runs} runs succeeded" if loop else "closed loop not measured",
            f"{format_figure(latency.get('median'), 2)} ms a frame ({latency.get('threads', '?')} threads)",
        ]
    )


def format_size(size: Any) -> str:
    """[H, W] -> "HxW" ("?" when the card has none)."""
    return f"{size[0]}x{size[1]}" if isinstance(size, (list, tuple)) and len(size) == 2 else "?"
