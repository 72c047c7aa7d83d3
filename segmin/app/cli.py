"""The `segmin` command: one entry point, subcommands contributed by each package.

Each package keeps its command-line code in its own `cli.py` exposing
`register(commands, bench)`: `commands` is the top-level subparser group, `bench` the group
under `segmin bench` (the benches a robot team runs on its own hardware; the developers' benches
are in the repository's `benchmarks/` folder, outside the wheel). A registered parser sets `func`
(called with the parsed args, returns an
exit code). Heavy imports (torch, pybullet, onnxruntime) happen inside those functions, so
`segmin --help` stays fast and works on the bare robot install; a command whose optional
dependencies are missing says which extra to install.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback

from segmin import __version__
from segmin.common.cli_args import CommandParser
from segmin.common.config import ConfigError
from segmin.common.console_log import show_progress
from segmin.common.extras import missing_extra_message

# Packages that contribute commands, in the order of the data flow.
COMMAND_MODULES: tuple[str, ...] = (
    "segmin.app.configs_cli",
    "segmin.data.cli",
    "segmin.data.synth.cli",
    "segmin.train.cli",
    "segmin.app.export_cli",
    "segmin.nav_eval.demo.cli",
    "segmin.nav_eval.replay.cli",
    "segmin.nav_eval.ros2.cli",
    "segmin.nav_eval.seg_eval.cli",
    "segmin.nav_eval.evaluation.cli",
    "segmin.nav_eval.sweeps.cli",
    "segmin.nav_eval.bench.cli",
    "segmin.app.pipeline.cli",
    "segmin.app.models_cli",
)
# Errors that are the user's (bad input, a path that is not there or not writable): one line, exit 2.
USER_ERRORS: tuple[type[BaseException], ...] = (ConfigError, ValueError, OSError)


def build_parser() -> argparse.ArgumentParser:
    """The full parser tree (used by `main` and by tests that check every `--help`)."""
    parser = CommandParser(  # its class goes to every subcommand parser: overrides anywhere on the line
        prog="segmin",
        description="Train, export and validate crop-segmentation navigation (SegMin / SegMinD).",
    )
    parser.add_argument("--version", action="version", version=f"segmin {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    bench_parser = commands.add_parser(
        "bench", help="speed figures on this computer: the models, the navigator with the runtime, the ROS 2 node"
    )
    bench = bench_parser.add_subparsers(dest="bench_target", metavar="TARGET", required=True)
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).register(commands, bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse arguments and run the chosen subcommand; user errors print one line and return 2."""
    return run_command(build_parser().parse_args(argv))


def run_command(args: argparse.Namespace, prog: str = "segmin") -> int:
    """Run a parsed command (its `func`), the way every segmin entry point answers errors: a user
    error or a missing extra is one line `PROG: error: ...` and exit 2 (`--debug`: the traceback too),
    Ctrl-C exit 130. The repository's benchmark runner shares it, so its errors read the same."""
    show_progress()
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except ModuleNotFoundError as exc:
        message = missing_extra_message(exc)
        if message is None or args.debug:
            raise
        print(f"{prog}: error: {message}", file=sys.stderr)
        return 2
    except USER_ERRORS as exc:
        if args.debug:
            traceback.print_exc()
        print(f"{prog}: error: {_one_line(exc)}", file=sys.stderr)
        return 2


def _one_line(exc: BaseException) -> str:
    """The message of a user error on one line; an OSError names its path and the reason."""
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
