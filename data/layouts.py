"""Find every frame under a dataset root, whatever its layout; detected per folder while walking.

- formatted (what AgriSeg's training code and our synthetic writer use):
  `<domain>/<domain>_<k>/images/ImageN/<file>`, `.../masks/ImageN/<file>`, `.../depths/ImageN/<file>`
- distributed (the AgriSeg download):
  `Synthetic_Dataset_<Crop>/<subset>/ImageN/{Image*, Segmentation*, Depth*}`
- flat real sets: `<name>/images/<stem>.jpg|png` + `<name>/masks/<stem>.png` (matching stems).

`scan` never raises on a bad layout: it records every problem naming the file, and
`domains.find_frames` decides what is fatal. No torch here: the robot runtime may import it.
"""

from __future__ import annotations

import re
from pathlib import Path

from segmin.data.frames import DEPTH_EXTS, IMAGE_EXTS, DatasetError, ScanResult, frame_id_of, pair_frames

# Distributed-layout crop folder -> formatted domain name (so families mean the same thing).
CROP_DOMAINS: dict[str, str] = {
    "big_trees": "tree",
    "pear": "pear",
    "vineyard_straight": "vineyard",
    "vineyard_pergolato": "vineyard_pergola",
}

_DISTRIBUTED_PREFIX = "Synthetic_Dataset_"
_FRAME_DIR = re.compile(r"^[A-Za-z_]*?(\d+)$")
_MASK_SUFFIXES = ("_mask", "_masks", "_seg", "_label", "_segmentation")


def scan(root: str | Path) -> ScanResult:
    """Walk `root` and collect every frame of every layout found, plus every problem.

    Does not raise on problems (that is `find_frames`' job); raises only if `root` is missing.
    """
    root = Path(root)
    if not root.exists():
        raise DatasetError(f"{root}: dataset root does not exist")
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset root is not a folder")
    result = ScanResult()
    _walk(root, root, result, depth=0)
    if not result.frames and not result.problems:
        result.problems.append(
            f"{root}: no dataset found (expected <domain>/<domain>_<k>/images|masks/ImageN/, "
            "Synthetic_Dataset_<Crop>/<subset>/ImageN/ or images/ + masks/ folders)"
        )
    result.frames.sort(key=lambda f: (f.domain, f.subset, f.frame_id))
    return result


def _subdirs(path: Path) -> list[Path]:
    try:
        return sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError:
        return []


def _walk(root: Path, folder: Path, result: ScanResult, depth: int) -> None:
    if (folder / "images").is_dir() and (folder / "masks").is_dir():
        _scan_image_mask_folder(root, folder, result)
        return
    if folder.name.startswith(_DISTRIBUTED_PREFIX):
        _scan_distributed_crop(folder, result)
        return
    if _is_distributed_subset(folder):  # a subset folder given directly (or under another name)
        parent = folder.parent.name
        crop = parent[len(_DISTRIBUTED_PREFIX) :] if parent.startswith(_DISTRIBUTED_PREFIX) else folder.name
        _scan_distributed_subset(CROP_DOMAINS.get(crop.lower(), crop.lower()), folder, folder.name, result)
        return
    if depth >= 4:
        return
    for child in _subdirs(folder):
        _walk(root, child, result, depth + 1)


def _is_distributed_subset(folder: Path) -> bool:
    """True when the first ImageN child folder holds Image* and Segmentation* files."""
    for child in _subdirs(folder):
        if _FRAME_DIR.match(child.name):
            names = [p.name.lower() for p in child.iterdir() if p.is_file()]
            return any(n.startswith("image") for n in names) and any(n.startswith("segmentation") for n in names)
    return False


def _domain_subset(root: Path, folder: Path) -> tuple[str, str]:
    """Formatted `<domain>/<domain>_<k>` -> (domain, subset); a lone folder is its own domain."""
    parent = folder.parent
    if parent.name and folder.name.startswith(parent.name + "_"):
        return parent.name, folder.name
    return folder.name, folder.name


def _scan_image_mask_folder(root: Path, folder: Path, result: ScanResult) -> None:
    domain, subset = _domain_subset(root, folder)
    images, masks, depths = folder / "images", folder / "masks", folder / "depths"
    if _subdirs(images):  # formatted: one file per ImageN folder
        result.layouts[str(folder)] = "formatted"
        img = _per_frame_dirs(images, IMAGE_EXTS, result)
        msk = _per_frame_dirs(masks, IMAGE_EXTS, result)
        dep = _per_frame_dirs(depths, DEPTH_EXTS, result) if depths.is_dir() else {}
    else:
        result.layouts[str(folder)] = "flat"
        img, msk, dep = _flat_pairs(images, masks, depths, result)
    pair_frames(domain, subset, folder, img, msk, dep, result)


def _frame_number(folder: Path, result: ScanResult) -> int | None:
    """The N of an `ImageN` frame folder; None (and a problem naming it) when it has none."""
    match = _FRAME_DIR.match(folder.name)
    if not match:
        result.problems.append(f"{folder}: folder name has no frame number (expected ImageN)")
        return None
    return int(match.group(1))


def _per_frame_dirs(parent: Path, exts: tuple[str, ...], result: ScanResult) -> dict[int, Path]:
    """{N: the file inside parent/ImageN/}; duplicates and empty folders are problems."""
    found: dict[int, Path] = {}
    for sub in _subdirs(parent):
        n = _frame_number(sub, result)
        if n is None:
            continue
        files = sorted(p for p in sub.iterdir() if p.is_file() and p.suffix.lower() in exts)
        if not files:  # an empty frame folder is a missing file: counts as unpaired
            result.unpaired.append(f"{sub}: no {'/'.join(exts)} file in frame folder")
            continue
        if len(files) > 1:
            result.problems.append(f"{sub}: {len(files)} files in one frame folder, expected one")
            continue
        if n in found:
            result.problems.append(f"{sub}: frame id {n} appears twice (also {found[n].parent})")
            continue
        found[n] = files[0]
    return found


def _flat_pairs(
    images: Path, masks: Path, depths: Path, result: ScanResult
) -> tuple[dict[int, Path], dict[int, Path], dict[int, Path]]:
    """Flat sets pair by stem; frame ids are the stems' trailing integers when unambiguous."""

    def by_stem(folder: Path, exts: tuple[str, ...], strip: bool) -> dict[str, Path]:
        out: dict[str, Path] = {}
        if not folder.is_dir():
            return out
        for p in sorted(folder.iterdir()):
            if not (p.is_file() and p.suffix.lower() in exts):
                continue
            stem = p.stem
            if strip:
                for suffix in _MASK_SUFFIXES:
                    if stem.lower().endswith(suffix):
                        stem = stem[: -len(suffix)]
                        break
            if stem in out:
                result.problems.append(f"{p}: stem {stem!r} also used by {out[stem].name}")
                continue
            out[stem] = p
        return out

    img, msk = by_stem(images, IMAGE_EXTS, False), by_stem(masks, IMAGE_EXTS, True)
    dep = by_stem(depths, DEPTH_EXTS, True)
    stems = sorted(set(img) | set(msk))
    ids = [frame_id_of(s) for s in stems]
    if None in ids or len(set(ids)) != len(ids):
        ids = list(range(len(stems)))  # stems are not distinct integers: number them in name order
    id_of = dict(zip(stems, ids))
    return (
        {id_of[s]: p for s, p in img.items()},
        {id_of[s]: p for s, p in msk.items()},
        {id_of[s]: p for s, p in dep.items() if s in id_of},
    )


def _scan_distributed_crop(crop_dir: Path, result: ScanResult) -> None:
    crop = crop_dir.name[len(_DISTRIBUTED_PREFIX) :]
    domain = CROP_DOMAINS.get(crop.lower(), crop.lower())
    subsets = _subdirs(crop_dir)
    if subsets and any(p.is_file() and p.name.lower().startswith("image") for p in subsets[0].iterdir()):
        subsets = [crop_dir]  # frame folders directly under the crop folder
    for subset_dir in subsets:
        subset = subset_dir.name if subset_dir != crop_dir else domain
        _scan_distributed_subset(domain, subset_dir, subset, result)


def _scan_distributed_subset(domain: str, subset_dir: Path, subset: str, result: ScanResult) -> None:
    result.layouts[str(subset_dir)] = "distributed"
    img: dict[int, Path] = {}
    msk: dict[int, Path] = {}
    dep: dict[int, Path] = {}
    for frame_dir in _subdirs(subset_dir):
        n = _frame_number(frame_dir, result)
        if n is None:
            continue
        for target, prefix, exts in (
            (img, "image", IMAGE_EXTS),
            (msk, "segmentation", IMAGE_EXTS),
            (dep, "depth", DEPTH_EXTS),
        ):
            files = sorted(
                p
                for p in frame_dir.iterdir()
                if p.is_file() and p.name.lower().startswith(prefix) and p.suffix.lower() in exts
            )
            if len(files) > 1:
                result.problems.append(f"{frame_dir}: {len(files)} {prefix} files, expected one")
            elif files:
                target[n] = files[0]
    pair_frames(domain, subset, subset_dir, img, msk, dep, result)
