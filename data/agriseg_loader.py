"""AgriSeg-style datasets on disk -> paired frames -> (image, mask) tensors.

Three layouts are read, detected per folder while scanning `root`:

- formatted (what AgriSeg's training code and our synthetic writer use):
  `<domain>/<domain>_<k>/images/ImageN/<file>`, `.../masks/ImageN/<file>`, `.../depths/ImageN/<file>`
- distributed (the AgriSeg download):
  `Synthetic_Dataset_<Crop>/<subset>/ImageN/{Image*, Segmentation*, Depth*}`
- flat real sets: `<name>/images/<stem>.jpg|png` + `<name>/masks/<stem>.png` (matching stems).

Frames are paired by their integer frame id (the N of `ImageN`, or the stem for flat sets), never
by sorted position: the reference code pairs by position, which silently mispairs as soon as one
folder is missing. Anything that does not pair is a problem: an error by default, or logged and
skipped with `skip_unpaired=True`. Nothing is dropped silently.
"""

from __future__ import annotations

import fnmatch
import json
import logging
import os
import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from segmin.common.atomic import write_json

log = logging.getLogger(__name__)

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
DEPTH_EXTS = (".png", ".exr", ".tif", ".tiff")

# Crop families of the paper. Members are domain names, globs or prefixes (see resolve_domains).
# `tree` is the domain name the distributed layout's Synthetic_Dataset_Big_Trees gets.
FAMILIES: dict[str, tuple[str, ...]] = {
    "trees": ("tree_1", "tree_2", "tree", "pear"),
    "vineyards": ("vineyard", "vineyard_pergola"),
    "synth_trees": ("synth_*tree*", "synth_*pear*"),
    "synth_vineyards": ("synth_*vineyard*", "synth_*pergola*"),
}

# Distributed-layout crop folder -> formatted domain name (so families mean the same thing).
CROP_DOMAINS: dict[str, str] = {
    "big_trees": "tree",
    "pear": "pear",
    "vineyard_straight": "vineyard",
    "vineyard_pergolato": "vineyard_pergola",
}

_DISTRIBUTED_PREFIX = "Synthetic_Dataset_"
_FRAME_DIR = re.compile(r"^[A-Za-z_]*?(\d+)$")
_TRAILING_INT = re.compile(r"(\d+)(?!.*\d)")
_MASK_SUFFIXES = ("_mask", "_masks", "_seg", "_label", "_segmentation")
_PNG_END = b"IEND\xaeB`\x82"


class DatasetError(ValueError):
    """Bad dataset input; the message names the file or folder and the problem."""


@dataclass(frozen=True)
class Frame:
    """One labelled frame: where its image, mask and (optional) depth live."""

    domain: str
    subset: str
    frame_id: int
    image_path: Path
    mask_path: Path
    depth_path: Path | None = None

    @property
    def key(self) -> tuple[str, str, int]:
        """The identity used in split files: (domain, subset, frame_id)."""
        return (self.domain, self.subset, self.frame_id)


@dataclass
class ScanResult:
    """Everything `scan` found: paired frames, problems (strings naming files) and layouts."""

    frames: list[Frame] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    unpaired: list[str] = field(default_factory=list)
    layouts: dict[str, str] = field(default_factory=dict)  # subset folder -> layout name


# ----------------------------------------------------------------------------- scanning


def frame_id_of(name: str) -> int | None:
    """The integer N of `ImageN` / `Image0010.png` / `frame_12`, or None when there is none."""
    stem = Path(name).stem if Path(name).suffix.lower() in IMAGE_EXTS + DEPTH_EXTS else name
    match = _TRAILING_INT.search(stem)
    return int(match.group(1)) if match else None


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
        crop = parent[len(_DISTRIBUTED_PREFIX):] if parent.startswith(_DISTRIBUTED_PREFIX) else folder.name
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
    _pair(domain, subset, folder, img, msk, dep, result)


def _per_frame_dirs(parent: Path, exts: tuple[str, ...], result: ScanResult) -> dict[int, Path]:
    """{N: the file inside parent/ImageN/}; duplicates and empty folders are problems."""
    found: dict[int, Path] = {}
    for sub in _subdirs(parent):
        match = _FRAME_DIR.match(sub.name)
        if not match:
            result.problems.append(f"{sub}: folder name has no frame number (expected ImageN)")
            continue
        n = int(match.group(1))
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
    crop = crop_dir.name[len(_DISTRIBUTED_PREFIX):]
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
        match = _FRAME_DIR.match(frame_dir.name)
        if not match:
            result.problems.append(f"{frame_dir}: folder name has no frame number (expected ImageN)")
            continue
        n = int(match.group(1))
        for target, prefix, exts in ((img, "image", IMAGE_EXTS), (msk, "segmentation", IMAGE_EXTS),
                                     (dep, "depth", DEPTH_EXTS)):
            files = sorted(p for p in frame_dir.iterdir()
                           if p.is_file() and p.name.lower().startswith(prefix) and p.suffix.lower() in exts)
            if len(files) > 1:
                result.problems.append(f"{frame_dir}: {len(files)} {prefix} files, expected one")
            elif files:
                target[n] = files[0]
    _pair(domain, subset, subset_dir, img, msk, dep, result)


def _pair(domain: str, subset: str, folder: Path, img: dict[int, Path], msk: dict[int, Path],
          dep: dict[int, Path], result: ScanResult) -> None:
    for n in sorted(set(img) | set(msk)):
        if n not in img:
            result.unpaired.append(f"{msk[n]}: mask of frame {n} has no image")
        elif n not in msk:
            result.unpaired.append(f"{img[n]}: image of frame {n} has no mask")
        else:
            result.frames.append(Frame(domain, subset, n, img[n], msk[n], dep.get(n)))
    if not img and not msk:
        result.problems.append(f"{folder}: empty (no image or mask files)")


# ----------------------------------------------------------------------------- domains


def available_domains(frames: Iterable[Frame]) -> list[str]:
    return sorted({f.domain for f in frames})


def resolve_domains(spec: Sequence[str] | str | None, available: Sequence[str]) -> list[str]:
    """Turn a list of family names, domain names, globs or prefixes into domain names.

    Each item is, in order of precedence: a family (`trees`, `vineyards`, `synth_trees`,
    `synth_vineyards`), an exact domain, a glob (`synth_*vineyard*`), or a prefix
    (`synth_train_vineyard` matches `synth_train_vineyard_a`). An item that matches nothing is an
    error (listing what exists), except family members, of which at least one must match.
    """
    if spec is None:
        return sorted(available)
    items = [spec] if isinstance(spec, str) else list(spec)
    chosen: list[str] = []
    for item in items:
        if item in FAMILIES:
            found = [d for member in FAMILIES[item] for d in _match(member, available)]
            if not found:
                raise DatasetError(
                    f"family {item!r} ({', '.join(FAMILIES[item])}): none of its domains is present; "
                    f"available: {', '.join(available) or 'none'}"
                )
        else:
            found = _match(item, available)
            if not found:
                raise DatasetError(
                    f"domain {item!r}: no frames found for it; available: {', '.join(available) or 'none'}"
                )
        chosen.extend(d for d in found if d not in chosen)
    return chosen


def _match(pattern: str, available: Sequence[str]) -> list[str]:
    if pattern in available:
        return [pattern]
    if any(c in pattern for c in "*?["):
        return sorted(d for d in available if fnmatch.fnmatchcase(d, pattern))
    return sorted(d for d in available if d.startswith(pattern + "_") or d.startswith(pattern + "-"))


def find_frames(root: str | Path, domains: Sequence[str] | str | None = None, *,
                skip_unpaired: bool = False) -> list[Frame]:
    """All paired frames under `root` of the chosen domains (all when None).

    Raises DatasetError naming the files when anything is unpaired (unless `skip_unpaired`, which
    logs each one), when the layout has other problems, or when a chosen domain is empty.
    """
    result = scan(root)
    if result.unpaired:
        if skip_unpaired:
            for message in result.unpaired:
                log.warning("skipping unpaired frame: %s", message)
        else:
            result.problems.extend(result.unpaired)
    if result.problems:
        shown = result.problems[:20]
        more = f"\n  ... and {len(result.problems) - 20} more" if len(result.problems) > 20 else ""
        raise DatasetError(f"{root}: {len(result.problems)} problem(s):\n  " + "\n  ".join(shown) + more)
    chosen = set(resolve_domains(domains, available_domains(result.frames)))
    return [f for f in result.frames if f.domain in chosen]


# ----------------------------------------------------------------------------- reading files


def _read_bytes_checked(path: Path) -> bytes:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from exc
    if not data:
        raise DatasetError(f"{path}: empty file")
    suffix = path.suffix.lower()
    # libjpeg and libpng decode truncated files with only a warning; check the end markers.
    if suffix == ".png" and not data.rstrip(b"\x00").endswith(_PNG_END):
        raise DatasetError(f"{path}: truncated PNG (no IEND chunk)")
    if suffix in (".jpg", ".jpeg") and not data.rstrip(b"\x00\r\n ").endswith(b"\xff\xd9"):
        raise DatasetError(f"{path}: truncated JPEG (no end-of-image marker)")
    return data


def read_image(path: str | Path) -> np.ndarray:
    """RGB uint8 H x W x 3; raises DatasetError naming the file when unreadable or truncated."""
    import cv2

    path = Path(path)
    data = _read_bytes_checked(path)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise DatasetError(f"{path}: unreadable image")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_mask(path: str | Path) -> np.ndarray:
    """Binary uint8 H x W (1 = crop): single channel or RGB(A), any non-zero value is crop."""
    import cv2

    path = Path(path)
    data = _read_bytes_checked(path)
    mask = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if mask is None:
        raise DatasetError(f"{path}: unreadable mask")
    if mask.ndim == 3:
        mask = mask[..., :3].max(axis=2) if mask.shape[2] >= 3 else mask[..., 0]
    return (mask > 0).astype(np.uint8)


def read_depth(path: str | Path) -> np.ndarray:
    """Depth in metres, float32 H x W (0 = invalid). PNG/TIFF hold millimetres; EXR holds metres."""
    import cv2

    path = Path(path)
    if path.suffix.lower() == ".exr":
        os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
        if depth is None:
            raise DatasetError(
                f"{path}: cannot read EXR depth (this OpenCV build may lack OpenEXR; set "
                "OPENCV_IO_ENABLE_OPENEXR=1 before starting Python, or convert to uint16 mm PNG)"
            )
        depth = depth[..., 0] if depth.ndim == 3 else depth
        return np.nan_to_num(depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    data = _read_bytes_checked(path)
    depth = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if depth is None:
        raise DatasetError(f"{path}: unreadable depth image")
    depth = depth[..., 0] if depth.ndim == 3 else depth
    if depth.dtype.kind == "f":
        return depth.astype(np.float32)
    return depth.astype(np.float32) / 1000.0


def load_frame(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 HxWx3, mask uint8 HxW of 0/1); size mismatch is an error naming both files."""
    image = read_image(frame.image_path)
    mask = read_mask(frame.mask_path)
    if image.shape[:2] != mask.shape[:2]:
        raise DatasetError(
            f"{frame.mask_path}: mask size {mask.shape[1]}x{mask.shape[0]} does not match image "
            f"{frame.image_path} size {image.shape[1]}x{image.shape[0]}"
        )
    return image, mask


# ----------------------------------------------------------------------------- splits


def make_splits(frames: Sequence[Frame], val_fraction: float = 0.1, seed: int = 0) -> dict[str, list[Frame]]:
    """Seeded split per domain: the same frames, fraction and seed always give the same split.

    Each domain is shuffled with its own generator (seeded by `seed` and the domain name), so
    adding a domain does not change the split of the others. A domain of two or more frames
    puts at least one frame in validation when `val_fraction` > 0.
    """
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction={val_fraction}: must be in [0, 1)")
    splits: dict[str, list[Frame]] = {"train": [], "val": []}
    by_domain: dict[str, list[Frame]] = {}
    for frame in sorted(frames, key=lambda f: f.key):
        by_domain.setdefault(frame.domain, []).append(frame)
    for domain, members in sorted(by_domain.items()):
        rng = np.random.default_rng([seed, zlib.crc32(domain.encode())])
        order = rng.permutation(len(members))
        n_val = int(round(len(members) * val_fraction))
        if val_fraction > 0 and n_val == 0 and len(members) >= 2:
            n_val = 1
        val_idx = set(order[:n_val].tolist())
        for i, frame in enumerate(members):
            splits["val" if i in val_idx else "train"].append(frame)
    return splits


def save_split(path: str | Path, splits: dict[str, list[Frame]], **meta: Any) -> None:
    """Write split lists as JSON of [domain, subset, frame_id] keys (plus `meta`), atomically."""
    write_json(path, {
        "format": "segmin-split-v1",
        **meta,
        **{name: [list(f.key) for f in frames] for name, frames in splits.items()},
    })


def load_split(path: str | Path, frames: Sequence[Frame]) -> dict[str, list[Frame]]:
    """Re-select `frames` by a saved split file; a listed frame that is missing is an error."""
    path = Path(path)
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: bad JSON or not UTF-8 text at all
        raise DatasetError(f"{path}: cannot read split file ({exc})") from exc
    if not isinstance(content, dict) or content.get("format") != "segmin-split-v1":
        raise DatasetError(f"{path}: not a segmin split file")
    index = {f.key: f for f in frames}
    splits: dict[str, list[Frame]] = {}
    for name in ("train", "val"):
        chosen = []
        for key in content.get(name, []):
            try:
                key = (str(key[0]), str(key[1]), int(key[2]))
            except (TypeError, ValueError, IndexError, KeyError):
                raise DatasetError(f"{path}: {name} entry {key!r} is not [domain, subset, frame_id]") from None
            if key not in index:
                raise DatasetError(f"{path}: {name} frame {key} is not in the dataset")
            chosen.append(index[key])
        splits[name] = chosen
    return splits


# ----------------------------------------------------------------------------- dataset

try:  # torch is a dependency of the package, but keep the scanning helpers importable without it
    from torch.utils.data import Dataset as _TorchDataset
except ImportError:  # pragma: no cover
    _TorchDataset = object  # type: ignore[assignment,misc]


class AgriSegDataset(_TorchDataset):
    """(image float 3xHxW ImageNet-normalised, mask float 1xHxW of 0/1) samples.

    `domains`: families, domain names, globs or prefixes (see `resolve_domains`); None = all.
    `split`: "train", "val" or "all"; splits are seeded per domain (`make_splits`), or read from
    `split_file` when given (exact reproduction of an earlier run).
    `transform`: a `data.augment.SegTransform` (or any callable `(image, mask, seed) -> (x, y)`);
    default: resize to `image_size` and normalise.
    An index may be an int or `(epoch, int)`: with the tuple the augmentation is seeded from
    (`seed`, epoch, index), so a run and its resume see exactly the same samples whatever the
    number of loader workers.
    """

    def __init__(
        self,
        root: str | Path,
        domains: Sequence[str] | str | None = None,
        split: str = "train",
        val_fraction: float = 0.1,
        seed: int = 0,
        transform: Callable[..., tuple[Any, Any]] | None = None,
        image_size: int | tuple[int, int] = 224,
        *,
        skip_unpaired: bool = False,
        split_file: str | Path | None = None,
        frames: Sequence[Frame] | None = None,
    ) -> None:
        if split not in ("train", "val", "all"):
            raise ValueError(f"split={split!r}: expected 'train', 'val' or 'all'")
        self.root = Path(root)
        all_frames = list(frames) if frames is not None else find_frames(root, domains, skip_unpaired=skip_unpaired)
        if not all_frames:
            raise DatasetError(f"{root}: no frames for domains {domains}")
        if split_file is not None:
            self.splits = load_split(split_file, all_frames)
        else:
            self.splits = make_splits(all_frames, val_fraction, seed)
        self.frames: list[Frame] = list(all_frames) if split == "all" else self.splits[split]
        if not self.frames:
            raise DatasetError(f"{root}: split {split!r} is empty (val_fraction={val_fraction}, {len(all_frames)} frames)")
        self.split = split
        self.seed = seed
        self.image_size = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
        if len(self.image_size) != 2 or not all(isinstance(v, int) and v >= 1 for v in self.image_size):
            raise ValueError(f"image_size={image_size!r}: expected a side or (height, width) of integers >= 1")
        if transform is None:
            from segmin.data.augment import eval_transform

            transform = eval_transform(self.image_size)
        self.transform = transform

    def __len__(self) -> int:
        return len(self.frames)

    def save_split(self, path: str | Path) -> None:
        save_split(path, self.splits, seed=self.seed)

    def sample_seed(self, epoch: int, index: int) -> int:
        return int(np.random.SeedSequence([self.seed, epoch, index]).generate_state(1)[0])

    def __getitem__(self, item: int | tuple[int, int]):
        if isinstance(item, tuple):
            epoch, index = item
            seed: int | None = self.sample_seed(epoch, index)
        else:
            index, seed = item, None
        image, mask = load_frame(self.frames[index])
        return self.transform(image, mask, seed)
