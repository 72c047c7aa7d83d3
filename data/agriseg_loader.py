"""AgriSeg-style datasets on disk -> paired frames -> (image, mask) tensors: the public facade.

The work is split by job, each in its own small module of `segmin.data`:

- `frames`: `Frame`, `ScanResult`, `DatasetError` and the pairing rule (by frame id, never by
  sorted position; anything that does not pair is a problem, nothing is dropped silently);
- `layouts`: `scan`, which detects the formatted, distributed and flat layouts per folder;
- `domains`: crop families, `resolve_domains` and `find_frames` (a scan whose problems are errors);
- `readers`: `read_image`, `read_mask`, `read_depth`, `load_frame` (each failure names the file);
- `splits`: seeded per-domain train/val splits and split files;
- `dataset`: `AgriSegDataset`, the only one that imports torch.

Code and docs import these names from here. Everything but `AgriSegDataset` is importable
without torch; that one is loaded on first use, so importing this facade never pulls torch in.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from segmin.data.domains import FAMILIES, available_domains, find_frames, resolve_domains
from segmin.data.frames import DEPTH_EXTS, IMAGE_EXTS, DatasetError, Frame, ScanResult, frame_id_of
from segmin.data.layouts import CROP_DOMAINS, scan
from segmin.data.readers import load_frame, read_depth, read_image, read_mask
from segmin.data.splits import load_split, make_splits, save_split

if TYPE_CHECKING:  # at run time it comes from __getattr__, so torch loads only when needed
    from segmin.data.dataset import AgriSegDataset

__all__ = [
    "CROP_DOMAINS",
    "DEPTH_EXTS",
    "FAMILIES",
    "IMAGE_EXTS",
    "AgriSegDataset",
    "DatasetError",
    "Frame",
    "ScanResult",
    "available_domains",
    "find_frames",
    "frame_id_of",
    "load_frame",
    "load_split",
    "make_splits",
    "read_depth",
    "read_image",
    "read_mask",
    "resolve_domains",
    "save_split",
    "scan",
]


def __getattr__(name: str) -> Any:
    """Load `AgriSegDataset` (and with it torch) only when someone asks for it."""
    if name == "AgriSegDataset":
        from segmin.data.dataset import AgriSegDataset

        return AgriSegDataset
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
