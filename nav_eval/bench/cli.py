"""`segmin bench navigator`: the navigators and the robot runtime per frame, on the robot's own computer.

The developers' benches (closed-loop speed, bag replay, the Gymnasium env, the executors) are in the
repository's `benchmarks/` folder, run by `python -m benchmarks`."""

from __future__ import annotations

import argparse


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


def _bench_navigator(args: argparse.Namespace) -> int:
    from segmin.nav_eval.bench.navigator import bench_navigator, bench_runtime, format_rows, single_thread_environment

    single_thread_environment()
    print(format_rows(bench_navigator(size=args.size, steps=args.steps), args.size))
    print(bench_runtime(size=args.size, steps=args.steps, model=args.model, threads=args.threads))
    return 0
