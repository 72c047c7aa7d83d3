"""The one override grammar of every command: positional `KEY=VALUE` tokens, `--set` as an alias.

`segmin train --config c.yaml epochs=5`, `segmin nav-eval ... run.length_m=10` and
`segmin synth render --world w rows.length=10` all read the same way. Positional tokens and
`--set` values land in one list, `args.overrides`, in command-line order, so a later value for
the same key wins whichever spelling was used.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence
from typing import Any

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
        _append(namespace, [v for v in values if is_override(v)])


def add_overrides(parser: argparse.ArgumentParser, alias: bool = True, example: str = "section.key=value") -> None:
    """Positional `KEY=VALUE` overrides (nargs="*"), plus `--set KEY=VALUE` when `alias`."""
    parser.add_argument(
        OVERRIDES_DEST,
        nargs="*",
        action=_AppendOverrides,
        default=None,
        metavar="KEY=VALUE",
        help=f"config overrides (dotted keys, YAML values), e.g. {example}",
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
