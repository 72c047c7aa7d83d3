"""Run-folder logs (rank 0 only): metrics.csv, TensorBoard scalars, prediction previews."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from segmin.common.atomic import write_bytes, write_text

CSV_COLUMNS = ("epoch", "train_loss", "val_loss", "val_iou", "val_pixel_acc", "lr", "seconds")


class RunLogger:
    def __init__(self, out_dir: Path, tensorboard: bool = True) -> None:
        self.out_dir = out_dir
        self.writer = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                self.writer = SummaryWriter(str(out_dir / "tensorboard"))
            except ImportError:  # tensorboard is a dependency; keep training if it is missing
                self.writer = None

    def epoch(self, history: list[dict[str, Any]]) -> None:
        """Rewrite metrics.csv from the whole history (atomic) and add the last row to TensorBoard."""
        lines = [",".join(CSV_COLUMNS)]
        for row in history:
            lines.append(",".join(_fmt(row.get(c)) for c in CSV_COLUMNS))
        write_text(self.out_dir / "metrics.csv", "\n".join(lines) + "\n")
        if self.writer is not None and history:
            row = history[-1]
            for key in CSV_COLUMNS[1:]:
                if row.get(key) is not None:
                    self.writer.add_scalar(key.replace("_", "/", 1), row[key], row["epoch"])
            self.writer.flush()

    def preview(
        self, epoch: int, samples: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]], threshold: float
    ) -> Path | None:
        """PNG grid, one row per sample: image | ground truth | probability | prediction overlay."""
        if not samples:
            return None
        import cv2

        from segmin.data.augment import denormalize
        from segmin.data.overlay import GREEN, tint_mask

        rows = []
        for image, mask, prob in samples:
            rgb = denormalize(image.float().numpy())
            truth = (mask[0].numpy() > 0.5).astype(np.uint8) * 255
            p = prob[0].float().numpy()
            prob_img = (np.clip(p, 0, 1) * 255).astype(np.uint8)
            overlay = tint_mask(rgb, p > threshold, GREEN, opacity=0.5)
            gray = [np.repeat(x[..., None], 3, axis=2) for x in (truth, prob_img)]
            rows.append(np.concatenate([rgb, gray[0], gray[1], overlay], axis=1))
        grid = np.concatenate(rows, axis=0)
        ok, data = cv2.imencode(".png", cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
        if not ok:
            return None
        path = self.out_dir / "previews" / f"epoch_{epoch:03d}.png"
        write_bytes(path, data.tobytes())
        return path

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def _fmt(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)
