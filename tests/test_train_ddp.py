"""A 2-process DDP run (gloo, CPU), started the way torchrun starts it (RANK/WORLD_SIZE env)."""

from __future__ import annotations

import os
import socket
import sys
from pathlib import Path

import torch
import torch.multiprocessing as mp

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _worker(rank: int, world_size: int, port: int, data_root: str, tmp: str) -> None:
    os.environ.update(
        RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE=str(world_size), MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port)
    )
    torch.set_num_threads(1)
    from test_train import tiny_config

    from segmin.train.run import fit

    config = tiny_config(Path(data_root), epochs=2, batch_size=2, swa_start_epoch=1)
    result = fit(config, Path(tmp) / f"run_rank{rank}")
    state = {k: v.detach().clone() for k, v in result.model.state_dict().items()}
    average = {k: v.detach().clone() for k, v in result.swa_model.state_dict().items()}
    torch.save(
        {"model": state, "swa": average, "history": result.history, "world_size": result.world_size},
        Path(tmp) / f"result_rank{rank}.pt",
    )


def test_two_process_gloo_run_gives_identical_weights(tmp_path):
    from test_train import write_blob_dataset

    root = write_blob_dataset(tmp_path / "data", frames=11)
    mp.spawn(_worker, args=(2, _free_port(), str(root), str(tmp_path)), nprocs=2, join=True)
    r0 = torch.load(tmp_path / "result_rank0.pt", weights_only=True)
    r1 = torch.load(tmp_path / "result_rank1.pt", weights_only=True)
    assert r0["world_size"] == r1["world_size"] == 2
    assert r0["model"].keys() == r1["model"].keys()
    differ = [k for k in r0["model"] if not torch.equal(r0["model"][k], r1["model"][k])]
    assert not differ, f"ranks disagree on {differ[:3]}"
    # rank 0 checkpointed exactly the final weights
    last = torch.load(tmp_path / "run_rank0" / "last.pt", weights_only=True)
    assert all(torch.equal(last["model"][k], r0["model"][k]) for k in r0["model"])
    # validation metrics are reduced over both ranks, so both report the same numbers
    assert [round(r["val_iou"], 9) for r in r0["history"]] == [round(r["val_iou"], 9) for r in r1["history"]]
    assert [round(r["train_loss"], 9) for r in r0["history"]] == [round(r["train_loss"], 9) for r in r1["history"]]
    # the weight average's BatchNorm statistics come from both shards: the ranks hold (and rank 0
    # saved) one model
    assert not [k for k in r0["swa"] if not torch.allclose(r0["swa"][k].float(), r1["swa"][k].float())]
    saved = torch.load(tmp_path / "run_rank0" / "swa.pt", weights_only=True)["model"]
    assert all(torch.equal(saved[k], r0["swa"][k]) for k in saved)
    # only rank 0 writes
    assert (tmp_path / "run_rank0" / "best.pt").is_file()
    assert not (tmp_path / "run_rank1").exists()
