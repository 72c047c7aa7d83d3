"""`segmin models list` and `segmin models release`: the shipped models and how they get there.

`list` runs on the bare robot install (it reads the cards' JSON, no torch, no onnx). `release`
takes a finished `segmin pipeline` run and puts each family's exported model into the registry
folder (`nav_eval/runtime/released/` of the package, or $SEGMIN_MODELS_DIR, or --to) with its
card beside it and inside its metadata. Every file is checked and every card built before the
first is written, and each file is written atomically, so a refused or failed release leaves the
registry as it was; files already there are replaced only with --force.
"""

from __future__ import annotations

import argparse
import contextlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any


def register(commands: argparse._SubParsersAction, bench: argparse._SubParsersAction) -> None:
    models = commands.add_parser("models", help="the shipped segmentation models: list them, release a run's")
    sub = models.add_subparsers(dest="models_command", metavar="ACTION", required=True)
    listing = sub.add_parser("list", help="the shipped model names, their files and headline figures (from the cards)")
    listing.set_defaults(func=_list)
    release = sub.add_parser(
        "release",
        help="copy a pipeline run's exported models and their model cards into the registry",
        description="Each family's export/<family>/<family>.onnx of the run becomes the shipped model of that "
        "name, with <name>.md (the card), <name>.card.json (its figures), the card in the ONNX metadata and "
        "<name>.real.jpg (the real-photo contact sheet, when the run scored the photos).",
    )
    release.add_argument("--run", type=Path, required=True, help="a finished `segmin pipeline` run folder")
    release.add_argument(
        "--families", nargs="+", default=None, help="families to release (default: every shipped name the run exported)"
    )
    release.add_argument(
        "--to", type=Path, default=None, help="registry folder (default: $SEGMIN_MODELS_DIR or the package's)"
    )
    release.add_argument("--force", action="store_true", help="replace models already in the registry")
    release.set_defaults(func=_release)
    to_torch = sub.add_parser(
        "to-torch",
        help="a shipped (or any segmin fp32 ONNX) model as a PyTorch state dict to train from",
        description="Writes the model's network as a PyTorch state dict that training loads with "
        "backbone_weights=FILE, to fine-tune a shipped model on your own frames. The exporter folded each "
        "BatchNorm into its convolution; their statistics are measured again on --frames (any segmin dataset "
        "root: rendered frames or your own; only the images are read). The result computes what the ONNX model "
        "computes (checked on those frames).",
    )
    to_torch.add_argument("--model", required=True, help="a shipped model name or an fp32 segmin .onnx file")
    to_torch.add_argument("--frames", type=Path, required=True, help="dataset root whose images calibrate BatchNorm")
    to_torch.add_argument("--count", type=int, default=64, help="frames to use, evenly spread (default 64)")
    to_torch.add_argument("--out", type=Path, required=True, help="the state dict to write (.pt)")
    to_torch.add_argument("--force", action="store_true", help="replace --out when it exists")
    to_torch.set_defaults(func=_to_torch)


def _list(args: argparse.Namespace) -> int:
    from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES, headline, models_dir, shipped_model

    print(f"shipped models in {models_dir()}:")
    for name in SHIPPED_NAMES:
        entry = shipped_model(name)
        if not entry.present:
            print(f"  {name}: not in this install (release one with `segmin models release --run RUN_DIR`)")
            continue
        card = entry.card()
        size = entry.onnx.stat().st_size / 1e6
        figures = headline(card) if card is not None else "no model card"
        print(f"  {name}: {entry.onnx.name} ({size:.1f} MB), {figures}")
    return 0


def _release(args: argparse.Namespace) -> int:
    from segmin.nav_eval.runtime.shipped_models import models_dir

    root = args.to if args.to is not None else models_dir()
    for name, release in release_run(args.run, root, families=args.families, force=args.force).items():
        onnx = root / f"{name}.onnx"
        extra = f", {release.card['real_photos']['contact_sheet_file']}" if release.sheet is not None else ""
        print(f"released {name}: {onnx} ({onnx.stat().st_size / 1e6:.1f} MB) with {name}.md, {name}.card.json{extra}")
    return 0


def release_run(run: Path, root: Path, *, families: list[str] | None = None, force: bool = False) -> dict[str, Any]:
    """Release the run's models into `root`: what `segmin models release` does, and the last
    stage of a pipeline profile with `release: true` (into the run's own release/ folder).
    Returns {name: what was released (its card and contact sheet)}."""
    from segmin.common.lock import writer_lock
    from segmin.common.outputs import make_dirs

    planned = _plan(run, families, root, force)
    make_dirs(root, "--to")
    with writer_lock(root / ".release.lock", f"the model registry {root}"):
        _check_unreleased(root, list(planned), force)  # again under the lock: another release may have come first
        _remove_leftovers(root)
        _write_release(planned, root)
    return planned


@dataclass
class _Release:
    """One family's release, read and checked: the model with its card in the metadata, the card
    (its figures, as Markdown and as JSON) and the real-photo contact sheet as JPEG bytes (None
    when the run scored no photos)."""

    model: Any  # onnx.ModelProto
    card: dict[str, Any]
    markdown: str
    card_json: str
    sheet: bytes | None


def _plan(run: Path, families: list[str] | None, root: Path, force: bool) -> dict[str, _Release]:
    """Every family to release, each model read and checked: every error comes before anything is
    written (a release that failed on its second family used to have replaced the first)."""
    from segmin.app.model_card import build_card, card_markdown
    from segmin.export import metadata as md
    from segmin.export.onnx import load_segmin_model, set_metadata
    from segmin.nav_eval.runtime.shipped_models import SHEET_SUFFIX, SHIPPED_NAMES

    if not (run / "render" / "stage.json").is_file():
        raise ValueError(f"--run {run}: not a segmin pipeline run folder (no render/stage.json)")
    names = families or [n for n in SHIPPED_NAMES if (run / "export" / n / "stage.json").is_file()]
    if not names:
        raise ValueError(f"--run {run}: exported none of the shipped names ({', '.join(SHIPPED_NAMES)})")
    unknown = [n for n in names if n not in SHIPPED_NAMES]
    if unknown:
        raise ValueError(f"--families {unknown[0]}: not a shipped model name (shipped: {', '.join(SHIPPED_NAMES)})")
    _check_unreleased(root, names, force)
    planned = {}
    for name in names:
        card = build_card(run, name)
        sheet = _contact_sheet(run, card)
        if sheet is not None:
            card["real_photos"]["contact_sheet_file"] = f"{name}{SHEET_SUFFIX}"
        model = load_segmin_model(run / "export" / name / f"{name}.onnx")
        markdown, card_json = card_markdown(card), json.dumps(card, indent=2, sort_keys=True)
        set_metadata(model, {md.KEY_MODEL_CARD: markdown, md.KEY_MODEL_CARD_JSON: card_json})
        planned[name] = _Release(model, card, markdown, card_json, sheet)
    return planned


def _check_unreleased(root: Path, names: list[str], force: bool) -> None:
    """Without `force`, none of the files a release of `names` writes may exist in `root` yet."""
    from segmin.nav_eval.runtime.shipped_models import CARD_SUFFIX, SHEET_SUFFIX

    if force:
        return
    for name in names:
        for suffix in (".onnx", ".md", CARD_SUFFIX, SHEET_SUFFIX):
            if (root / f"{name}{suffix}").exists():
                raise ValueError(f"{root / f'{name}{suffix}'}: already released (use --force to replace it)")


def _contact_sheet(run: Path, card: dict[str, Any]) -> bytes | None:
    """The run's real-photo contact sheet as JPEG (a third of the PNG's size in the wheel), None
    when the run scored no photos."""
    import cv2

    if not card["real_photos"]:
        return None
    path = run / card["real_photos"]["contact_sheet"]
    image = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
    if image is None:
        raise ValueError(
            f"{path}: the scored model's real-photo contact sheet is missing or unreadable "
            "(rerun `segmin pipeline` with this --out to score the photos again)"
        )
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        raise ValueError(f"{path}: could not encode the contact sheet as JPEG")
    return jpeg.tobytes()


def _remove_leftovers(root: Path) -> None:
    """The temporary files a killed release left (`atomic_path` names them `.<file>.<random>.tmp`):
    no later write would ever replace them. Called under the registry's lock, so none is live."""
    from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES

    for name in SHIPPED_NAMES:
        for leftover in root.glob(f".{name}.*.tmp"):
            leftover.unlink(missing_ok=True)


def _write_release(planned: dict[str, _Release], root: Path) -> None:
    """Every family's model, card files and contact sheet, all or nothing: each file goes to a
    temporary beside its name, and the temporaries replace the registry's files only once every
    one is written (an error on the way removes them all)."""
    import onnx

    from segmin.common.atomic import atomic_path
    from segmin.nav_eval.runtime.shipped_models import CARD_SUFFIX, SHEET_SUFFIX

    with contextlib.ExitStack() as stack:
        for name, release in planned.items():
            onnx.save(release.model, str(stack.enter_context(atomic_path(root / f"{name}.onnx"))))
            files = {
                f"{name}.md": release.markdown.encode(),
                f"{name}{CARD_SUFFIX}": (release.card_json + "\n").encode(),
            }
            if release.sheet is not None:
                files[f"{name}{SHEET_SUFFIX}"] = release.sheet
            for file_name, data in files.items():
                stack.enter_context(atomic_path(root / file_name)).write_bytes(data)
    for name, release in planned.items():
        if release.sheet is None:  # a replaced model's sheet would show another model's errors
            (root / f"{name}{SHEET_SUFFIX}").unlink(missing_ok=True)


def _to_torch(args: argparse.Namespace) -> int:
    import torch

    from segmin.common.atomic import atomic_path
    from segmin.common.outputs import check_output_file, make_dirs
    from segmin.export.to_torch import check_conversion, network_from_onnx
    from segmin.nav_eval.runtime.shipped_models import resolve_model

    if args.count < 1:
        raise ValueError(f"--count {args.count}: must be >= 1")
    check_output_file(args.out, "--out")  # a folder there would fail only after the conversion
    if args.out.exists() and not args.force:
        raise ValueError(f"{args.out}: already exists (use --force to replace it)")
    source = resolve_model(args.model)
    network, frames = network_from_onnx(source, args.frames, args.count)
    worst = check_conversion(network, source, frames)
    make_dirs(args.out.parent, what="--out folder")
    with atomic_path(args.out) as tmp:
        torch.save(network.state_dict(), tmp)
    print(
        f"wrote {args.out}: the network of {source}, BatchNorm statistics from {len(frames)} frames of {args.frames} "
        f"(largest probability difference to the ONNX model {worst:.1e}); train from it with backbone_weights={args.out}"
    )
    return 0
