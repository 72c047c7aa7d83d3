"""`segmin bench navigator` and `segmin bench model-speed`: the navigators and the robot runtime per
frame, and the segmenter's configurations against the paper's model, on the robot's own computer.

The developers' benches (closed-loop speed, bag replay, the Gymnasium env, the executors) are in the
repository's `benchmarks/` folder, run by `python -m benchmarks`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    nav = bench.add_parser("navigator", help="time Navigator.step per method, and the runtime per frame, on one thread")
    nav.add_argument("--size", type=int, default=224)
    nav.add_argument("--steps", type=int, default=3000)
    nav.add_argument(
        "--model",
        default=None,
        help="ONNX file or shipped model name for the full runtime step (default: an untrained model exported to a temp file, "
        "needs the [train] extra; skipped without it)",
    )
    nav.add_argument("--threads", type=int, default=2, help="onnxruntime threads for the full step (default 2)")
    nav.set_defaults(func=_bench_navigator)
    _register_model_speed(bench)


def _register_model_speed(bench: argparse._SubParsersAction) -> None:
    seg = bench.add_parser(
        "model-speed",
        help="a model's frame-to-mask time per runtime configuration, as a ratio to the paper's TFLite model",
        description=(
            "Time a model from the camera frame to the mask in each runtime configuration (threads, "
            "onnxruntime's thread spinning), each in a fresh process of its own, taking turns for "
            "--rounds rounds, beside the paper's TFLite model fed as the paper's node feeds it "
            "(needs the [litert] extra). Prints each configuration's median, its ratio to the paper's "
            "model at the same thread count, and the load."
        ),
    )
    seg.add_argument("--model", default="vineyards", help="shipped model name or ONNX file (default vineyards)")
    seg.add_argument("--paper", type=Path, default=None, help="the paper's TFLite file (its vineyards or trees model)")
    seg.add_argument(
        "--frame", type=Path, default=None, help="RGB image to segment (default: the shipped model's real photo)"
    )
    seg.add_argument(
        "--litert", type=Path, nargs="+", default=[], help="segmin LiteRT files to time too (the model's fp32 / INT8)"
    )
    seg.add_argument("--threads", type=int, nargs="+", default=[2, 1], help="thread counts (default 2 1)")
    seg.add_argument("--rounds", type=int, default=5, help="turns of every configuration (default 5)")
    seg.add_argument("--runs", type=int, default=300, help="timed frames per turn (default 300)")
    seg.add_argument("--warmup", type=int, default=30, help="untimed frames first in each turn (default 30)")
    seg.add_argument(
        "--busy", type=int, default=0, help="background processes keeping half a core busy each (default 0)"
    )
    seg.add_argument("--json", type=Path, default=None, help="also write the figures to this JSON file")
    seg.set_defaults(func=_bench_model_speed)


def _bench_model_speed(args: argparse.Namespace) -> int:
    from segmin.common.machine import load_average
    from segmin.data.readers import read_image
    from segmin.nav_eval.bench.segmenter_speed import (
        Setup,
        busy_processes,
        camera_frame,
        format_figures,
        run_rounds,
        write_json,
    )
    from segmin.nav_eval.runtime.segmenter import SPIN_DEFAULT, runtime_model_file
    from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES, resolve_model, shipped_model

    for name in ("rounds", "runs"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} {getattr(args, name)}: must be >= 1")
    if args.warmup < 0 or args.busy < 0 or any(t < 1 for t in args.threads):
        raise ValueError("--warmup and --busy must be >= 0, --threads each >= 1")
    for path in [args.paper, *args.litert]:
        if path is not None and not path.is_file():
            raise ValueError(f"{'--paper' if path == args.paper else '--litert'} {path}: no such file")
    model = resolve_model(args.model)
    default_file = runtime_model_file(args.model)  # what the runtime loads for --model
    litert_files = list(dict.fromkeys([*args.litert, *([default_file] if default_file.suffix == ".tflite" else [])]))
    if args.frame is None and args.model not in SHIPPED_NAMES:
        raise ValueError(f"--model {args.model} is a file: --frame must name the image to segment")
    frame_path = args.frame or shipped_model(args.model).onnx.with_suffix(".real.jpg")
    frame = camera_frame(read_image(frame_path))
    setups = []
    for threads in args.threads:
        if args.paper is not None:
            setups.append(Setup("paper", str(args.paper), threads))
        setups += [Setup("onnx", str(model), threads, spin) for spin in (True, False)]
        setups += [Setup("litert", str(path), threads) for path in litert_files]
    print(
        f"{model} on {frame_path} at {frame.shape[1]} x {frame.shape[0]}, {args.busy} busy process(es), {load_average()}"
    )
    with busy_processes(args.busy):
        figures = run_rounds(setups, frame, args.rounds, args.warmup, args.runs)
    default = Setup("litert", str(default_file), 0) if default_file.suffix == ".tflite" else None
    print("\n".join(format_figures(figures, default or Setup("onnx", str(model), 0, SPIN_DEFAULT))))
    print(load_average())
    if args.json is not None:
        write_json(args.json, figures, {k: str(v) for k, v in vars(args).items() if k != "func"})
    return 0


def _bench_navigator(args: argparse.Namespace) -> int:
    from segmin.nav_eval.bench.navigator import bench_navigator, bench_runtime, format_rows, single_thread_environment

    single_thread_environment()
    print(format_rows(bench_navigator(size=args.size, steps=args.steps), args.size))
    print(bench_runtime(size=args.size, steps=args.steps, model=args.model, threads=args.threads))
    return 0
