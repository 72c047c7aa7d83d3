"""Verify frames before they are used: every file decodes, sizes agree, the pairing holds.

Training reads a frame only when the sampler picks it, inside a loader worker: a corrupt file
then shows up as a multi-line worker traceback, hours in, or never (another batch size, another
seed). `verify_frames` decodes every frame once up front instead; a small JSON cache keyed by
each file's size and mtime makes the check of an unchanged dataset nearly free on a rerun.
`worker_error_line` turns the DataLoader's re-raised worker error back into one line.
`promise_problems` compares each rendered subset's meta.json with the frames on disk (a killed
render leaves a meta file listing every planned frame and only part of them).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from segmin.common.atomic import write_json
from segmin.data.agriseg_loader import DatasetError, Frame, load_frame, read_depth

CACHE_FORMAT = "segmin-frame-check-v1"


def check_frame(frame: Frame, *, depth: bool = True) -> None:
    """Decode the frame's image, mask (and depth when `depth`); DatasetError naming the file."""
    image, _ = load_frame(frame)  # decodes both, checks the mask size against the image
    if depth and frame.depth_path is not None:
        d = read_depth(frame.depth_path)
        if d.shape[:2] != image.shape[:2]:
            raise DatasetError(
                f"{frame.depth_path}: depth size {d.shape[1]}x{d.shape[0]} does not match image "
                f"{frame.image_path} size {image.shape[1]}x{image.shape[0]}"
            )


def _files(frame: Frame, depth: bool) -> list[Path]:
    files = [frame.image_path, frame.mask_path]
    if depth and frame.depth_path is not None:
        files.append(frame.depth_path)
    return files


def _stamp(frame: Frame, depth: bool) -> list[list[int]] | None:
    """(size, mtime_ns) of each file; None when one is missing (then the check reports it)."""
    try:
        return [[st.st_size, st.st_mtime_ns] for st in (os.stat(p) for p in _files(frame, depth))]
    except OSError:
        return None


def _read_cache(path: Path | None) -> dict[str, list[list[int]]]:
    if path is None or not path.is_file():
        return {}
    try:
        content = json.loads(path.read_text())
    except (OSError, ValueError):  # a broken cache only costs a full check
        return {}
    if not isinstance(content, dict) or content.get("format") != CACHE_FORMAT:
        return {}
    files = content.get("frames")
    return files if isinstance(files, dict) else {}


def verify_frames(
    frames: Sequence[Frame], cache: Path | None = None, *, depth: bool = False, threads: int = 1
) -> list[str]:
    """Problems (one line each, naming the file) of `frames`; [] when every frame is sound.

    Frames whose files have the size and mtime recorded in `cache` are not decoded again; the
    cache is rewritten (atomically) with every frame found sound.
    """
    known = _read_cache(cache)
    good: dict[str, list[list[int]]] = {}
    todo: list[tuple[Frame, list[list[int]] | None]] = []
    for frame in frames:
        key = f"{frame.image_path}|{int(depth)}"
        stamp = _stamp(frame, depth)
        if stamp is not None and known.get(key) == stamp:
            good[key] = stamp
        else:
            todo.append((frame, stamp))

    def one(item: tuple[Frame, list[list[int]] | None]) -> str | None:
        frame, _ = item
        try:
            check_frame(frame, depth=depth)
        except DatasetError as exc:
            return str(exc)
        return None

    problems: list[str] = []
    with ThreadPoolExecutor(max(1, threads)) as pool:  # cv2 decodes outside the GIL
        for (frame, stamp), problem in zip(todo, pool.map(one, todo)):
            if problem is not None:
                problems.append(problem)
            elif stamp is not None:
                good[f"{frame.image_path}|{int(depth)}"] = stamp
    if cache is not None and todo:
        write_json(cache, {"format": CACHE_FORMAT, "frames": good})
    return problems


def require_sound_frames(frames: Sequence[Frame], cache: Path | None = None, *, threads: int = 1) -> None:
    """DatasetError listing the first problems when any frame fails `verify_frames`."""
    problems = verify_frames(frames, cache, threads=threads)
    if problems:
        more = f" (and {len(problems) - 3} more)" if len(problems) > 3 else ""
        raise DatasetError(
            f"{len(problems)} of {len(frames)} frame(s) failed to decode before training: "
            + "; ".join(problems[:3])
            + more
        )


def worker_error_line(exc: BaseException) -> str:
    """The original one-line message of an error re-raised from a DataLoader worker.

    torch re-raises a worker's exception with the worker's whole traceback as its message;
    the last line is `module.Type: message`, and the message is what names the file.
    """
    text = str(exc)
    if "DataLoader worker" not in text or "Traceback" not in text:
        return text.splitlines()[0] if text else type(exc).__name__
    last = next((line for line in reversed(text.splitlines()) if line.strip()), text)
    head, sep, message = last.partition(": ")
    return message if sep and " " not in head else last


def promise_problems(root: str | Path, frames: Sequence[Frame]) -> list[str]:
    """One line per meta.json under `root` that lists frames not present (paired) on disk."""
    present: dict[tuple[str, str], set[int]] = {}
    for frame in frames:
        present.setdefault((frame.domain, frame.subset), set()).add(frame.frame_id)
    problems = []
    for meta_path in sorted(Path(root).rglob("meta.json")):
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
            promised = {int(k) for k in meta["frames"]}
            key = (str(meta["domain"]), str(meta["subset"]))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            problems.append(f"{meta_path}: unreadable dataset meta file ({type(exc).__name__}: {exc})")
            continue
        missing = sorted(promised - present.get(key, set()))
        if missing:
            problems.append(
                f"{meta_path}: lists {len(promised)} frames, {len(missing)} of them are not on disk "
                f"(e.g. Image{missing[0]}): an interrupted render? rerun it to finish the dataset"
            )
    return problems
