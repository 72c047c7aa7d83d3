"""checkpoint -> verified ONNX or LiteRT file (+ optional fp16 / INT8 variants) and a JSON export report.

Every file is written through `segmin.common.atomic.atomic_path`: the graph is exported, stamped with
metadata and verified inside the temporary file, and only a file that passed is renamed to its
final name. A failed check therefore leaves no new file behind (with `force`, a previous file of
the same name stays as it was: a failed export never destroys the last good model). Existing
outputs are never overwritten without `force`.
"""

from __future__ import annotations

import ast
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from segmin.common.atomic import atomic_path, write_json
from segmin.common.outputs import check_output_file
from segmin.export import metadata as md
from segmin.export import quantize as quant
from segmin.export.onnx import (
    DEFAULT_OPSET,
    EXPORTERS,
    DeployWrapper,
    build_metadata,
    check_graph_io,
    drop_node_metadata,
    export_graph,
    set_metadata,
)
from segmin.export.verify import (
    MAX_ABS_DIFF,
    MIN_MASK_AGREEMENT,
    Agreement,
    VerificationError,
    check_bounds,
    load_frames,
    make_session,
    run_session,
    torch_reference,
    verify_against_torch,
)

log = logging.getLogger(__name__)

# `format` -> the output file's suffix (ONNX for onnxruntime / TensorRT, LiteRT for XNNPACK / Coral-class targets).
FORMATS = {"onnx": ".onnx", "tflite": ".tflite"}


class OutputExistsError(ValueError):
    """An output file exists and `force` was not given."""


@dataclass(frozen=True)
class ExportOptions:
    """Everything `segmin export` takes (see segmin/app/export_cli.py for the user-facing help)."""

    checkpoint: Path
    out: Path
    calib_data: Path | None = None
    fp16: bool = False
    int8: bool = False
    force: bool = False
    opset: int | None = None
    exporter: str | None = None  # ONNX only; None: "dynamo"
    format: str = "onnx"
    verify_frames: int = 32
    calib_frames: int = 32
    threads: int = 2
    max_abs_diff: float = MAX_ABS_DIFF
    min_agreement: float = MIN_MASK_AGREEMENT

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise ValueError(f"format={self.format!r}: expected one of {', '.join(FORMATS)}")
        if self.format == "onnx":
            object.__setattr__(self, "exporter", self.exporter or "dynamo")
            if self.exporter not in EXPORTERS:
                raise ValueError(f"exporter={self.exporter!r}: expected one of {', '.join(EXPORTERS)}")
        else:
            given = [
                flag for flag, value in (("--exporter", self.exporter), ("--opset", self.opset)) if value is not None
            ]
            if self.fp16:
                given.append("--fp16")
            if given:
                raise ValueError(f"{', '.join(given)}: ONNX options, not used with --format {self.format}")
        for name in ("verify_frames", "calib_frames", "threads"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        suffix = FORMATS[self.format]
        if Path(self.out).suffix.lower() != suffix:
            raise ValueError(f"--out {self.out}: the output file name must end in {suffix} (--format {self.format})")


def variant_path(out: str | Path, tag: str) -> Path:
    """model.onnx -> model.fp16.onnx / model.int8.onnx (model.tflite -> model.int8.tflite)."""
    out = Path(out)
    return out.with_name(f"{out.stem}.{tag}{out.suffix}")


def report_path(out: str | Path) -> Path:
    """model.onnx -> model.export.json."""
    out = Path(out)
    return out.with_name(f"{out.stem}.export.json")


def planned_outputs(options: ExportOptions) -> list[Path]:
    outputs = [Path(options.out), report_path(options.out)]
    if options.fp16:
        outputs.append(variant_path(options.out, "fp16"))
    if options.int8:
        outputs.append(variant_path(options.out, "int8"))
    return outputs


def parse_train_data(text: str) -> tuple[Path, list[str] | None]:
    """The training data root and domains from model_info["train_data"].

    train/ records it as "<root> domains=<list or 'all'>[; val ...]"; a bare path also works.
    """
    head = str(text).split(";")[0].strip()
    root_text, _, domains_text = head.partition(" domains=")
    domains: list[str] | None = None
    domains_text = domains_text.strip()
    if domains_text and domains_text != "all":
        try:
            parsed = ast.literal_eval(domains_text)
        except (ValueError, SyntaxError):
            parsed = domains_text
        domains = [parsed] if isinstance(parsed, str) else [str(d) for d in parsed]
    return Path(root_text.strip()), domains


def _frame_source(options: ExportOptions, model_info: dict[str, Any]) -> tuple[Path, list[str] | None]:
    if options.calib_data is not None:
        return Path(options.calib_data), None
    train_data = str(model_info.get("train_data") or "")
    root, domains = parse_train_data(train_data)
    if train_data and root.is_dir():
        return root, domains
    raise ValueError(
        f"{options.checkpoint}: no real frames to verify the export on: its training data "
        f"{train_data!r} is not a folder here; pass --calib-data DIR (images or an AgriSeg root)"
    )


def _stamp(path: Path, meta: dict[str, str]) -> None:
    import onnx

    model = onnx.load(str(path))
    set_metadata(model, meta)
    onnx.save(model, str(path))


def export_checkpoint(options: ExportOptions) -> dict[str, Any]:
    """Run the whole export; returns the report (also written to model.export.json).

    checkpoint -> real frames -> fp32 graph (verified against PyTorch) -> fp16 / INT8 variants
    (compared with the fp32 graph) -> report.
    """
    _refuse_existing_outputs(options)
    model, info, carried, checkpoint_file = _load_source(options)
    input_size = tuple(int(v) for v in info["input_size"])
    threshold = float(info.get("threshold", 0.5))
    source, domains = _frame_source(options, info)
    frames = load_frames(
        source,
        input_size,
        limit=max(options.verify_frames, options.calib_frames if options.int8 else 1),
        domains=domains,
    )
    if options.int8:
        _check_calibration_frames(len(frames), options.calib_frames, source)
    verify_set = spread(frames, options.verify_frames)
    opset: int | None = None
    if options.format == "tflite":
        from segmin.export.litert import converter_name

        exporter, file_format = converter_name(), md.FORMAT_LITERT
    else:
        exporter, file_format = str(options.exporter), md.FORMAT
        opset = int(options.opset if options.opset is not None else DEFAULT_OPSET[exporter])
    meta = build_metadata(
        info,
        input_size=input_size,
        exporter=exporter,
        opset=opset,
        checkpoint=checkpoint_file,
        file_format=file_format,
    )
    meta.update(carried)
    report: dict[str, Any] = {
        "checkpoint": str(options.checkpoint),
        "frames_from": str(source),
        "frames_domains": domains,
        "frames_used": len(frames),
        "input_size": list(input_size),
        "threshold": threshold,
        "metadata": meta,
        "bounds": {"max_abs_diff": options.max_abs_diff, "min_mask_agreement": options.min_agreement},
    }
    out = Path(options.out)
    if options.format == "tflite":
        from segmin.export.litert import export_litert

        calib_set = spread(frames, options.calib_frames) if options.int8 else None
        int8_path = variant_path(out, "int8")
        report.update(export_litert(options, int8_path, model, meta, verify_set, calib_set, threshold, input_size))
        _remove_stale_variants(options)
        write_json(report_path(out), report)
        return report
    agreement = _export_verified_fp32(options, model, meta, verify_set, threshold, input_size, int(meta[md.KEY_OPSET]))
    report["fp32"] = {"path": str(out), "verification_vs_torch": agreement.as_dict()}
    log.info("wrote %s (verified: %s)", out, agreement.summary())
    _remove_stale_variants(options)
    fp32_probs = run_session(make_session(out, threads=options.threads), verify_set)
    if options.fp16:
        report["fp16"] = _export_fp16(out, meta, fp32_probs, verify_set, threshold)
    if options.int8:
        calib_set = spread(frames, options.calib_frames)
        report["int8"] = _export_int8(out, meta, fp32_probs, calib_set, verify_set, threshold, options.threads)
    write_json(report_path(out), report)
    return report


def _load_source(options: ExportOptions) -> tuple[Any, dict[str, Any], dict[str, str], Path]:
    """(network, model_info, metadata carried over, the source file) of `options.checkpoint`.

    A segmin checkpoint is read as it is. A segmin fp32 ONNX file (a shipped model: those exist
    only as ONNX; `segmin export --checkpoint NAME` passes its file) is converted back to PyTorch first
    (`export.to_torch`), its BatchNorm statistics measured on --calib-data, and its card carried over.
    """
    from segmin.models.checkpoint import load_model

    source = Path(options.checkpoint)
    if source.suffix.lower() != ".onnx":
        model, info = load_model(source)
        return model, info, {}, source
    from segmin.export.to_torch import model_from_onnx

    if options.calib_data is None:
        raise ValueError(
            f"--checkpoint {source}: an ONNX model; pass --calib-data DIR (frames of its crop) to measure its "
            "BatchNorm statistics and verify the export on"
        )
    if not source.is_file():
        raise FileNotFoundError(f"--checkpoint {source}: ONNX model not found")
    model, info, props = model_from_onnx(source, Path(options.calib_data))
    carried = {key: props[key] for key in (md.KEY_MODEL_CARD, md.KEY_MODEL_CARD_JSON) if key in props}
    return model, info, carried, source


def _refuse_existing_outputs(options: ExportOptions) -> None:
    """Every output must be writable, and none may exist unless `force` says to replace it."""
    for planned in planned_outputs(options):
        check_output_file(planned, "--out")
    existing = [str(p) for p in planned_outputs(options) if p.exists()]
    if existing and not options.force:
        raise OutputExistsError(f"{', '.join(existing)}: already exists; pass --force to overwrite")


def _export_verified_fp32(
    options: ExportOptions,
    model,
    meta: dict[str, str],
    verify_set: np.ndarray,
    threshold: float,
    input_size: tuple[int, ...],
    opset: int,
) -> Agreement:
    """Export, stamp and verify the fp32 graph inside a temporary file, renamed to `options.out`
    only when it matches PyTorch within the bounds; returns the agreement."""
    import onnx

    out = Path(options.out)
    wrapper = DeployWrapper(model).eval()
    with atomic_path(out) as tmp:
        export_graph(model, tmp, input_size=input_size, exporter=str(options.exporter), opset=opset)
        graph = onnx.load(str(tmp))
        check_graph_io(graph, input_size, str(out))
        drop_node_metadata(graph)
        set_metadata(graph, meta)
        onnx.save(graph, str(tmp))
        del graph
        try:
            agreement = verify_against_torch(
                tmp,
                torch_reference(wrapper),
                verify_set,
                threshold,
                max_abs_diff=options.max_abs_diff,
                min_agreement=options.min_agreement,
                threads=options.threads,
            )
        except VerificationError as exc:
            kept = " (the existing file was left unchanged)" if out.exists() else ""
            raise VerificationError(f"{out}: export failed verification, no file written{kept}: {exc}") from exc
        _stamp(tmp, {"verification": agreement.summary()})
    return agreement


def _remove_stale_variants(options: ExportOptions) -> None:
    """fp16 / INT8 files not asked for this time were built from the fp32 file being replaced."""
    out = Path(options.out)
    for tag, wanted in (("fp16", options.fp16), ("int8", options.int8)):
        stale = variant_path(out, tag)
        if not wanted and stale.exists():
            stale.unlink()
            log.info("removed %s (a variant of the previous %s)", stale, out.name)


def spread(frames: np.ndarray, count: int) -> np.ndarray:
    """At most `count` of `frames`, evenly spaced (all of them when there are not more)."""
    return frames[np.linspace(0, len(frames) - 1, min(len(frames), count)).round().astype(int)]


def _check_calibration_frames(found: int, wanted: int, source: Path) -> None:
    """INT8 ranges come from the calibration frames alone: on a fraction of the frames asked for,
    the activation ranges miss what the others hold, and the mask IoU measured on the same few
    frames cannot show it. Refused before any file is written; asking for fewer is the user's call."""
    if found < wanted:
        raise ValueError(
            f"--calib-frames {wanted}: only {found} frame(s) found in {source} for INT8 calibration; "
            f"add frames there (or pick another --calib-data), or pass --calib-frames {found} to calibrate on them"
        )


def _export_fp16(out: Path, meta: dict[str, str], fp32_probs, frames, threshold: float) -> dict[str, Any]:
    path = variant_path(out, "fp16")
    with atomic_path(path) as tmp:
        quant.convert_fp16(out, tmp)
        agreement = quant.compare_with_fp32(tmp, fp32_probs, frames, threshold)
        check_bounds(agreement, str(path), max_abs_diff=quant.FP16_MAX_ABS_DIFF, min_agreement=quant.FP16_MIN_AGREEMENT)
        _stamp(tmp, {**meta, md.KEY_PRECISION: "fp16", "verification": "vs fp32: " + agreement.summary()})
    return {"path": str(path), "vs_fp32": agreement.as_dict()}


def _export_int8(
    out: Path, meta: dict[str, str], fp32_probs, calib, frames, threshold: float, threads: int
) -> dict[str, Any]:
    path = variant_path(out, "int8")
    with atomic_path(path) as tmp:
        quant.quantize_int8(out, tmp, calib)
        agreement = quant.compare_with_fp32(tmp, fp32_probs, frames, threshold)
        _stamp(tmp, {**meta, md.KEY_PRECISION: "int8", "verification": "vs fp32: " + agreement.summary()})
        latency = quant.interleaved_latency({"fp32": out, "int8": tmp}, frames[:1], threads=threads, runs=30)
    return {"path": str(path), **quant.int8_report(agreement, latency, len(calib))}
