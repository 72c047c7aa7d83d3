"""Fixtures shared by several test files.

- `one_thread`: one torch thread for a test (the 2 shared cores are oversubscribed otherwise,
  and no result may depend on the thread count); modules opt in with `pytestmark`.
- `bullet_client`: a fresh pybullet DIRECT client, disconnected afterwards.
- `sigint_delivered`: Python's Ctrl-C handler for a test that raises SIGINT, also when the suite
  was started in the background (`make test &`), where the shell leaves SIGINT ignored.
- `checkpoint`, `frames_dir`, `exported`: one tiny trained checkpoint, its toy frames and one
  full export per session, shared by the export and segmenter tests (each takes seconds on 2 cores).
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path

import pytest
from export_helpers import make_checkpoint, write_frames


@pytest.fixture()
def one_thread() -> Iterator[None]:
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture()
def sigint_delivered() -> Iterator[None]:
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.fixture()
def bullet_client() -> Iterator[int]:
    import pybullet as p

    client = p.connect(p.DIRECT)
    yield client
    p.disconnect(client)


@pytest.fixture(scope="session")
def _tiny_model_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("tiny_checkpoint")


@pytest.fixture(scope="session")
def checkpoint(_tiny_model_folder: Path) -> Path:
    """A tiny LR-ASPP checkpoint trained for a few steps on toy field images (see export_helpers)."""
    return make_checkpoint(_tiny_model_folder / "tiny.pt")


@pytest.fixture(scope="session")
def frames_dir(_tiny_model_folder: Path) -> Path:
    """Six toy frames (PNG and JPG, not at the model size) for calibration and verification."""
    return write_frames(_tiny_model_folder / "frames", count=6)


@pytest.fixture(scope="session")
def exported(tmp_path_factory: pytest.TempPathFactory, checkpoint: Path, frames_dir: Path) -> tuple[Path, dict]:
    """model.onnx (default dynamo exporter) with fp16 and int8 variants, and its report."""
    from segmin.export.pipeline import ExportOptions, export_checkpoint

    out = tmp_path_factory.mktemp("tiny_export") / "model.onnx"
    report = export_checkpoint(
        ExportOptions(checkpoint=checkpoint, out=out, calib_data=frames_dir, fp16=True, int8=True, calib_frames=6)
    )
    return out, report
