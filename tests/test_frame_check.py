"""Frames are verified once before training; a worker's error is one line naming the file."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from segmin.data.agriseg_loader import AgriSegDataset, DatasetError, find_frames
from segmin.data.frame_check import verify_frames, worker_error_line
from tests.test_train import tiny_config, write_blob_dataset


@pytest.fixture()
def broken_root(tmp_path: Path) -> tuple[Path, Path]:
    root = write_blob_dataset(tmp_path / "data", frames=8, size=32)
    bad = sorted(root.rglob("Image5.png"))[0]
    bad.write_bytes(bad.read_bytes()[:40])  # cut off mid-file: no IEND
    return root, bad


def test_training_stops_before_the_first_step_naming_the_corrupt_file(broken_root, tmp_path):
    from segmin.train.run import fit

    root, _bad = broken_root
    # before: found only if a worker happened to load it (a 15-line dump), or never
    config = tiny_config(root, epochs=1, image_size=32, batch_size=2, tensorboard=False)
    with pytest.raises(DatasetError, match="Image5.png: truncated PNG") as info:
        fit(config, tmp_path / "run")
    assert len(str(info.value).splitlines()) == 1
    assert not (tmp_path / "run" / "last.pt").exists()


def test_the_check_is_cached_by_size_and_mtime(tmp_path, monkeypatch):
    import segmin.data.frame_check as fc

    root = write_blob_dataset(tmp_path / "data", frames=4, size=32)
    frames = find_frames(root)
    cache = tmp_path / "check.json"
    assert verify_frames(frames, cache) == []
    calls = []
    real = fc.check_frame
    monkeypatch.setattr(fc, "check_frame", lambda frame, **k: calls.append(frame) or real(frame, **k))
    assert verify_frames(frames, cache) == [] and calls == []  # unchanged: nothing decoded again
    frames[1].image_path.write_bytes(frames[1].image_path.read_bytes()[:30])
    problems = verify_frames(frames, cache)
    assert [f.image_path for f in calls] == [frames[1].image_path] and "truncated PNG" in problems[0]


def test_a_loader_workers_error_is_one_line_naming_the_file(broken_root):
    root, bad = broken_root
    dataset = AgriSegDataset(root, split="all", image_size=32)
    loader = torch.utils.data.DataLoader(dataset, batch_size=8, num_workers=1)
    with pytest.raises(DatasetError) as info:
        next(iter(loader))
    assert len(str(info.value).splitlines()) > 5  # torch's dump
    line = worker_error_line(info.value)
    assert line == f"{bad}: truncated PNG (no IEND chunk)"
