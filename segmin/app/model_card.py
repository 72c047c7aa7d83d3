"""Model cards: what a released model is, how it was made and how well it does, from its pipeline run.

Why a card: a shipped model is only as trustworthy as what is known about it. The card gathers,
from the stage records of one `segmin pipeline` run folder (nothing is re-measured), the command
and the recipe with its hash, the data (worlds with their seeds, frame counts), the chain of
training stages (each fine-tuning stage from the one before), the training time and machine, the synthetic
validation IoU, the real-photo IoU / precision / recall with the contact sheet, the closed-loop
results, the onnxruntime latency and the licence. A stage the run did not do is reported as
"not measured", never guessed. `card_markdown` renders it for people; the same dict goes beside
the model as JSON (`segmin models list` reads it, `shipped_models.headline`) and, with the Markdown, into the ONNX metadata.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

from segmin.app.pipeline.cache import StageCache, file_digest
from segmin.app.pipeline.config import FIRST_STAGE
from segmin.app.pipeline.report import count_frames
from segmin.app.pipeline.run_files import COMMAND_FILE, RECIPE_FILE
from segmin.app.pipeline.stages import read_metrics_csv
from segmin.common.figures import format_figure
from segmin.nav_eval.runtime.shipped_models import format_size

LICENCE = (
    "MIT (segmin's code and these weights). Trained on frames segmin renders itself; the real photos "
    "it is scored on (Aghi et al. 2021, doi:10.5281/zenodo.4601472, CC BY 4.0) are a test set only."
)


def build_card(run_dir: Path, family: str) -> dict[str, Any]:
    """The card of `family`'s exported model in the pipeline run `run_dir`.

    ValueError naming the run and the stage when the model was not exported there (a card needs
    at least the training and the export; the evaluations are optional).
    """
    cache = StageCache(run_dir)
    export = _finished(cache, f"export/{family}")
    # The training stages that made the model, first to last (records from before fine-tuning
    # stages existed name none: the family's one training stage).
    keys = list(export.get("train_stages", [f"train/{family}"])) if export is not None else [f"train/{family}"]
    found = [_finished(cache, key) for key in keys]
    chain = [outputs for outputs in found if outputs is not None]
    if export is None or len(chain) < len(keys):
        raise ValueError(f"{run_dir}: no finished {keys[-1]} and export/{family} stages (run `segmin pipeline`)")
    train = chain[-1]
    onnx = _in_run(run_dir, f"export/{family}", export["onnx"])
    worlds = ((_finished(cache, "render") or {}).get("worlds") or {}).get(family, [])
    return {
        "name": family,
        "family": family,
        "architecture": train.get("architecture", "lraspp_mobilenet_v3_large"),
        "input_size": export.get("input_size"),
        "onnx_sha256": file_digest(onnx),
        "onnx_mb": round(onnx.stat().st_size / 1e6, 2),
        "recipe": _recipe(run_dir),
        "command": _command(run_dir),
        "data": _data(run_dir, cache, family, _stage_name(keys[-1])),
        "training": {
            "epochs": train.get("epochs"),
            "image_size": train.get("image_size"),
            "backbone_weights": train.get("backbone_weights"),
            "kept": train.get("kept"),
            "seed": train.get("seed"),
            "seconds": _chain_seconds(run_dir, keys),
            "machine": train.get("machine"),
        },
        "stages": [_stage_entry(run_dir, key, outputs, worlds) for key, outputs in zip(keys, chain, strict=True)],
        "candidate_gate": export.get("gate"),  # a candidate stage's verdict on held-out frames (None: no gate)
        "synthetic_val_iou": train.get("kept_val_iou"),
        "real_photos": _real_photos(cache, family, _photo_looks_before(run_dir, family)),
        "closed_loop": _closed_loop(run_dir, cache, family),
        "latency": export.get("latency_ms"),
        "licence": LICENCE,
        "source_run": str(run_dir),
    }


def card_markdown(card: dict[str, Any]) -> str:
    """The card for people: one page of Markdown."""
    recipe, data, training = card["recipe"], card["data"], card["training"]
    real, latency = card.get("real_photos"), card.get("latency")
    lines = [
        f"# segmin model card: `{card['name']}`",
        "",
        f"- network: `{card['architecture']}`, input {format_size(card['input_size'])} (uint8 RGB NHWC), "
        f"{card['onnx_mb']} MB fp32 ONNX, sha256 `{card['onnx_sha256'][:16]}`",
        f"- recipe: pipeline profile `{recipe['profile']}`, config sha256 `{recipe['config_sha256']}`"
        + (f"; command `{card['command']}`" if card.get("command") else ""),
        f"- data: {data['train_frames']} rendered training frames from {', '.join(data['train_worlds']) or '?'}; "
        f"{data['val_frames']} validation frames from held-out worlds {', '.join(data['val_worlds']) or '?'}"
        + (f" ({_world_list(data['validation'])})" if data.get("validation") else ""),
        f"- training: {training['epochs']} epochs at {training['image_size']} px"
        + (f", seed {training['seed']}" if training.get("seed") is not None else "")
        + ", backbone "
        f"{training['backbone_weights']}, kept `{training['kept']}`, {_duration(training['seconds'])} on "
        f"{training['machine'] or 'a machine the run did not record'}",
        f"- synthetic validation IoU: {format_figure(card['synthetic_val_iou'])}",
    ]
    if len(card.get("stages") or []) > 1:
        lines += ["", "## Training stages", ""]
        lines += [
            f"{i}. `{st['stage']}`: from {st['start']}{_sha(st)}, {st['epochs']} epochs, seed {st['seed']}, kept `{st['kept']}` (validation IoU "
            f"{format_figure(st['val_iou'])}), {_duration(st['seconds'])}; {st['frames']} frames from "
            f"{_world_list(st['worlds'])}"
            for i, st in enumerate(card["stages"], 1)
        ]
        lines.append("")
    gate = card.get("candidate_gate")
    if gate:
        lines.append(
            f"- candidate stage `{gate['stage']}`: "
            + (
                "passed its gate on the held-out frames, so this model is it"
                if gate["passed"]
                else "failed its gate on the held-out frames ("
                + "; ".join(gate["failures"])
                + "), so this model is the stage before it"
            )
        )
    if real:
        lines.append(
            f"- real photos ({real['images']} labelled vineyard photos, a test set{_looks(real)}): mean IoU "
            f"{format_figure(real['mean_iou'])} (pooled {format_figure(real['pooled_iou'])}), precision "
            f"{format_figure(real['precision'])} and recall {format_figure(real['recall'])} over all pixels "
            f"(per-photo means {format_figure(real['mean_precision'])} / {format_figure(real['mean_recall'])}); "
            + (
                f"contact sheet `{real['contact_sheet_file']}` beside this card (photo | errors: green found, "
                "red false crop, blue missed | truth)"
                if real.get("contact_sheet_file")
                else f"contact sheet `{real['contact_sheet']}` in the source run"
            )
        )
    else:
        lines.append("- real photos: not measured in this run")
    if latency:
        lines.append(
            f"- latency: median {format_figure(latency.get('median'), 2)} ms, p95 {format_figure(latency.get('p95'), 2)} ms a frame "
            f"(onnxruntime, {latency.get('threads')} threads, {format_size(latency.get('frame_size'))} frames, "
            "the run's machine)"
        )
    lines += ["", "## Closed loop", ""]
    if card["closed_loop"]:
        lines += [
            "| field | method | successes | MAE m, all runs | MAE m, successful runs |",
            "|---|---|---|---|---|",
        ]
        lines += [
            f"| {r['field']} | {r['method']} | {r['successes']}/{r['runs']} | {format_figure(r['mae'])} "
            f"| {format_figure(r.get('mae_successful'))} |"
            for r in card["closed_loop"]
        ]
        lines += ["", "A failed run's MAE covers the path until it failed (collision, leaving the row or stalling)."]
    else:
        lines.append("Not measured in this run.")
    return "\n".join([*lines, "", "## Licence", "", card["licence"], "", f"Source run: `{card['source_run']}`", ""])


def _finished(cache: StageCache, stage: str) -> dict[str, Any] | None:
    record = cache.record(stage)
    return dict(record.outputs) if record is not None and record.finished and record.outputs else None


def _training_seconds(run_dir: Path, key: str) -> float | None:
    """A training stage's time: the sum of its epochs' wall time from metrics.csv (None without one).

    Why not the stage record's time: a stage resumed after an interruption records only the
    last process's share (a release training of hours resumed near its end would read minutes).
    metrics.csv keeps every finished epoch's time across resumes; an epoch resumed from a
    mid-epoch checkpoint counts from its resume, so an interruption loses at most part of one.
    """
    rows = read_metrics_csv(run_dir / key / "metrics.csv")
    seconds = [row["seconds"] for row in rows if "seconds" in row]
    return sum(seconds) if seconds else None


def _chain_seconds(run_dir: Path, keys: list[str]) -> float | None:
    """The whole chain's time of epochs (None when no stage recorded one)."""
    times = [t for t in (_training_seconds(run_dir, key) for key in keys) if t is not None]
    return sum(times) if times else None


def _sha(stage: dict[str, Any]) -> str:
    """(sha256 abcd...) after a given stage's model, for people."""
    return f" (sha256 `{stage['start_sha256'][:16]}`)" if stage.get("start_sha256") else ""


def _looks(real: dict[str, Any]) -> str:
    """How often the photo set was looked at, for the card's line (cards from before it was kept: nothing).

    A run's card counts the looks before it and its own one; a card released before the count was
    kept carries the count since (`in_all`) and whether the model was chosen among candidates
    scored on the photos, which makes its figures there no clean test."""
    looks = real.get("looks")
    if not looks:
        return ""
    if "in_all" in looks:
        chosen = ", this model chosen among candidates scored on it" if looks.get("chosen_with_them") else ""
        return f" looked at {looks['in_all']} times in all for models of this recipe{chosen}"
    before = looks["before"]
    earlier = f"{before} time{'s' * (before != 1)} while this model's recipe was made and " if before else ""
    return f" looked at {earlier}once for this model, after it was chosen"


def _stage_entry(run_dir: Path, key: str, outputs: dict[str, Any], worlds: list[dict[str, Any]]) -> dict[str, Any]:
    """One training stage of the chain: where it started, its data and what it kept."""
    own = [w for w in worlds if w.get("stage") == _stage_name(key)]
    start = str(outputs.get("backbone_weights"))
    run = str(run_dir)
    return {
        "stage": key,
        # A fine-tuning stage starts from a checkpoint inside the run: named by its path in the run.
        "start": Path(start).relative_to(run).as_posix() if start.startswith(run) else start,
        # A stage given by start_from: the exact model file it started from.
        **({"start_sha256": outputs["model_sha256"]} if outputs.get("model_sha256") else {}),
        "epochs": outputs.get("epochs"),
        "seed": outputs.get("seed"),
        "kept": outputs.get("kept"),
        "val_iou": outputs.get("kept_val_iou"),
        "seconds": _training_seconds(run_dir, key),
        "worlds": own,
        "frames": sum(int(w["frames"]) for w in own),
    }


def _stage_name(key: str) -> str:
    """train/<family>/<stage> -> <stage>; a family's only stage, train/<family>, is its first."""
    return key.split("/")[2] if key.count("/") > 1 else FIRST_STAGE


def _world_list(worlds: list[dict[str, Any]]) -> str:
    """world (seed s, n frames), ... for people."""
    return ", ".join(f"{w['world']} (seed {w['seed']}, {w['frames']} frames)" for w in worlds) or "?"


def _command(run_dir: Path) -> str | None:
    """The `segmin pipeline` command line that ran the run (None for a run from before it was recorded)."""
    path = run_dir / COMMAND_FILE
    return path.read_text(encoding="utf-8").strip() if path.is_file() else None


def _in_run(run_dir: Path, stage: str, recorded: str) -> Path:
    """A file a stage recorded (its path as the pipeline was called), found in that stage's folder."""
    path = run_dir / stage / Path(recorded).name
    if path.is_file():
        return path
    if Path(recorded).is_file():
        return Path(recorded)
    raise ValueError(f"{run_dir}: {stage} recorded {recorded}, which is not in {run_dir / stage}")


def _recipe(run_dir: Path) -> dict[str, str]:
    """The profile and its resolved config's hash (pipeline.yaml, written by the runner)."""
    import yaml

    path = run_dir / RECIPE_FILE
    if not path.is_file():
        return {"profile": "unknown (run predates pipeline.yaml)", "config_sha256": "unknown"}
    text = path.read_text(encoding="utf-8")
    profile = (yaml.safe_load(text) or {}).get("profile", "unknown")
    return {"profile": str(profile), "config_sha256": hashlib.sha256(text.encode()).hexdigest()[:16]}


def _data(run_dir: Path, cache: StageCache, family: str, stage: str) -> dict[str, Any]:
    """The last training stage's frames (the model's final data) and the validation frames."""
    render = _finished(cache, "render") or {}
    domains = render.get("domains", {}).get(family, {"train": [], "val": []})
    sets = (render.get("training_sets") or {}).get(family, {})
    last = sets.get(stage, {"root": "train", "domains": domains["train"]})
    worlds = (render.get("worlds") or {}).get(family, [])
    return {
        "train_worlds": list(last["domains"]),
        "val_worlds": list(domains["val"]),
        "train_frames": count_frames(run_dir / "render" / last["root"], last["domains"]),
        "val_frames": count_frames(run_dir / "render" / "val", domains["val"]),
        # Each held-out world with its seed and frames (render records from before they were kept lack them).
        **({"validation": [w for w in worlds if w.get("stage") == "validation"]} if worlds else {}),
    }


def _photo_looks_before(run_dir: Path, family: str) -> int:
    """The family's `photo_looks_before` in the run's resolved profile (0 when it has none)."""
    import yaml

    path = run_dir / RECIPE_FILE
    recipe = (yaml.safe_load(path.read_text(encoding="utf-8")) or {}) if path.is_file() else {}
    return int(((recipe.get("families") or {}).get(family) or {}).get("photo_looks_before") or 0)


def _real_photos(cache: StageCache, family: str, looks_before: int) -> dict[str, Any] | None:
    real = _finished(cache, f"real-eval/{family}")
    if real is None:
        return None
    from segmin.data.real_sets import DEFAULT_REAL_SET, real_data_root

    keys = ("images", "mean_iou", "mean_precision", "mean_recall", "pooled_iou", "precision", "recall", "threshold")
    # Whether the figures are on segmin's own photos: only then can a report set them beside its own.
    on_shipped = (
        real.get("data") is not None and Path(real["data"]).resolve() == (real_data_root() / DEFAULT_REAL_SET).resolve()
    )
    return {
        **{k: real.get(k) for k in keys},
        "shipped_photos": on_shipped,
        # A test set is worth what its looks left of it: before this run (the record), and this run's one.
        "looks": {"before": looks_before if on_shipped else 0, "this_model": 1},
        "contact_sheet": f"real-eval/{family}/contact_sheet.png",
    }


def _closed_loop(run_dir: Path, cache: StageCache, family: str) -> list[dict[str, Any]]:
    """Per field and method: runs, successes and mean MAE of the family's nav-eval results.

    The MAE is given over all runs and over the successful ones: a run that left the row early has
    a short path whose MAE cannot be compared with a full run's.
    """
    nav = _finished(cache, f"nav-eval/{family}")
    if nav is None:
        return []
    rows = json.loads(_in_run(run_dir, f"nav-eval/{family}", nav["results"]).read_text(encoding="utf-8"))["rows"]
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["field"], row["method"]), []).append(row)
    summary = []
    for (field, method), group in groups.items():
        summary.append(
            {
                "field": field,
                "method": method,
                "runs": len(group),
                "successes": sum(bool(r.get("success")) for r in group),
                "mae": _mean_mae(group),
                "mae_successful": _mean_mae([r for r in group if r.get("success")]),
            }
        )
    return summary


def _mean_mae(rows: list[dict[str, Any]]) -> float | None:
    """Mean of the rows' finite MAEs; None when no row has one."""
    maes = [float(r["mae"]) for r in rows if r.get("mae") is not None and math.isfinite(float(r["mae"]))]
    return sum(maes) / len(maes) if maes else None


def _duration(seconds: float | None) -> str:
    """The training's epochs' time for people (hours from 1.5 h)."""
    if seconds is None:
        return "training time not recorded (no metrics.csv)"
    return f"{seconds / 3600:.1f} h of epochs" if seconds >= 5400 else f"{seconds / 60:.1f} min of epochs"
