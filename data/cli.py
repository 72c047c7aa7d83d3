"""`segmin data inspect ROOT`: what a dataset folder holds and everything wrong with it."""

from __future__ import annotations

import argparse
from collections import Counter


def register(commands, bench) -> None:
    data = commands.add_parser("data", help="inspect datasets on disk (AgriSeg layouts, rendered frames)")
    sub = data.add_subparsers(dest="data_command", metavar="ACTION", required=True)
    inspect = sub.add_parser("inspect", help="frames per domain and subset, and every problem found")
    inspect.add_argument("root", help="dataset root folder")
    inspect.add_argument(
        "--quick",
        "--no-decode",
        dest="quick",
        action="store_true",
        help="only pair file names (skip decoding every image, mask and depth file)",
    )
    inspect.set_defaults(func=_inspect)


def _inspect(args: argparse.Namespace) -> int:
    from segmin.data.agriseg_loader import scan
    from segmin.data.frame_check import promise_problems, verify_frames

    result = scan(args.root)
    problems = list(result.problems) + list(result.unpaired)
    counts = Counter((f.domain, f.subset) for f in result.frames)
    with_depth = Counter((f.domain, f.subset) for f in result.frames if f.depth_path is not None)
    layouts = Counter(result.layouts.values())
    print(
        f"{args.root}: {len(result.frames)} paired frames; layouts: "
        + (", ".join(f"{k} x{v}" for k, v in sorted(layouts.items())) or "none")
    )
    print(f"{'domain':<28} {'subset':<32} {'frames':>7} {'depth':>6}")
    for domain in sorted({d for d, _ in counts}):
        subsets = sorted(s for d, s in counts if d == domain)
        for subset in subsets:
            print(f"{domain:<28} {subset:<32} {counts[domain, subset]:>7} {with_depth[domain, subset]:>6}")
        if len(subsets) > 1:
            total = sum(counts[domain, s] for s in subsets)
            print(f"{domain:<28} {'(all)':<32} {total:>7}")
    problems += promise_problems(args.root, result.frames)
    if not args.quick:  # every file reported on is decoded: image, mask and depth (sizes checked)
        problems += verify_frames(result.frames, depth=True)
    if problems:
        print(f"{len(problems)} problem(s):")
        for message in problems:
            print(f"  {message}")
        return 1
    print("no problems found" + (" (names paired only, files not decoded: --quick)" if args.quick else ""))
    return 0
