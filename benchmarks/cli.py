"""The developers' benchmarks: `python -m benchmarks TARGET [flags]` from the repository root.

These time how segmin is built (rendering, training, export, the closed loop, bag replay, the
Gymnasium env, the executors) and guard its speed targets; a robot team does not need them, so they
live outside the wheel. The benches a team runs on its own hardware stay in `segmin bench`
(model-speed: its model against the paper's; navigator; ros2). Every target prints its figures and, where it has them, its
targets' verdicts; errors read as the `segmin` command's (one line, exit 2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from segmin.app.cli import run_command
from segmin.common.cli_args import CommandParser, add_overrides, overrides_of
from segmin.data.synth.cli import camera_from_size
from segmin.nav_eval.evaluation.cli import add_scenario_options


def build_parser() -> argparse.ArgumentParser:
    """Every benchmark target under one parser (used by `main` and by the tests of every `--help`)."""
    parser = CommandParser(prog="python -m benchmarks", description=__doc__.split("\n\n")[0].strip('"'))
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    bench = parser.add_subparsers(dest="bench_target", metavar="TARGET", required=True)
    _register_data(bench)
    _register_train(bench)
    _register_export(bench)
    _register_architectures(bench)
    _register_litert(bench)
    _register_closed_loop(bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments and run the chosen benchmark; user errors print one line and return 2."""
    return run_command(build_parser().parse_args(argv), prog="benchmarks")


def _register_data(bench: argparse._SubParsersAction) -> None:
    b = bench.add_parser("synth", help="frames/s written per test field (1 and 2 workers); 20 m vs 200 m rows")
    b.add_argument("--frames", type=int, default=120, help="frames per measurement (default 120)")
    b.add_argument("--fields", nargs="+", default=None, help="worlds to measure (default: the five test fields)")
    b.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts (default 1 2)")
    b.add_argument("--size", default="224", help="frame size W or WxH (default 224)")
    b.add_argument(
        "--backends", nargs="+", default=["tiny", "gl"], help="render backends, in turn per world (default tiny gl)"
    )
    b.set_defaults(func=_bench_synth)

    a = bench.add_parser(
        "render-agreement", help="the gl render backend against TinyRenderer: mask IoU, depth error, speed"
    )
    a.add_argument("--poses", type=int, default=8, help="poses along each field's evaluation gap (default 8)")
    a.add_argument("--fields", nargs="+", default=None, help="worlds to compare (default: the five test fields)")
    a.add_argument("--size", default="224", help="frame size W or WxH (default 224)")
    a.add_argument("--sheet", type=Path, default=None, help="PNG file for the side-by-side frames (one row a field)")
    a.add_argument("--force", action="store_true", help="overwrite an existing --sheet")
    a.add_argument(
        "--sun-distance",
        type=float,
        default=None,
        help="metres from the world origin to the sun of the shadow figures (default 40: within the "
        "camera's far plane; the worlds' own 100 m sun casts no shadow in either backend)",
    )
    a.set_defaults(func=_bench_agreement)


def _register_train(bench: argparse._SubParsersAction) -> None:
    b = bench.add_parser("train", help="training images/s: full data pipeline vs the model step alone")
    b.add_argument("--root", type=Path, default=None, help="dataset root (default: a generated 320x240 PNG set)")
    b.add_argument("--size", type=int, default=224)
    b.add_argument("--batch", type=int, default=8)
    b.add_argument("--threads", type=int, default=2)
    b.add_argument("--workers", type=int, default=1)
    b.add_argument("--steps", type=int, default=6)
    b.add_argument("--repeats", type=int, default=2)
    b.add_argument("--device", default="cpu")
    b.set_defaults(func=_bench_train)

    bound = bench.add_parser(
        "iou-bound", help="estimated crop-IoU ceiling that LR-ASPP's 1/8-resolution output puts on a dataset's masks"
    )
    bound.add_argument("--root", required=True, help="dataset root (any layout data.agriseg_loader reads)")
    bound.add_argument("--domains", nargs="+", default=None, help="domains or families (default: all)")
    bound.add_argument(
        "--sizes", type=int, nargs="+", default=[128, 192, 224], help="input sides (default 128 192 224)"
    )
    bound.add_argument("--frames", type=int, default=200, help="masks to use, evenly spaced (default 200)")
    bound.add_argument("--steps", type=int, default=150, help="Adam steps of the logit fit (default 150)")
    bound.set_defaults(func=_bench_iou_bound)


def _register_export(bench: argparse._SubParsersAction) -> None:
    parser = bench.add_parser(
        "export",
        help="per-frame latency: PyTorch eager vs onnxruntime fp32 / INT8, and one full SegMinD step",
    )
    parser.add_argument("--checkpoint", type=Path, default=None, help="checkpoint (default: random weights)")
    parser.add_argument("--onnx", type=Path, default=None, help="an exported fp32 file to time instead")
    parser.add_argument("--size", type=int, default=224, help="square input size (default 224)")
    parser.add_argument("--threads", type=int, default=2, help="threads for torch and onnxruntime (default 2)")
    parser.add_argument("--runs", type=int, default=200, help="timed frames per model (default 200)")
    parser.add_argument("--no-int8", action="store_true", help="skip building and timing INT8")
    parser.add_argument(
        "--compare-exporters", action="store_true", help="also time the legacy TorchScript exporter's graph"
    )
    parser.add_argument("--calib-data", type=Path, default=None, help="frames for INT8 calibration")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    parser.set_defaults(func=_bench_export)


def _register_closed_loop(bench: argparse._SubParsersAction) -> None:
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
        help="render backends driving the same run in turn (default: tiny gl; auto: what a run gets with "
        "no backend setting); --matrix uses the last",
    )
    b.add_argument("--rounds", type=int, default=1, help="turns of every backend (default 1)")
    b.add_argument("--out", type=Path, default=None, help="folder for --matrix outputs (default: a temp folder)")
    add_scenario_options(b)
    b.set_defaults(func=_bench_nav_eval)

    bag = bench.add_parser(
        "replay-bag", help="segmin replay --bag against segmin replay on the same frames as folders (frames/s)"
    )
    bag.add_argument("--model", type=Path, required=True, help="exported .onnx file or a shipped model name")
    bag.add_argument("--bag", type=Path, required=True, help="a bag with segmin's camera topics (nav-eval --bag)")
    bag.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    bag.add_argument("--method", default="segmind", choices=("segmin", "segmind", "segzeros"))
    bag.add_argument("--depth-threshold", type=float, default=5.0, help="depth cut in metres (default 5)")
    bag.set_defaults(func=_bench_replay_bag)

    live = bench.add_parser(
        "live-view",
        help="what --live's publisher costs the runtime, as a share of its frame time (a client subscribed)",
    )
    live.add_argument("--model", default="vineyards", help="exported .onnx file or a shipped model name (vineyards)")
    live.add_argument("--frames", type=int, default=150, help="frames per round, at 30 Hz (default 150: 5 s)")
    live.add_argument(
        "--rounds", type=int, default=5, help="alternations of the runtime alone and with the view (default 5)"
    )
    live.add_argument("--size", default="640x480", help="frame size WxH (default 640x480, the D435's colour)")
    live.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    live.set_defaults(func=_bench_live_view)

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
        help="render backends, taking turns on each setting (default: tiny gl; auto: the env's default; "
        "ratios against the first)",
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


def _bench_synth(args: argparse.Namespace) -> int:
    from benchmarks.synth import SynthBenchOptions, bench_synth
    from segmin.data.synth.spec import TEST_FIELDS

    options = SynthBenchOptions(
        camera=camera_from_size(args.size),
        frames=args.frames,
        fields=tuple(args.fields or TEST_FIELDS),
        workers=tuple(args.workers),
        backends=tuple(args.backends),
    )
    bench_synth(options)
    return 0


def _bench_agreement(args: argparse.Namespace) -> int:
    from benchmarks.render_agreement import AgreementOptions, bench_render_agreement
    from segmin.common.outputs import check_output_file
    from segmin.data.synth.spec import TEST_FIELDS

    if args.sheet is not None:
        check_output_file(args.sheet, "--sheet")
        if args.sheet.exists() and not args.force:
            raise ValueError(f"--sheet {args.sheet}: already exists; use --force to overwrite")
    options = AgreementOptions(
        camera=camera_from_size(args.size),
        poses=args.poses,
        fields=tuple(args.fields or TEST_FIELDS),
        sheet=args.sheet,
        **({} if args.sun_distance is None else {"sun_distance": args.sun_distance}),
    )
    bench_render_agreement(options)
    return 0


def _bench_train(args: argparse.Namespace) -> int:
    from benchmarks.train import TrainBenchOptions, bench_train, report_lines

    options = TrainBenchOptions(
        root=args.root,
        image_size=args.size,
        batch_size=args.batch,
        threads=args.threads,
        steps=args.steps,
        workers=args.workers,
        repeats=args.repeats,
        device=args.device,
    )
    print("\n".join(report_lines(bench_train(options))))
    return 0


def _bench_iou_bound(args: argparse.Namespace) -> int:
    from benchmarks.iou_bound import check_size, iou_bound, load_masks, resize_masks

    if args.steps < 0:
        raise ValueError(f"--steps {args.steps}: must be >= 0")
    for size in args.sizes:
        check_size(size)
    masks = load_masks(args.root, args.domains, args.frames)
    print(
        f"IoU ceilings of LR-ASPP (logits at 1/8 resolution, bilinear upsampling) on {args.root}"
        f" {args.domains or '(all domains)'}"
    )
    print(f"{'input':>7}{'logit grid':>12}{'frames':>8}{'area-average':>14}{'fitted logits':>15}")
    for size in args.sizes:
        b = iou_bound(resize_masks(masks, size), steps=args.steps)
        print(f"{b.size:>7}{f'{b.grid}x{b.grid}':>12}{b.frames:>8}{b.area_iou:>14.3f}{b.fitted_iou:>15.3f}")
    print(
        "fitted is a close estimate of the ceiling from below (BCE fit of the logit grid);"
        " a target well above it is out of reach at that input size"
    )
    return 0


def _bench_export(args: argparse.Namespace) -> int:
    from benchmarks.export import ExportBenchOptions, run_benchmark
    from benchmarks.perception_step import perception_step_candidates

    options = ExportBenchOptions(
        checkpoint=args.checkpoint,
        onnx=args.onnx,
        size=args.size,
        threads=args.threads,
        runs=args.runs,
        int8=not args.no_int8,
        compare_exporters=args.compare_exporters,
        calib_data=args.calib_data,
        json=args.json,
    )
    run_benchmark(options, step_candidates=perception_step_candidates)
    return 0


def _bench_nav_eval(args: argparse.Namespace) -> int:
    from benchmarks.nav_eval import NavEvalBenchOptions, bench_nav_eval
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
    from benchmarks.replay_bag import bench_replay_bag

    print(bench_replay_bag(args.model, args.bag, args.threads, args.method, args.depth_threshold))
    return 0


def _bench_live_view(args: argparse.Namespace) -> int:
    from benchmarks.live_view import bench_live_view

    for name, low in (("frames", 30), ("rounds", 1), ("threads", 1)):  # 30 frames: one second of camera
        if getattr(args, name) < low:
            raise ValueError(f"bench live-view: --{name} {getattr(args, name)}: must be >= {low}")
    camera = camera_from_size(args.size)
    print(bench_live_view(args.model, args.frames, args.rounds, (camera.width, camera.height), args.threads))
    return 0


def _bench_gym(args: argparse.Namespace) -> int:
    from benchmarks.gym import bench_gym, format_gym_rows

    if args.steps < 1 or any(s < 8 for s in args.sizes) or any(n < 1 for n in args.num_envs):
        raise ValueError("bench gym: --steps, --num-envs must be >= 1 and --sizes >= 8 px")
    from segmin.data.synth.render import BACKENDS

    if not args.backends or any(b not in BACKENDS for b in args.backends):
        raise ValueError(f"bench gym: --backends {' '.join(args.backends)}: each must be one of {', '.join(BACKENDS)}")
    print(format_gym_rows(bench_gym(args.field, args.sizes, args.steps, args.num_envs, args.backends)))
    return 0


def _bench_executor(args: argparse.Namespace) -> int:
    from benchmarks.executor import ExecutorBenchOptions, bench_executor

    for name in ("frames", "size", "runs", "workers", "rounds"):
        if getattr(args, name) < 1:
            raise ValueError(f"bench executor: --{name} must be >= 1, got {getattr(args, name)}")
    overrides = tuple(overrides_of(args)) or ExecutorBenchOptions.nav_overrides
    options = ExecutorBenchOptions(
        args.field, args.frames, args.size, args.runs, args.workers, args.rounds, overrides, args.ray_address
    )
    bench_executor(options)
    return 0


if __name__ == "__main__":
    sys.exit(main())


def _register_architectures(bench: argparse._SubParsersAction) -> None:
    from segmin.models.architectures import ARCHITECTURES

    parser = bench.add_parser(
        "architectures",
        help="onnxruntime frame time of the candidate networks (backbone cuts) as a ratio to the full network",
        description=(
            "Export every architecture (random weights) at every size, time them alternately in one "
            "session with onnxruntime, and print median / p95 ms, the ratio to the full network at "
            "224 px, parameters, file size and the optimised graph's op counts, with the load average."
        ),
    )
    parser.add_argument(
        "--architectures",
        nargs="+",
        default=list(ARCHITECTURES),
        metavar="NAME",
        help=f"networks to time (default: all: {', '.join(ARCHITECTURES)}); the full network is always timed",
    )
    parser.add_argument("--sizes", nargs="+", type=int, default=[224, 192], help="square input sizes (default 224 192)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads (default 2)")
    parser.add_argument("--runs", type=int, default=200, help="timed frames per candidate (default 200)")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    parser.set_defaults(func=_bench_architectures)


def _bench_architectures(args: argparse.Namespace) -> int:
    from benchmarks.architectures import ModelSpeedOptions
    from benchmarks.architectures import run_model_speed as run

    run(
        ModelSpeedOptions(
            architectures=tuple(args.architectures),
            sizes=tuple(args.sizes),
            threads=args.threads,
            runs=args.runs,
            json=args.json,
        )
    )
    return 0


def _register_litert(bench: argparse._SubParsersAction) -> None:
    parser = bench.add_parser(
        "litert",
        help="LiteRT (.tflite) files' frame time side by side, and the ops XNNPACK leaves out of each",
        description=(
            "Time LiteRT files alternately in one process (XNNPACK, per thread count) and print median / p95 "
            "ms, the ratio to the first file and the load average; before that, each file's XNNPACK partitions "
            "and the ops left to LiteRT's own kernels (why an INT8 file can be slower than fp32)."
        ),
    )
    parser.add_argument("--models", nargs="+", required=True, type=Path, metavar="FILE", help=".tflite files")
    parser.add_argument("--threads", nargs="+", type=int, default=[2, 1], help="thread counts (default 2 1)")
    parser.add_argument("--rounds", type=int, default=6, help="alternating rounds (default 6)")
    parser.add_argument("--runs", type=int, default=240, help="timed frames per file and thread count (default 240)")
    parser.set_defaults(func=_bench_litert)


def _bench_litert(args: argparse.Namespace) -> int:
    from benchmarks.litert import LiteRtSpeedOptions
    from benchmarks.litert import run_litert_speed as run

    run(LiteRtSpeedOptions(tuple(args.models), tuple(args.threads), args.rounds, args.runs))
    return 0
