"""The one override grammar of every command: positional `KEY=VALUE` tokens, `--set` as an alias.

`segmin train --config c.yaml epochs=5`, `segmin nav-eval ... run.length_m=10` and
`segmin synth render --world w rows.length=10` all read the same way. Positional tokens and
`--set` values land in one list, `args.overrides`, in command-line order, so a later value for
the same key wins whichever spelling was used.

Overrides may stand anywhere on the line (`nav-eval ... run.length_m=1 --runs 1 run.time_limit_s=15`):
argparse hands a positional only the first run of plain tokens, so a parser that takes overrides
is a `CommandParser`, which parses options and positionals intermixed and then puts the overrides
back in the order they were typed.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections import Counter
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from segmin.common.executor import Executor

OVERRIDES_DEST = "overrides"
# A dotted config key, then "=": what an override looks like (a world path such as
# configs/worlds/a.yaml has no "=" after a bare key, so it is never mistaken for one).
_OVERRIDE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*=")


def is_override(token: str) -> bool:
    """True when `token` reads as `key=value` (a dotted key, then "=")."""
    return bool(_OVERRIDE.match(token))


def _append(namespace: argparse.Namespace, values: Sequence[str]) -> None:
    """Extend `namespace.overrides` with a fresh list (never a shared default)."""
    setattr(namespace, OVERRIDES_DEST, [*(getattr(namespace, OVERRIDES_DEST, None) or []), *values])


class _AppendOverrides(argparse.Action):
    """Positional tokens and `--set` values both append, so their order on the line is kept."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        _append(namespace, [values] if isinstance(values, str) else list(values or []))


class NamesThenOverrides(argparse.Action):
    """For an `nargs="+"` option (`--world a b`): `key=value` tokens it swallowed are overrides.

    argparse hands every following non-option token to such an option, so
    `--world a b rows.length=10` would otherwise make `rows.length=10` a world name.
    """

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        names = [v for v in values if not is_override(v)]
        if not names:
            parser.error(f"{option_string}: expected at least one name before the KEY=VALUE overrides")
        setattr(namespace, self.dest, names)
        overrides = [v for v in values if is_override(v)]
        if overrides:  # an empty list here would make intermixed parsing warn and drop the attribute
            _append(namespace, overrides)


def in_line_order(overrides: list[str], argv: Sequence[str]) -> list[str]:
    """`overrides` in the order their tokens stand in `argv` (`--set=K=V` counts where it stands).

    Intermixed parsing collects option values (`--set`) before positional tokens; this restores
    the typed order, so the later of two values for one key still wins.
    """
    pending = Counter(overrides)
    ordered = []
    for token in argv:
        value = token.partition("=")[2] if token.startswith("-") else token
        if pending[value] > 0:
            pending[value] -= 1
            ordered.append(value)
    return ordered + list(pending.elements())  # nothing left: every override is a token or follows "="


class CommandParser(argparse.ArgumentParser):
    """The parser class of the `segmin` command tree (subcommand parsers inherit it from the root).

    One that takes overrides (`add_overrides`) parses intermixed, so they work wherever they stand
    on the line; every other parser parses as argparse always does.
    """

    takes_overrides = False
    _intermixing = False  # parse_known_intermixed_args calls parse_known_args itself (Python < 3.13)

    def parse_known_args(  # type: ignore[override]  # one signature for typeshed's three overloads
        self, args: Sequence[str] | None = None, namespace: Any = None
    ) -> tuple[Any, list[str]]:
        if not self.takes_overrides or self._intermixing:
            return super().parse_known_args(args, namespace)
        argv = list(sys.argv[1:] if args is None else args)
        self._intermixing = True
        try:
            namespace, extras = self.parse_known_intermixed_args(argv, namespace)
        finally:
            self._intermixing = False
        overrides = getattr(namespace, OVERRIDES_DEST, None)
        if overrides:
            setattr(namespace, OVERRIDES_DEST, in_line_order(overrides, argv))
        return namespace, extras


def add_overrides(parser: argparse.ArgumentParser, alias: bool = True, example: str = "section.key=value") -> None:
    """Positional `KEY=VALUE` overrides (nargs="*", anywhere on the line), plus `--set KEY=VALUE` when `alias`."""
    if not isinstance(parser, CommandParser):  # a plain parser would take overrides only before the first option
        raise TypeError(f"add_overrides needs a CommandParser, got {type(parser).__name__}")
    parser.takes_overrides = True
    parser.add_argument(
        OVERRIDES_DEST,
        nargs="*",
        action=_AppendOverrides,
        default=None,
        metavar="KEY=VALUE",
        help=f"config overrides (dotted keys, YAML values), anywhere on the line, e.g. {example}",
    )
    if alias:
        parser.add_argument(
            "--set",
            dest=OVERRIDES_DEST,
            action=_AppendOverrides,
            default=None,
            metavar="KEY=VALUE",
            help="the same override as an option (repeatable)",
        )


def overrides_of(args: argparse.Namespace) -> list[str]:
    """The overrides given on the command line, in order ([] when none)."""
    return list(getattr(args, OVERRIDES_DEST, None) or [])


def add_executor_options(parser: argparse.ArgumentParser) -> None:
    """`--executor local|ray` and `--ray-address`: where a command's workers run
    (`segmin.common.executor`); `--workers` stays the number of them."""
    from segmin.common.executor import EXECUTORS

    parser.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="where the --workers run: local processes (default) or Ray actors (needs the [cluster] extra)",
    )
    parser.add_argument(
        "--ray-address",
        default=None,
        help="the Ray cluster for --executor ray (default: RAY_ADDRESS, else a Ray instance started for the run)",
    )


def executor_of(args: argparse.Namespace) -> Executor:
    """The Executor that `add_executor_options`'s arguments name: a ValueError when they disagree,
    the [cluster] advice, or a cluster address that does not answer, now (not after the command's
    first steps) when Ray is chosen."""
    from segmin.common.executor import Executor, check_ray_address, import_ray

    executor = Executor(args.executor, args.ray_address)
    if executor.kind == "ray":
        import_ray()
        check_ray_address(executor.ray_address)
    return executor
