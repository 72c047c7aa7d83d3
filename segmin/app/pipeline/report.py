"""The pipeline's final report: report.md, and report.html with every figure embedded.

It gathers what each stage left in its folder (stage records, metrics.csv, export reports,
nav-eval results and figures) so the report can be rebuilt from cached stages alone.
"""

from __future__ import annotations

import base64
import datetime
import math
import re
from pathlib import Path
from typing import Any

from segmin.app.pipeline.cache import StageCache
from segmin.app.pipeline.config import PipelineConfig
from segmin.app.pipeline.stages import load_results, read_metrics_csv
from segmin.common.atomic import atomic_path, write_text
from segmin.common.figures import format_figure


def write_pipeline_report(
    config: PipelineConfig, run_dir: Path, cache: StageCache, log, cards: dict[str, dict[str, Any]]
) -> dict[str, str]:
    """Write run_dir/report.md and run_dir/report.html; returns their paths.

    The report's sections in order, each built by its own function from what the stages left;
    `cards` are the shipped models' cards to set beside the run's (`shipped_cards`, which the
    caller has already hashed into the report stage's inputs).
    """
    families = list(config.families)
    # Every training stage by its label: the family, or family/stage in a chain of fine-tuning stages.
    trainings = {step.key.removeprefix("train/"): step.key for family in families for step in config.run_chain(family)}
    curves = run_dir / "report" / "training_curves.png"
    _training_curves(run_dir, trainings, curves)
    model_results, oracle_results = _nav_eval_results(config, run_dir, families)
    lines = [
        *_title_and_stages(config, cache, families),
        *_rendered_data(config, run_dir, cache),
        *_training(cache, trainings, curves),
        *_export(cache, families),
        "",
        *_real_photos(config, cache, families, cards),
        *_closed_loop(model_results, oracle_results, cards),
        *_figures(run_dir, families),
    ]
    markdown_text = "\n".join(lines) + "\n"
    md_path = run_dir / "report.md"
    write_text(md_path, markdown_text)
    html_path = run_dir / "report.html"
    write_text(html_path, to_html(markdown_text, run_dir, title=f"segmin pipeline report ({config.profile})"))
    log(f"report: {md_path} and {html_path}")
    return {"markdown": str(md_path), "html": str(html_path)}


def _nav_eval_results(config: PipelineConfig, run_dir: Path, families: list[str]) -> tuple[list[Any], list[Any]]:
    """The exported models' closed-loop results (every family's), and the oracle's."""
    model_results = []
    for family in families:
        path = run_dir / "nav-eval" / family / "results.json"
        if path.is_file():
            model_results += load_results(path)
    oracle_path = run_dir / "nav-eval" / "oracle" / "results.json"
    oracle_results = load_results(oracle_path) if config.nav.oracle and oracle_path.is_file() else []
    return model_results, oracle_results


def _title_and_stages(config: PipelineConfig, cache: StageCache, families: list[str]) -> list[str]:
    """Title, date, commit and machine, and the table of stages with their times and input hashes."""
    from segmin.common.machine import machine_summary
    from segmin.common.provenance import git_commit

    lines = [
        f"# segmin pipeline report: `{config.profile}` profile",
        "",
        f"- date: {datetime.datetime.now().strftime('%Y-%m-%d %H:%M')}",
        f"- commit: `{git_commit()}`",
        f"- machine: {machine_summary()}",
        "",
        "## Stages",
        "",
        "| stage | time s | input hash |",
        "|---|---|---|",
    ]
    for key in [
        "render",
        *[step.key for f in families for step in config.run_chain(f)],
        *[f"{s}/{f}" for s in ("export", "real-eval", "nav-eval") for f in families],
        *(["nav-eval/oracle"] if config.nav.oracle else []),
    ]:
        record = cache.record(key)
        if record is not None:
            lines.append(f"| {key} | {record.seconds:.1f} | `{record.input_hash}` |")
    if config.parallel_training:
        lines += [
            "",
            "The families' training stages ran side by side (one process and one thread each): their times overlap.",
        ]
    return lines


def _rendered_data(config: PipelineConfig, run_dir: Path, cache: StageCache) -> list[str]:
    """Section 1: frames rendered per family and split (and per fine-tuning stage), and the contact sheet."""
    lines = ["", "## 1. Data: rendered training worlds", ""]
    render = cache.record("render")
    if render and render.outputs:
        for family, domains in render.outputs["domains"].items():
            counts = {split: count_frames(run_dir / "render" / split, names) for split, names in domains.items()}
            lines.append(
                f"- **{family}**: {counts['train']} training frames from {', '.join(domains['train'])}; "
                f"{counts['val']} validation frames from held-out worlds {', '.join(domains['val'])}"
            )
            sets = (render.outputs.get("training_sets") or {}).get(family, {})
            for step in config.training_chain(family)[1:] if family in config.families else []:
                entry = sets.get(step.name, {"root": step.render_split, "domains": []})
                frames = count_frames(run_dir / "render" / entry["root"], entry["domains"])
                lines.append(
                    f"- **{family}/{step.name}** (fine-tuning stage, from the stage before's checkpoint): {frames} "
                    f"training frames from {', '.join(entry['domains'])}"
                )
        lines += [
            "",
            "RGB | vegetation mask overlay | depth, one row per training world:",
            "",
            "![contact sheet](render/contact_sheet.png)",
            "",
        ]
    return lines


def _training(cache: StageCache, trainings: dict[str, str], curves: Path) -> list[str]:
    """Section 2: one row per training stage ({label: stage key}), and the training curves."""
    lines = [
        "## 2. Training",
        "",
        "| family | epochs | image size | backbone | best val IoU | pixel acc | exported | its val IoU | time s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, key in trainings.items():
        record = cache.record(key)
        if record and record.outputs:
            o = record.outputs
            lines.append(
                f"| {label} | {o['epochs']} | {o['image_size']} | {o['backbone_weights']} | "
                f"{format_figure(o['best_val_iou'])} | {format_figure(o['best_val_pixel_acc'])} | {o.get('kept', 'best')} | "
                f"{format_figure(kept_val_iou(o))} | {record.seconds:.0f} |"
            )
    lines += [
        "",
        "Validation IoU is the crop-class IoU summed over the whole held-out set (the paper reports "
        "IoU on AgriSeg test domains; these are rendered frames). The exported model is the best epoch "
        "(`best`), or with `swa_start_epoch` the average of the last epochs' weights (`swa`).",
        "",
    ]
    lines += _held_out(cache, trainings)
    if curves.is_file():
        lines += ["![training curves](report/training_curves.png)", ""]
    return lines


def _held_out(cache: StageCache, trainings: dict[str, str]) -> list[str]:
    """Each stage's kept model on its held-out validation frames, scored as the real photos are."""
    rows = []
    for label, key in trainings.items():
        record = cache.record(key)
        held = (record.outputs or {}).get("held_out") if record else None
        if held and "target_error_median_px" in held:  # none on a held-out set without frames
            blank = held.get("blank_frames_worst")
            rows.append(
                f"| {label} | {held['images']} | {format_figure(held['pooled_iou'])} | {format_figure(held['mean_iou'])} | "
                f"{held['target_error_median_px']:.1f} | {held['target_error_mean_px']:.1f} | "
                f"{held['targets_outside_corridor']} | {held['targets_at_edge']} | "
                f"{'n/a' if blank is None else f'{blank:.2%}'} |"
            )
    if not rows:
        return []
    return [
        "Held-out validation frames (worlds no stage trains on, seeds of their own), scored as the real photos are: "
        "IoU against the canopy region the model learns, the steering figures (target error in px at 224 px of width, "
        "targets outside the truth's free corridor and at the image edge) and the worst uniform frame painted. "
        "Changes of recipe are judged here, never on the real photos.",
        "",
        "| stage | frames | pooled IoU | mean IoU | target error median px | mean px | outside corridor | at edge | uniform frames |",
        "|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]


def _export(cache: StageCache, families: list[str]) -> list[str]:
    """Section 3: each family's export, its verification against PyTorch and its latency."""
    lines = [
        "## 3. Export (ONNX, verified against PyTorch)",
        "",
        "| family | max abs prob diff | mask agreement | onnxruntime latency median / p95 ms (2 threads) |",
        "|---|---|---|---|",
    ]
    verdicts = []
    for family in families:
        record = cache.record(f"export/{family}")
        if record and record.outputs:
            v, t = record.outputs["verification"], record.outputs["latency_ms"]
            lines.append(
                f"| {family} | {v['max_abs_diff']:.2e} | {100 * v['mask_agreement']:.3f} % | "
                f"{t['median']:.2f} / {t['p95']:.2f} |"
            )
            gate = record.outputs.get("gate")
            if gate:
                shipped = record.outputs["train_stages"][-1].rsplit("/", 1)[-1]
                outcome = (
                    "passes its gate" if gate["passed"] else "fails its gate (" + "; ".join(gate["failures"]) + ")"
                )
                verdicts.append(f"- {family}: the candidate stage `{gate['stage']}` {outcome}; exported: `{shipped}`.")
    if verdicts:
        lines += ["", "Candidate stages, judged on their held-out frames against the stage before them:", "", *verdicts]
    return lines


def _closed_loop(model_results: list[Any], oracle_results: list[Any], cards: dict[str, dict[str, Any]]) -> list[str]:
    """Section 5: Table 3 with the exported models, with the oracle, the shipped models' closed loop
    from their cards, and the comparison with the paper."""
    from segmin.nav_eval.evaluation.report import table3_markdown

    lines = [
        "## 5. Closed loop in the five test fields",
        "",
        "With the exported models (trees model: high trees and pear; vineyards model: the three vineyards). "
        "Ours: mean ± std over runs; the paper's Table 3 value (Gazebo) in brackets.",
        "",
        table3_markdown(model_results) if model_results else "(no results)",
        "",
    ]
    if oracle_results:
        lines += [
            "With the oracle segmenter (the simulator's exact mask), which separates control from perception:",
            "",
            table3_markdown(oracle_results),
            "",
        ]
    loops = {family: card["closed_loop"] for family, card in cards.items() if card.get("closed_loop")}
    if loops:
        lines += [
            "The shipped models of the same families, from their model cards (their release run's fields and runs):",
            "",
            "| model | field | method | successes | MAE m, all runs | MAE m, successful runs |",
            "|---|---|---|---|---|---|",
        ]
        lines += [
            f"| {family} | {r['field']} | {r['method']} | {r['successes']}/{r['runs']} | {format_figure(r['mae'])} "
            f"| {format_figure(r.get('mae_successful'))} |"
            for family, rows in loops.items()
            for r in rows
        ]
        lines.append("")
    return [*lines, "### Comparison with the paper", "", *_comparison(model_results), ""]


def _figures(run_dir: Path, families: list[str]) -> list[str]:
    """Section 6: every family's trajectory and histogram figures."""
    lines = ["## 6. Figures", ""]
    for family in families:
        folder = run_dir / "nav-eval" / family
        for figure in sorted(folder.glob("*_trajectories.png")) + sorted(folder.glob("*_histograms.png")):
            lines += [f"![{figure.stem}]({figure.relative_to(run_dir).as_posix()})", ""]
    return lines


# Known figures on the shipped vineyard photos (data/real/vineyard_rows/README.md).
REAL_REFERENCES = (
    "the SegMin paper's released vineyard model (ImageNet-pretrained, trained on AgriSeg) scores "
    "mean IoU 0.545 (precision 0.67, recall 0.78) with its own preprocessing; the repository's demo "
    "`vineyards.onnx` 0.217 (precision 0.24, recall 0.77)"
)


def shipped_cards(run_dir: Path, families: list[str]) -> dict[str, dict[str, Any]]:
    """The model cards of the shipped models named like the run's families, where this install has
    them and they are not this run's own models (a release run's report after its release).

    Why in a report: what a run just trained is best judged beside what segmin ships for the same
    crop family (`segmin models list`); the figures are the cards' own, nothing is re-measured.
    """
    from segmin.app.pipeline.cache import file_digest
    from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES, shipped_model

    cards = {}
    for family in families:
        entry = shipped_model(family) if family in SHIPPED_NAMES else None
        card = entry.card() if entry is not None and entry.present else None
        exported = run_dir / "export" / family / f"{family}.onnx"
        if card is not None and not (exported.is_file() and file_digest(exported) == card.get("onnx_sha256")):
            cards[family] = card
    return cards


def _real_photos(
    config: PipelineConfig, cache: StageCache, families: list[str], cards: dict[str, dict[str, Any]]
) -> list[str]:
    """Section 4: synthetic validation IoU beside the real-photo figures, per family, with contact
    sheets; on the shipped photos, the shipped models' figures from their cards beside them."""
    lines = ["## 4. Real photos (segmentation, held-out test set)", ""]
    if not config.real_eval.enabled:
        return [*lines, "Disabled in this profile (`real_eval.enabled: false`).", ""]
    records = {f: cache.record(f"real-eval/{f}") for f in families}
    results = {f: r.outputs for f, r in records.items() if r is not None and r.outputs}
    if not results:
        return [*lines, "(no results)", ""]
    first = next(iter(results.values()))
    shipped = config.real_eval.data is None
    lines += [
        f"Every exported model segments the labelled photos in `{first['data']}` "
        f"({first['images']} images"
        + (
            ", the shipped real vineyard rows: Aghi et al. 2021, doi:10.5281/zenodo.4601472, CC BY 4.0"
            if shipped
            else ""
        )
        + "). They are a test set: no stage trains or validates on them. Figures at the photos' own resolution; "
        "precision is n/a when nothing is predicted.",
        "",
        "| family | synthetic val IoU | real mean IoU | real pooled IoU | precision | recall | pixel acc |",
        "|---|---|---|---|---|---|---|",
    ]
    for family, o in results.items():
        train = cache.record(config.run_chain(family)[-1].key)
        val_iou = kept_val_iou(train.outputs) if train and train.outputs else None
        lines.append(
            f"| {family} | {format_figure(val_iou)} | {format_figure(o['mean_iou'])} | {format_figure(o['pooled_iou'])} | "
            f"{format_figure(o['precision'])} | {format_figure(o['recall'])} | {format_figure(o['pixel_accuracy'])} |"
        )
    shipped_rows = {
        f: c["real_photos"] for f, c in cards.items() if shipped and (c.get("real_photos") or {}).get("shipped_photos")
    }
    for family, real in shipped_rows.items():
        lines.append(
            f"| {family}: shipped model | {format_figure(cards[family].get('synthetic_val_iou'))} | {format_figure(real['mean_iou'])} | "
            f"{format_figure(real['pooled_iou'])} | {format_figure(real['precision'])} | {format_figure(real['recall'])} | n/a |"
        )
    lines += ["", *_steering_table(results)]
    if shipped_rows:
        lines += [
            "Rows marked *shipped model*: the models segmin ships under the family's name (`segmin models list`), "
            "from their model cards, on the same photos.",
            "",
        ]
    if shipped:
        lines += [
            "The photos are vineyards: the vineyards model's figure is in-crop, the trees model's is cross-crop "
            "(a model trained on tree rows scored on vine canopy), shown for scale only. "
            f"For reference, {REAL_REFERENCES}.",
            "",
        ]
    lines += [
        "Contact sheets: photo | prediction (green: crop found, red: false crop, blue: missed crop) | ground truth.",
        "",
    ]
    for family, o in results.items():
        if o.get("contact_sheet"):
            lines += [f"![real photos, {family} model](real-eval/{family}/contact_sheet.png)", ""]
    return lines


def _steering_table(results: dict[str, dict[str, Any]]) -> list[str]:
    """Where each model's masks would steer on the photos against the truth's (eval-seg's steering figures)."""
    lines = [
        "Steering on the same photos: the SegMin target (no depth, 224 px of width) of each model mask against the "
        "truth mask's; the free corridor is where the truth's histogram is clearly free (definitions: the metrics "
        "reference of segmin's documentation, docs/reference/metrics.md). Uniform frames: the "
        "largest share of an all-black, all-white or one-colour frame painted as crop (a release model must stay under 1 %).",
        "",
        "| family | target error median (px) | mean (px) | worst (px) | outside the corridor | at the image edge | uniform frames painted |",
        "|---|---|---|---|---|---|---|",
    ]
    for family, o in results.items():
        if "target_error_median_px" not in o:
            continue  # a stage cached before the steering figures existed
        blank = o.get("blank_frames_worst")
        lines.append(
            f"| {family} | {o['target_error_median_px']:.1f} | {o['target_error_mean_px']:.1f} | "
            f"{o['target_error_worst_px']:.1f} | {o['targets_outside_corridor']} of {o['images']} | "
            f"{o['targets_at_edge']} | {'n/a' if blank is None else f'{blank:.2%}'} |"
        )
    return [*lines, ""]


def count_frames(root: Path, domains: list[str]) -> int:
    """Rendered frames of `domains` under a render split folder (the report's and the model cards' counts)."""
    return sum(len(list((root / d).glob("*/images/*/*.png"))) for d in domains)


# What the comparison sets beside the paper's SegMinD figure, in this order: ours of the same
# method, and SegCorridor (not in the paper), the corridor follower that goes beyond it.
COMPARED_METHODS: dict[str, str] = {"segmind": "SegMinD", "segcorridor": "SegCorridor"}


def _comparison(results: list[Any]) -> list[str]:
    """One line per field: the paper's SegMinD MAE, then our SegMinD's and SegCorridor's (those that
    ran) against it, each with how many runs succeeded. SegCorridor has no figure of its own in the
    paper; the paper's best method is the bar it has to clear."""
    from segmin.nav_eval.evaluation.report import PAPER_TABLE3, summarise

    entries = [e for e in summarise(results) if e["method"] in COMPARED_METHODS]
    entries.sort(key=lambda e: list(COMPARED_METHODS).index(e["method"]))
    lines = []
    for field in dict.fromkeys(e["field"] for e in entries):
        paper = PAPER_TABLE3.get((field, "segmind"))
        paper_mae = paper[1] if paper else None
        bar = f"MAE against the paper's SegMinD {paper_mae:.3f} m: " if paper_mae is not None else ""
        figures = [_against_paper(e, paper_mae) for e in entries if e["field"] == field]
        lines.append(f"- {field}: {bar}{'; '.join(figures)}.")
    return lines or ["(no SegMinD or SegCorridor runs)"]


def _against_paper(entry: dict[str, Any], paper_mae: float | None) -> str:
    """One method's mean MAE in a field, lower or higher than the paper's, and its successful runs."""
    mae, _, n = entry["mae"]
    name = COMPARED_METHODS[entry["method"]]
    ok = f"{entry['successes']}/{entry['runs']} runs succeeded"
    if paper_mae is None or not n or not math.isfinite(mae):
        return f"{name}: {ok}"
    verdict = "lower (better)" if mae < paper_mae else "higher (worse)"
    return f"{name} {mae:.3f} m, {verdict}, {ok}"


def _training_curves(run_dir: Path, trainings: dict[str, str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    histories = {label: read_metrics_csv(run_dir / key / "metrics.csv") for label, key in trainings.items()}
    if not any(histories.values()):
        return
    fig, (loss_ax, iou_ax) = plt.subplots(1, 2, figsize=(10, 3.6))
    for family, rows in histories.items():
        epochs = [r["epoch"] for r in rows]
        loss_ax.plot(epochs, [r["train_loss"] for r in rows], marker="o", label=f"{family} train")
        loss_ax.plot(epochs, [r["val_loss"] for r in rows], marker="o", ls="--", label=f"{family} val")
        iou_ax.plot(epochs, [r["val_iou"] for r in rows], marker="o", label=family)
    loss_ax.set(xlabel="epoch", ylabel="BCE loss", title="loss")
    iou_ax.set(xlabel="epoch", ylabel="val IoU (crop)", title="validation IoU on held-out worlds", ylim=(0, 1))
    loss_ax.legend(fontsize=8)
    iou_ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:  # makes the folder
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)


def to_html(markdown_text: str, base: Path, *, title: str) -> str:
    """A self-contained HTML page: markdown rendered, every local image inlined as a data URI."""
    import markdown

    body = markdown.markdown(markdown_text, extensions=["tables"])

    def inline(match: re.Match) -> str:
        src = match.group(1)
        image = base / src
        if not image.is_file():
            return match.group(0)
        data = base64.b64encode(image.read_bytes()).decode("ascii")
        return f'src="data:image/png;base64,{data}"'

    body = re.sub(r'src="([^"]+\.png)"', inline, body)
    style = (
        "body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}"
        "table{border-collapse:collapse;font-size:0.85em;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 6px}"
        "th{background:#f0f0f0}img{max-width:100%}code{background:#f4f4f4}"
    )
    return (
        f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{title}</title><style>{style}</style>"
        f"</head><body>\n{body}\n</body></html>\n"
    )


def kept_val_iou(train_outputs: dict) -> float | None:
    """Validation IoU of the exported checkpoint (stage records from before swa.pt lack the key)."""
    return train_outputs.get("kept_val_iou", train_outputs.get("best_val_iou"))
