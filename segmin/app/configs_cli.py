"""`segmin configs list` and `segmin configs copy NAME DIR`: the configs shipped inside the package.

A wheel carries its worlds, training recipes, nav settings, pipeline profiles and sweeps; these commands
show them and write one out for editing, after which the copy's path works wherever the name did.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from segmin.common.shipped import KINDS, copy_shipped, shipped_dir, shipped_names


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    configs = commands.add_parser("configs", help="list the shipped configs, or copy one out for editing")
    sub = configs.add_subparsers(dest="configs_command", metavar="ACTION", required=True)
    listing = sub.add_parser(
        "list", help="the shipped worlds, training configs, nav configs, pipeline profiles and sweeps"
    )
    listing.add_argument("--paths", action="store_true", help="also print where each kind is installed")
    listing.set_defaults(func=_list)
    copy = sub.add_parser("copy", help="write a shipped config to DIR/<name>.yaml (use it as --config DIR/<name>.yaml)")
    copy.add_argument("name", help="a shipped name, e.g. straight_vineyard or pipeline/quick when it is ambiguous")
    copy.add_argument("dir", type=Path, help="folder to write into (created if needed)")
    copy.add_argument("--force", action="store_true", help="overwrite an existing file")
    copy.set_defaults(func=_copy)


def _list(args: argparse.Namespace) -> int:
    for kind, purpose in KINDS.items():
        where = f" [{shipped_dir(kind)}]" if args.paths else ""
        print(f"{kind}: {purpose}{where}")
        print("  " + " ".join(shipped_names(kind)))
    return 0


def _copy(args: argparse.Namespace) -> int:
    print(f"wrote {copy_shipped(args.name, args.dir, force=args.force)}")
    return 0
