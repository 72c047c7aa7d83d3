"""The pipeline's stages, in data-flow order: render -> train -> export -> real-eval -> nav-eval -> report.

Each stage function does one family's (or the oracle's) work in its own folder and returns a
small JSON-able dict of outputs for its stage record. Caching and ordering live in
`runner.py`; the work itself is done by the packages (data.synth, train, export, nav_eval).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from segmin.app.pipeline.config import FIRST_STAGE, FamilyPlan, PipelineConfig, TrainStep, ValidationWorld
from segmin.common.config import to_dict
from segmin.common.outputs import make_dirs


def resolve_backbone(config: PipelineConfig, log) -> str:
    """`auto` means ImageNet when its file is cached (and say so), else training from scratch."""
    if config.backbone_weights != "auto":
        return config.backbone_weights
    from segmin.models.lraspp import imagenet_weights_cached, imagenet_weights_path

    if imagenet_weights_cached():
        log(f"using the cached ImageNet backbone weights at {imagenet_weights_path()}")
        return "imagenet"
    log(
        f"no ImageNet backbone file at {imagenet_weights_path()}: families without backbone_weights of their own "
        "train from scratch (backbone_weights=none)"
    )
    return "none"


def output_paths(stage: str, folder: Path, outputs: dict[str, Any]) -> list[Path]:
    """The files and folders a finished stage leaves for the stages after it and the report:
    what its record fingerprints, and what must be unchanged for a rerun to skip it.

    The whole stage folder, except for training: its folder also holds what only training reads
    back (last.pt to resume, logs, previews), and a log appended by a resumed run changes no
    model. There the kept checkpoint and metrics.csv (the report's curves) count; a stage given
    by `start_from` trained nothing and has no metrics.csv. The report
    writes report.md and report.html beside the stage folders.
    """
    if stage == "train":
        return [Path(outputs["checkpoint"]), *([] if outputs.get("kept") == "given" else [folder / "metrics.csv"])]
    if stage == "report":
        return [folder, Path(outputs["markdown"]), Path(outputs["html"])]
    return [folder]


# ------------------------------------------------------------------------------------ render


def world_specs(config: PipelineConfig) -> dict[str, dict[str, Any]]:
    """Every world to render, per family and split, as loaded specs (so YAML edits change the hash).

    A fine-tuning stage's worlds carry their frame count (its own render folder); a held-out
    `validation` world its seed (in the spec) and frame count."""
    from segmin.data.synth.spec import load_world_spec

    specs: dict[str, dict[str, Any]] = {}
    for family, plan in config.families.items():
        for step, frames in rendered_chain(config, family):
            for name in step.worlds:
                spec = to_dict(load_world_spec(name))
                if step.render_split == "train" and step.given is None:
                    specs[f"{family}/train/{name}"] = spec
                else:
                    specs[f"{family}/{step.render_split}/{name}"] = {**spec, "frames": frames}
        for name in plan.val_worlds:
            specs[f"{family}/val/{name}"] = to_dict(load_world_spec(name, _world_overrides(config, name, "val")))
        for entry in plan.validation:
            spec = to_dict(load_world_spec(entry.world, validation_overrides(entry)))
            specs[f"{family}/val/{entry.world}@{entry.seed}"] = {**spec, "frames": entry.frames}
    return specs


def rendered_chain(config: PipelineConfig, family: str) -> list[tuple[TrainStep, int]]:
    """The training stages whose frames this run renders, each with its frames per world.

    Every stage the run trains gets the recipe's count. A stage `start_from` gives trains nothing:
    it gets only the frames its BatchNorm statistics are measured on (`calibration_frames`, spread
    over its worlds), and the stages before it none, since their models were made in another run.
    """
    rendered = []
    for step in config.run_chain(family):
        frames = step.frames_per_world
        if step.given is not None:
            frames = min(frames, math.ceil(step.given.calibration_frames / len(step.worlds)))
        rendered.append((step, frames))
    return rendered


def render_inputs(config: PipelineConfig) -> tuple[Any, ...]:
    """What the rendered frames depend on (the render stage's hash): the render settings, every
    world's spec and each family's frames per training world."""
    family_frames = {family: plan.frames_per_world for family, plan in config.families.items()}
    return to_dict(config.render), world_specs(config), family_frames


def _world_overrides(config: PipelineConfig, name: str, split: str) -> list[str]:
    """Validation worlds are the same kind of field grown from another seed, under their own domain."""
    if split == "train":
        return []
    seed, stem = _seed_and_stem(name)
    return [f"seed={seed + config.render.val_seed_offset}", f"domain=synth_val_{stem}"]


def validation_overrides(entry: ValidationWorld) -> list[str]:
    """A held-out world grown from its own seed, under a domain that names world and seed."""
    _, stem = _seed_and_stem(entry.world)
    return [f"seed={entry.seed}", f"domain=synth_val_{stem}_{entry.seed}"]


def _seed_and_stem(world: str) -> tuple[int, str]:
    """A world's own seed and its name without `train_` (the stem of its validation domain)."""
    from segmin.data.synth.spec import load_world_spec

    base = load_world_spec(world)
    return base.seed, base.name.removeprefix("train_")


def _render_jobs(
    config: PipelineConfig, family: str, plan: FamilyPlan
) -> list[tuple[str, str | None, str, int, list[str]]]:
    """(render folder, training stage or None for validation, world, frames, spec overrides) of
    every world the family renders: each training stage's, then the validation worlds."""
    jobs: list[tuple[str, str | None, str, int, list[str]]] = [
        (step.render_split, step.name, name, frames, [])
        for step, frames in rendered_chain(config, family)
        for name in step.worlds
    ]
    jobs += [
        ("val", None, name, config.render.val_frames_per_world, _world_overrides(config, name, "val"))
        for name in plan.val_worlds
    ]
    jobs += [("val", None, v.world, v.frames, validation_overrides(v)) for v in plan.validation]
    return jobs


def render_stage(config: PipelineConfig, folder: Path, *, overwrite: bool, log) -> dict[str, Any]:
    """Render training and held-out validation frames in the AgriSeg layout, plus a contact sheet.

    Outputs: `domains` (per family, the first training stage's and the validation domains),
    `training_sets` (per family and training stage, its render folder and domains) and `worlds`
    (per family, every rendered world with its stage, seed and frame count: the model cards' data).
    """
    from segmin.data.synth.camera import CameraModel
    from segmin.data.synth.spec import load_world_spec
    from segmin.data.synth.writer import RenderJob, render_dataset

    camera = CameraModel(width=config.render.size, height=config.render.size)
    outputs: dict[str, Any] = {"domains": {}, "training_sets": {}, "worlds": {}}
    for family, plan in config.families.items():
        sets: dict[str, dict[str, Any]] = {
            step.name: {"root": step.render_split, "domains": []} for step, _ in rendered_chain(config, family)
        }
        val_domains: list[str] = []
        worlds: list[dict[str, Any]] = []
        for split, stage, name, frames, overrides in _render_jobs(config, family, plan):
            spec = load_world_spec(name, overrides)
            log(
                f"render: {family} {stage or 'validation'} world {name} ({spec.domain}, seed {spec.seed}), {frames} frames"
            )
            job = RenderJob(
                spec=spec,
                out=folder / split,
                frames=frames,
                camera=camera,
                workers=config.render.workers,
                overwrite=overwrite,
                executor=config.fan_out(),
            )
            render_dataset(job)
            (val_domains if stage is None else sets[stage]["domains"]).append(spec.domain)
            worlds.append(
                {
                    "stage": stage or "validation",
                    "world": name,
                    "domain": spec.domain,
                    "seed": spec.seed,
                    "frames": frames,
                }
            )
        first = sets.get(FIRST_STAGE, {"domains": []})  # none when `start_from` gives a later stage
        outputs["domains"][family] = {"train": first["domains"], "val": val_domains}
        outputs["training_sets"][family] = sets
        outputs["worlds"][family] = worlds
    sheet = folder / "contact_sheet.png"
    _contact_sheet(config, camera, sheet)
    outputs["contact_sheet"] = str(sheet)
    return outputs


def _contact_sheet(config: PipelineConfig, camera, path: Path) -> None:
    import cv2

    from segmin.common.atomic import write_bytes
    from segmin.data.synth.cli import preview_sheet

    worlds = list(dict.fromkeys(w for family in config.families for w in config.training_chain(family)[-1].worlds))
    sheet = preview_sheet(worlds, config.render.contact_sheet_frames, camera)
    ok, png = cv2.imencode(".png", sheet[:, :, ::-1])
    if not ok:
        raise RuntimeError(f"{path}: PNG encoding failed")
    write_bytes(path, png.tobytes())


# ------------------------------------------------------------------------------------- train


def train_config_for(
    config: PipelineConfig,
    family: str,
    plan: FamilyPlan,
    render_dir: Path,
    domains: dict[str, list[str]],
    backbone: str,
    step: TrainStep | None = None,
    init: str | None = None,
):
    """The family's training config for one training stage (`step`, default its first), pointed at
    this run's rendered frames. A fine-tuning stage starts from `init`, the previous stage's kept
    checkpoint: set after every override, so the chain cannot be broken by one."""
    from segmin.train.config import load_train_config

    overrides = [
        f"family={family}",
        f"data.root={render_dir / (step.render_split if step is not None else 'train')}",
        f"data.val_root={render_dir / 'val'}",
        f"data.domains=[{', '.join(domains['train'])}]",
        f"data.val_domains=[{', '.join(domains['val'])}]",
        f"backbone_weights={backbone}",
        # Side by side, each training gets one core's thread (a family's own override still wins).
        *(["threads=1"] if config.parallel_training else []),
        *plan.train_overrides,
        *(step.overrides if step is not None else ()),
        *([f"backbone_weights={init}"] if init is not None else []),
        # The profile's seed last: a spread run's train_seed=N must not lose to a family's own.
        *([f"seed={config.train_seed}"] if config.train_seed is not None else []),
    ]
    train_config = load_train_config(plan.train_config, overrides)
    if config.real_eval.data is not None:  # data/real itself is refused by the training config
        from segmin.data.real_sets import check_not_real_data

        check_not_real_data(
            f"family {family}",
            extra=[config.real_eval.data],
            paths={"data.root": train_config.data.root, "data.val_root": train_config.data.val_root},
        )
    return train_config


def check_keep(step: TrainStep, train_config, where: str) -> None:
    """The stage's declared model-choice rule is what its training config does (swa.pt exactly
    when weight averaging is on): the rule is written before training and cannot drift."""
    if step.keep is None:
        return
    averages = train_config.swa_start_epoch is not None
    if (step.keep == "swa") != averages:
        need = "set swa_start_epoch" if step.keep == "swa" else "leave swa_start_epoch unset"
        raise ValueError(f"{where}: keep is {step.keep!r}, so its training must {need}")


def train_stage(train_config, folder: Path, *, resume: bool, log) -> dict[str, Any]:
    """Train one family; `resume` continues from the folder's last checkpoint.

    The stage folder belongs to the pipeline: a stage that is not resumed is rerun because its
    inputs changed (or --from), so earlier outputs there are replaced (force).
    """
    from segmin.common.machine import machine_summary
    from segmin.models.checkpoint import read_checkpoint
    from segmin.train.run import train_model

    log(
        f"train: {train_config.family} for {train_config.epochs} epochs at {train_config.image_size} px "
        f"(backbone {train_config.backbone_weights}){', resuming' if resume else ''}"
    )
    kept = train_model(train_config, folder, resume=resume, force=not resume)
    history = read_metrics_csv(folder / "metrics.csv")
    best_row = max(history, key=lambda r: r.get("val_iou", -1.0)) if history else {}
    # The exported model: best.pt, or swa.pt (weight average) whose validation is not an epoch row.
    kept_metrics = read_checkpoint(kept)["metrics"]
    held_out = held_out_eval(train_config, kept, folder / "held-out", log)
    return {
        "checkpoint": str(kept),
        "epochs": len(history),
        "best_val_iou": best_row.get("val_iou"),
        "best_val_pixel_acc": best_row.get("val_pixel_acc", best_row.get("val_acc")),
        "kept": kept.stem,
        "kept_val_iou": kept_metrics.get("val_iou"),
        "backbone_weights": train_config.backbone_weights,
        "image_size": train_config.image_size,
        "architecture": train_config.architecture,
        "seed": train_config.seed,
        "held_out": held_out,
        "machine": machine_summary(),  # for the model card: training time means little without it
    }


def held_out_eval(train_config, checkpoint: Path, folder: Path, log) -> dict[str, Any] | None:
    """The kept checkpoint scored like the real photos on the stage's held-out validation frames.

    IoU against the canopy region the model learns (`data.label_closing`), and the steering
    figures: the rendered stand-in for the photos, on which a change of recipe is judged (the
    photos are a test set). None when the stage validates on a split of its training worlds.
    """
    from segmin.data.agriseg_loader import find_frames
    from segmin.nav_eval.seg_eval.predictor import load_predictor
    from segmin.nav_eval.seg_eval.results import write_results
    from segmin.nav_eval.seg_eval.score import evaluate
    from segmin.nav_eval.seg_eval.summary import json_safe

    data = train_config.data
    if data.val_root is None or not data.val_domains:
        return None
    frames = [f for f in find_frames(data.val_root) if f.domain in data.val_domains]
    log(f"held-out: {checkpoint.name} on {len(frames)} frames of {', '.join(data.val_domains)}")
    predictor = load_predictor(checkpoint, size=train_config.image_size)
    summary, sheet = evaluate(predictor, frames, data.val_root, truth_closing=data.label_closing)
    write_results(summary, sheet, folder, force=True)  # the stage folder is the cache's own
    return json_safe(summary.figures())


def train_stage_logged(train_config, folder: Path, resume: bool) -> dict[str, Any]:
    """`train_stage` in a process of its own (trainings side by side): its output, progress bars
    included, goes to `folder/train.log` instead of a terminal the processes would share."""
    import contextlib

    from segmin.common.console_log import show_progress

    make_dirs(folder)
    with (
        open(folder / "train.log", "a" if resume else "w", buffering=1) as handle,
        contextlib.redirect_stdout(handle),
        contextlib.redirect_stderr(handle),
    ):
        show_progress()  # a process of its own: training's progress lines go to the log as in a command
        return train_stage(train_config, folder, resume=resume, log=print)


def read_metrics_csv(path: Path) -> list[dict[str, float]]:
    """train/'s metrics.csv as a list of numeric rows (empty when there is none yet)."""
    import csv

    if not path.is_file():
        return []
    rows = []
    with open(path, newline="") as handle:
        for raw in csv.DictReader(handle):
            row = {}
            for key, value in raw.items():
                try:
                    row[key] = float(value)
                except (TypeError, ValueError):
                    continue
            rows.append(row)
    return rows


# ------------------------------------------------------------------------------------ export


def export_stage(config: PipelineConfig, checkpoint: Path, out: Path, val_root: Path, log) -> dict[str, Any]:
    """Export and verify one family's ONNX model, then time it with the runtime the robot uses."""
    from segmin.export.pipeline import ExportOptions, export_checkpoint

    log(f"export: {checkpoint} -> {out}")
    report = export_checkpoint(
        ExportOptions(
            checkpoint=checkpoint,
            out=out,
            force=True,
            exporter=config.export.exporter,
            verify_frames=config.export.verify_frames,
            fp16=config.export.fp16,
            int8=config.export.int8,
        )
    )
    verification = report["fp32"]["verification_vs_torch"]
    latency = onnx_latency_ms(out, val_root, config.export.latency_frames)
    return {"onnx": str(out), "verification": verification, "latency_ms": latency, "input_size": report["input_size"]}


def litert_stage(config: PipelineConfig, checkpoint: Path, out: Path, log) -> dict[str, Any]:
    """Export and verify one family's LiteRT file (`export.formats` has tflite), INT8 too when `export.int8`."""
    from segmin.export.pipeline import ExportOptions, export_checkpoint

    log(f"export: {checkpoint} -> {out}")
    report = export_checkpoint(
        ExportOptions(
            checkpoint=checkpoint,
            out=out,
            force=True,
            format="tflite",
            verify_frames=config.export.verify_frames,
            int8=config.export.int8,
        )
    )
    outputs = {"litert": str(out), "verification": report["fp32"]["verification_vs_torch"]}
    if "int8" in report:
        outputs["litert_int8"] = report["int8"]["path"]
    return outputs


def onnx_latency_ms(model: Path, frames_root: Path, count: int, threads: int = 2) -> dict[str, Any]:
    """Median and p95 of one `OnnxSegmenter.segment` call on rendered validation frames."""
    from segmin.common.timing import time_calls
    from segmin.data.readers import read_image
    from segmin.nav_eval.runtime.segmenter import OnnxSegmenter

    paths = sorted(frames_root.rglob("images/*/*.png"))[:count]
    if not paths:
        raise FileNotFoundError(f"{frames_root}: no rendered images to time the model on")
    images = [read_image(p) for p in paths]
    segmenter = OnnxSegmenter(model, threads=threads)
    times = time_calls(segmenter.segment, runs=len(images), warmup=min(3, len(images)), inputs=images) * 1e3
    return {
        "median": float(np.median(times)),
        "p95": float(np.percentile(times, 95)),
        "threads": threads,
        "frames": len(times),
        "frame_size": list(images[0].shape[:2]),
    }


# --------------------------------------------------------------------------------- real-eval


def dataset_fingerprint(root: Path) -> list[tuple[str, int]]:
    """(relative path, size) of every file under `root`: edits to the photo set change the stage hash."""
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: real_eval.data folder not found")
    return [(p.relative_to(root).as_posix(), p.stat().st_size) for p in sorted(root.rglob("*")) if p.is_file()]


def real_eval_stage(config: PipelineConfig, model: Path, folder: Path, log) -> dict[str, Any]:
    """Score one family's ONNX on the real photos; results and contact sheet go in the stage folder."""
    from segmin.nav_eval.seg_eval.results import write_results
    from segmin.nav_eval.seg_eval.score import evaluate_model
    from segmin.nav_eval.seg_eval.summary import json_safe

    data = config.real_eval.resolved_data()
    log(f"real-eval: {model} on {data}")
    summary, sheet = evaluate_model(model, data)
    paths = write_results(summary, sheet, folder, force=True)  # the stage folder is the cache's own
    return {"data": str(data), "threshold": summary.threshold, **json_safe(summary.figures()), **paths}


# ---------------------------------------------------------------------------------- nav-eval


def nav_config(config: PipelineConfig):
    from segmin.nav_eval.sim.config import load_nav_config

    return load_nav_config(config.nav.config, config.nav.overrides)


def nav_stage(config: PipelineConfig, model: str, fields: list[str], folder: Path, log) -> dict[str, Any]:
    """Drive every method through `fields` with `model` (an ONNX path or 'oracle')."""
    from segmin.nav_eval.evaluation.evaluate import raise_for_errors, run_evaluation

    methods = config.nav.methods_for(model)
    log(f"nav-eval: {model} on {', '.join(fields)} with {', '.join(methods)}, {config.nav.runs} run(s) each")
    results = run_evaluation(
        model,
        fields=fields,
        methods=methods,
        runs=config.nav.runs,
        out_dir=folder,
        workers=config.nav.workers,
        config=nav_config(config),
        seed=config.nav.seed,
        video=config.nav.video,
        executor=config.fan_out(),
    )
    raise_for_errors(results, f"nav-eval in {folder}")  # never cache a stage whose runs raised
    successes = sum(bool(r.success) for r in results)
    return {"results": str(folder / "results.json"), "runs": len(results), "successes": successes}


def load_results(path: Path) -> list[Any]:
    """RunResult objects back from a results.json (for a report over cached stages)."""
    import json

    from segmin.nav_eval.evaluation.records import RunResult

    rows = json.loads(path.read_text())["rows"]
    return [RunResult.from_row({k: (math.nan if v is None else v) for k, v in row.items()}) for row in rows]
