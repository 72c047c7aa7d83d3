"""Dataset writer: AgriSeg layout, determinism across workers and shards, resume after a kill."""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from synth_helpers import tiny, write_spec

from segmin.app.cli import main as segmin_main
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.spec import spec_from_dict
from segmin.data.synth.writer import RenderJob, render_dataset

ROOT = Path(__file__).resolve().parents[1]
CAM = CameraModel(width=32, height=32)


def _job(out, frames=6, **kw) -> RenderJob:
    kw.setdefault("camera", CAM)
    return RenderJob(spec=spec_from_dict(tiny()), out=out, frames=frames, progress=False, **kw)


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_layout_is_agriseg_formatted(tmp_path):
    summary = render_dataset(_job(tmp_path, frames=6, frames_per_subset=4))
    assert summary["written"] == 6
    domain = tmp_path / "synth_tiny_vineyard"
    assert sorted(p.name for p in domain.iterdir()) == ["synth_tiny_vineyard_1", "synth_tiny_vineyard_2"]
    pattern = re.compile(
        r"synth_tiny_vineyard_(\d)/(?:images/Image(\d+)/Image(\d+)\.png|masks/Image(\d+)/Segmentation(\d+)\.png"
        r"|depths/Image(\d+)/Depth(\d+)\.png|meta\.json)$"
    )
    files = [str(p.relative_to(domain)) for p in domain.rglob("*") if p.is_file()]
    assert len(files) == 6 * 3 + 2
    for f in files:
        m = pattern.match(f)
        assert m, f"unexpected file {f}"
        numbers = {int(g) for g in m.groups()[1:] if g is not None}
        assert len(numbers) <= 1, f"folder and file ids differ in {f}"
        if numbers:
            assert int(m.group(1)) == numbers.pop() // 4 + 1
    for n in range(6):
        sub = domain / f"synth_tiny_vineyard_{n // 4 + 1}"
        rgb = cv2.imread(str(sub / f"images/Image{n}/Image{n}.png"), cv2.IMREAD_UNCHANGED)
        mask = cv2.imread(str(sub / f"masks/Image{n}/Segmentation{n}.png"), cv2.IMREAD_UNCHANGED)
        depth = cv2.imread(str(sub / f"depths/Image{n}/Depth{n}.png"), cv2.IMREAD_UNCHANGED)
        assert rgb.shape == (32, 32, 3) and rgb.dtype == np.uint8
        assert mask.shape == (32, 32) and mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
        assert depth.shape == (32, 32) and depth.dtype == np.uint16
        assert 0 < depth.max() < 65535 and (depth > 0).mean() > 0.3  # millimetres
    meta = json.loads((domain / "synth_tiny_vineyard_2" / "meta.json").read_text())
    assert sorted(meta["frames"], key=int) == ["4", "5"]
    assert meta["intrinsics"]["width"] == 32 and meta["world"]["name"] == "tiny_vineyard"
    pose = np.array(meta["frames"]["4"]["camera_pose"])
    assert pose.shape == (4, 4) and np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-5)


def test_bytes_do_not_depend_on_workers_or_shards(tmp_path):
    render_dataset(_job(tmp_path / "one", frames=12, workers=1))
    render_dataset(_job(tmp_path / "two", frames=12, workers=2))
    for i in range(3):
        render_dataset(_job(tmp_path / "shards", frames=12, shard=(i, 3)))
    one = _tree(tmp_path / "one")
    assert one == _tree(tmp_path / "two")
    assert one == _tree(tmp_path / "shards")
    # A different dataset seed gives different frames.
    render_dataset(_job(tmp_path / "seed", frames=2, seed=123))
    other = _tree(tmp_path / "seed")
    key = "synth_tiny_vineyard/synth_tiny_vineyard_1/images/Image0/Image0.png"
    assert other[key] != one[key]


def test_resume_after_killing_a_run(tmp_path):
    spec_path = write_spec(tmp_path / "tiny.yaml", tiny())
    out = tmp_path / "killed"
    frames = 300
    cmd = [
        sys.executable,
        "-m",
        "segmin.app.cli",
        "synth",
        "render",
        "--world",
        spec_path,
        "--frames",
        str(frames),
        "--out",
        str(out),
        "--workers",
        "2",
        "--size",
        "32",
        "--no-progress",
    ]
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    images = out / "synth_tiny_vineyard" / "synth_tiny_vineyard_1" / "images"
    deadline = time.time() + 90
    try:
        while time.time() < deadline and proc.poll() is None:
            if images.is_dir() and sum(1 for _ in images.glob("Image*")) >= 20:
                break
            time.sleep(0.01)
        assert proc.poll() is None, "the run finished before it could be killed: " + proc.stderr.read().decode()[-500:]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # the render process and its workers, mid-run
        proc.wait()
    done_before = sum(1 for _ in images.glob("Image*"))
    assert 0 < done_before < frames
    # Whatever is visible is whole: every ImageN/ folder holds exactly its one PNG.
    for kind_dir in images.parent.iterdir():
        if kind_dir.is_dir():
            for folder in kind_dir.glob("Image*"):
                assert [p.name.split(".")[0] for p in folder.iterdir()] in (
                    [folder.name],
                    [folder.name.replace("Image", "Segmentation")],
                    [folder.name.replace("Image", "Depth")],
                ), f"half-written {folder}"
    assert segmin_main(cmd[3:]) == 0  # rerun: continues where the killed run stopped
    reference = tmp_path / "reference"
    render_dataset(RenderJob(spec=spec_from_dict(tiny()), out=reference, frames=frames, camera=CAM, progress=False))
    assert _tree(out) == _tree(reference)
    assert not list(out.rglob(".*")), "staging or temporary files left behind"


def test_unwritable_output_fails_before_rendering(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    built = []
    import segmin.data.synth.world as world_module

    monkeypatch.setattr(world_module, "build_world", lambda *a, **k: built.append(1))
    with pytest.raises(NotADirectoryError, match="is a file, not a folder"):
        render_dataset(_job(blocker / "out"))
    assert (
        segmin_main(["synth", "render", "--world", "straight_vineyard", "--frames", "1", "--out", str(blocker / "out")])
        == 2
    )
    assert not built


def test_rerun_with_other_settings_is_refused_unless_overwrite(tmp_path):
    render_dataset(_job(tmp_path, frames=2))
    with pytest.raises(ValueError, match="dataset_seed"):
        render_dataset(_job(tmp_path, frames=2, seed=77))
    summary = render_dataset(_job(tmp_path, frames=2, seed=77, overwrite=True))
    assert summary["written"] == 2 and summary["skipped"] == 0
    again = render_dataset(_job(tmp_path, frames=3, seed=77))
    assert again["written"] == 1 and again["skipped"] == 2


def test_a_second_writer_is_refused_and_a_dead_writers_lock_is_taken_over(tmp_path, caplog):
    """A second render on the same --out deleted the first one's staging folders.

    Taking over a dead writer's lock is logged as a warning (whether or not a progress bar shows)."""
    from segmin.common.lock import LockHeldError
    from segmin.data.synth.writer import lock_path

    job = _job(tmp_path, frames=2)
    staging = tmp_path / "synth_tiny_vineyard" / "synth_tiny_vineyard_1" / "images" / ".Image0.abc.staging"
    staging.mkdir(parents=True)  # the first writer's frame in flight
    code = (
        "import sys, time\nfrom segmin.common.lock import writer_lock\n"
        "with writer_lock(sys.argv[1], 'test'):\n    print('held', flush=True)\n    time.sleep(60)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code, str(lock_path(job))], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(LockHeldError, match=f"pid {holder.pid} on "):
            render_dataset(job)
        assert staging.is_dir()  # untouched
    finally:
        holder.kill()  # like kill -9: no clean-up, the lock file still names it
        holder.wait()
    assert f'"pid": {holder.pid}' in lock_path(job).read_text()
    with caplog.at_level(logging.WARNING, logger="segmin.data.synth.writer"):
        assert render_dataset(job)["written"] == 2  # stale lock taken over
    assert [r.getMessage() for r in caplog.records if r.name == "segmin.data.synth.writer"] == [
        f"{lock_path(job)}: taking over the lock of pid {holder.pid} on {socket.gethostname()}, "
        "which has stopped; resuming its work"
    ]
    assert not staging.exists()  # and now the clean-up of the dead writer's leftovers is right
    assert not lock_path(job).exists()  # released


def test_a_killed_writers_lock_is_free_while_its_forked_workers_still_live(tmp_path):
    """CI, 2026-12-02: a rerun right after kill -9 of a render was refused while its dying fork
    workers still held copies of the locked descriptor."""
    from segmin.data.synth.writer import lock_path

    job = _job(tmp_path, frames=2)
    # The worker itself reports that it runs: a fork's child runs its at-fork handlers before
    # anything else, so the kill below cannot come before the child was scheduled (under load
    # the parent could print the child's pid and be killed while the child had not run yet).
    code = (
        "import os, sys, time\nfrom segmin.common.lock import writer_lock\n"
        "with writer_lock(sys.argv[1], 'test'):\n"
        "    if os.fork() == 0:\n"
        "        print(os.getpid(), flush=True)\n        time.sleep(60)\n        os._exit(0)\n"
        "    time.sleep(60)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code, str(lock_path(job))], stdout=subprocess.PIPE, text=True)
    worker = int(holder.stdout.readline())
    try:
        holder.kill()  # the writer dies; its forked worker lives on
        holder.wait()
        os.kill(worker, 0)  # still alive
        assert render_dataset(job)["written"] == 2
    finally:
        os.kill(worker, signal.SIGKILL)


def test_a_rerun_with_fewer_frames_is_refused_and_more_frames_extend(tmp_path):
    """--frames 3 after --frames 5 exited 0 and rewrote meta.json for 3 frames."""
    domain = tmp_path / "synth_tiny_vineyard"
    render_dataset(_job(tmp_path, frames=5))
    meta = domain / "synth_tiny_vineyard_1" / "meta.json"
    before = meta.read_bytes()
    with pytest.raises(ValueError, match="already holds 5 frames.*--frames 5"):
        render_dataset(_job(tmp_path, frames=3))
    assert meta.read_bytes() == before
    summary = render_dataset(_job(tmp_path, frames=7))  # an extension: resumed, two new frames
    assert (summary["written"], summary["skipped"]) == (2, 5)
    assert sorted(json.loads(meta.read_text())["frames"], key=int) == [str(n) for n in range(7)]
    assert render_dataset(_job(tmp_path, frames=2, overwrite=True))["written"] == 2
