"""`segmin bench nav-eval` (simulated seconds per wall second), `segmin bench navigator`
(the navigators and the runtime per frame), `segmin bench replay-bag` (bag replay frames/s) and
`segmin bench gym` (the Gymnasium env's steps/s) and `segmin bench executor` (Ray against the local pool)."""

from __future__ import annotations

import argparse
from pathlib import Path

from segmin.common.cli_args import add_overrides, overrides_of
from segmin.nav_eval.evaluation.cli import add_scenario_options


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    b = bench.add_parser("nav-eval", help="simulated seconds per wall-clock second (one worker, ONNX segmenter)")
    b.add_argument(
        "--model",
        default=None,
        help="ONNX file, shipped model name or 'oracle' (default: an untrained model exported to a temporary file)",
    )
    b.add_argument("--field", default="straight_vineyard", help="field to drive (default straight_vineyard)")
    b.add_argument("--method", default="segmind", help="navigator method (default segmind)")
    b.add_argument("--seconds", type=float, default=20.0, help="simulated seconds to drive (default 20)")
    b.add_argument("--threads", type=int, default=1, help="onnxruntime threads (default 1, as with 2 workers)")
    b.add_argument(
        "--matrix",
        action="store_true",
        help="also run the full matrix (5 fields x 3 methods x 3 runs) on --workers and time it",
    )
    b.add_argument("--workers", type=int, default=2, help="workers for --matrix (default 2)")
    b.add_argument(
        "--backends",
        nargs="+",
        default=["tiny", "gl"],
        help="render backends driving the same run in turn (default: tiny gl); --matrix uses the last",
    )
    b.add_argument("--rounds", type=int, default=1, help="turns of every backend (default 1)")
    b.add_argument("--out", type=Path, default=None, help="folder for --matrix outputs (default: a temp folder)")
    add_scenario_options(b)
    b.set_defaults(func=_bench)

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

    bag = bench.add_parser(
        "replay-bag", help="segmin replay --bag against segmin replay on the same frames as folders (frames/s)"
    )
    bag.add_argument("--model", type=Path, required=True, help="exported .onnx file or a shipped model name")
    bag.add_argument("--bag", type=Path, required=True, help="a bag with segmin's camera topics (nav-eval --bag)")
    bag.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    bag.add_argument("--method", default="segmind", choices=("segmin", "segmind", "segzeros"))
    bag.add_argument("--depth-threshold", type=float, default=5.0, help="depth cut in metres (default 5)")
    bag.set_defaults(func=_bench_replay_bag)

    gym = bench.add_parser(
        "gym", help="segmin/RowFollow-v0 env steps/s: single, make_vec sync and async, per observation option"
    )
    gym.add_argument("--field", default="straight_vineyard", help="field to drive (default straight_vineyard)")
    gym.add_argument("--steps", type=int, default=150, help="timed steps per setting (default 150)")
    gym.add_argument("--sizes", type=int, nargs="+", default=[224, 112], help="camera sides, px (default 224 112)")
    gym.add_argument("--num-envs", type=int, nargs="+", default=[1, 2], help="vector sizes (default 1 2)")
    gym.add_argument(
        "--backends",
        nargs="+",
        default=["tiny", "gl"],
        help="render backends, taking turns on each setting (default: tiny gl; ratios against the first)",
    )
    gym.set_defaults(func=_bench_gym)

    ex = bench.add_parser(
        "executor", help="--executor ray against the local pool: a render and a nav-eval, alternately (time ratio)"
    )
    ex.add_argument(
        "--field", default="straight_vineyard", help="field to render and drive (default straight_vineyard)"
    )
    ex.add_argument("--frames", type=int, default=200, help="frames of the render (default 200)")
    ex.add_argument("--size", type=int, default=224, help="render size, px (default 224)")
    ex.add_argument("--runs", type=int, default=15, help="nav-eval runs, over the 3 methods (default 15)")
    ex.add_argument("--workers", type=int, default=2, help="workers of both executors (default 2)")
    ex.add_argument("--rounds", type=int, default=2, help="local/ray rounds, order alternating (default 2)")
    ex.add_argument("--ray-address", default=None, help="Ray cluster (default: RAY_ADDRESS, else a local instance)")
    add_overrides(ex, example="run.length_m=5 (nav config of the nav-eval; default run.length_m=5)")
    ex.set_defaults(func=_bench_executor)


def _bench(args: argparse.Namespace) -> int:
    from segmin.nav_eval.bench.closed_loop import NavEvalBenchOptions, bench_nav_eval
    from segmin.nav_eval.sim.config import load_nav_config

    options = NavEvalBenchOptions(
        config=load_nav_config(args.config, overrides_of(args)),
        model=args.model,
        field=args.field,
        method=args.method,
        seconds=args.seconds,
        threads=args.threads,
        seed=args.seed,
        matrix=args.matrix,
        workers=args.workers,
        out=args.out,
        backends=tuple(args.backends),
        rounds=args.rounds,
    )
    bench_nav_eval(options)
    return 0


def _bench_replay_bag(args: argparse.Namespace) -> int:
    from segmin.nav_eval.bench.replay_bag import bench_replay_bag

    print(bench_replay_bag(args.model, args.bag, args.threads, args.method, args.depth_threshold))
    return 0


def _bench_navigator(args: argparse.Namespace) -> int:
    from segmin.nav_eval.bench.navigator import bench_navigator, bench_runtime, format_rows, single_thread_environment

    single_thread_environment()
    print(format_rows(bench_navigator(size=args.size, steps=args.steps), args.size))
    print(bench_runtime(size=args.size, steps=args.steps, model=args.model, threads=args.threads))
    return 0


def _bench_gym(args: argparse.Namespace) -> int:
    from segmin.nav_eval.bench.gym import bench_gym, format_gym_rows

    if args.steps < 1 or any(s < 8 for s in args.sizes) or any(n < 1 for n in args.num_envs):
        raise ValueError("bench gym: --steps, --num-envs must be >= 1 and --sizes >= 8 px")
    if not args.backends or any(b not in ("tiny", "gl") for b in args.backends):
        raise ValueError(f"bench gym: --backends {' '.join(args.backends)}: each must be one of tiny, gl")
    print(format_gym_rows(bench_gym(args.field, args.sizes, args.steps, args.num_envs, args.backends)))
    return 0


def _bench_executor(args: argparse.Namespace) -> int:
    from segmin.nav_eval.bench.executor import ExecutorBenchOptions, bench_executor

    for name in ("frames", "size", "runs", "workers", "rounds"):
        if getattr(args, name) < 1:
            raise ValueError(f"bench executor: --{name} must be >= 1, got {getattr(args, name)}")
    overrides = tuple(overrides_of(args)) or ExecutorBenchOptions.nav_overrides
    options = ExecutorBenchOptions(
        args.field, args.frames, args.size, args.runs, args.workers, args.rounds, overrides, args.ray_address
    )
    bench_executor(options)
    return 0
