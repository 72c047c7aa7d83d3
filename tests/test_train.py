"""Training: metrics, loss decreases, run folder contents, exact resume (also after Ctrl-C), configs."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from segmin.common.config import ConfigError
from segmin.models.checkpoint import load_model
from segmin.train.config import TrainConfig, load_train_config
from segmin.train.loop import SegLoss, StepContext, train_step
from segmin.train.metrics import SegMetrics, count_pixels

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "train"


def write_blob_dataset(
    root: Path, domain: str = "synth_vineyard_a", frames: int = 10, size: int = 64, seed: int = 0
) -> Path:
    """Formatted-layout frames: green blobs (crop) on brown soil under a blue sky."""
    rng = np.random.default_rng(seed)
    for n in range(1, frames + 1):
        mask = np.zeros((size, size), np.uint8)
        for _ in range(3):
            centre = (int(rng.integers(0, size)), int(rng.integers(size // 4, size)))
            cv2.circle(mask, centre, int(rng.integers(5, 14)), 255, -1)
        image = np.zeros((size, size, 3), np.uint8)  # BGR
        image[: size // 3] = (200, 150, 90)
        image[size // 3 :] = (40, 70, 110)
        image[mask > 0] = (40, 170, 50)
        image = np.clip(image.astype(int) + rng.integers(-15, 15, image.shape), 0, 255).astype(np.uint8)
        sub = root / domain / f"{domain}_1"
        for kind, name, data in (("images", f"Image{n}.png", image), ("masks", f"Segmentation{n}.png", mask)):
            path = sub / kind / f"Image{n}" / name
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), data)
    return root


def tiny_config(root: Path, **overrides) -> TrainConfig:
    raw = {
        "family": "vineyards",
        "data": {"root": str(root), "domains": ["synth_vineyards"], "val_fraction": 0.3},
        "backbone_weights": "none",
        "image_size": 64,
        "epochs": 2,
        "batch_size": 3,
        "lr": 1e-3,
        "num_workers": 0,
        "threads": 1,
        "progress": False,
        "preview_images": 2,
        "device": "cpu",
    }
    for key, value in overrides.items():
        raw[key] = value
    from segmin.common.config import from_dict

    return from_dict(TrainConfig, raw)


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest: one torch thread per test


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory) -> Path:
    return write_blob_dataset(tmp_path_factory.mktemp("blobs"))


# ----------------------------------------------------------------------------- metrics and loss


def test_iou_is_summed_over_the_whole_set_not_averaged_over_batches():
    metrics = SegMetrics(threshold=0.5)
    big = 10.0
    # batch 1: one sample, 4 pixels, prediction = truth on 2 crop pixels -> IoU 1
    logits1 = torch.tensor([big, big, -big, -big]).view(1, 1, 2, 2)
    target1 = torch.tensor([1.0, 1.0, 0.0, 0.0]).view(1, 1, 2, 2)
    # batch 2: predicted 4 crop pixels, 1 true -> inter 1, union 4
    logits2 = torch.full((1, 1, 2, 2), big)
    target2 = torch.tensor([1.0, 0.0, 0.0, 0.0]).view(1, 1, 2, 2)
    metrics.update(logits1, target1, loss_sum=1.0)
    metrics.update(logits2, target2, loss_sum=3.0)
    result = metrics.compute()
    assert result["iou"] == pytest.approx(3 / 6)  # a mean of batch IoUs would say (1 + 0.25) / 2
    assert result["pixel_acc"] == pytest.approx(5 / 8)
    assert result["loss"] == pytest.approx(2.0)
    empty = SegMetrics()
    empty.update(torch.full((1, 1, 2, 2), -big), torch.zeros(1, 1, 2, 2))
    assert empty.compute()["iou"] == 1.0


def test_count_pixels_gives_tp_fp_fn_tn_in_the_order_the_core_reads():
    pred = torch.tensor([[True, True, False, False], [True, False, False, False]])
    truth = torch.tensor([[True, False, True, False], [True, True, False, False]])
    # TP at (0,0), (1,0); FP at (0,1); FN at (0,2), (1,1); TN at (0,3), (1,2), (1,3)
    assert count_pixels(pred, truth).tolist() == [2, 1, 2, 3]
    assert count_pixels(pred[:0], truth[:0]).tolist() == [0, 0, 0, 0]


def test_training_predicts_crop_strictly_above_the_threshold():
    metrics = SegMetrics(threshold=0.5)
    # sigmoid(0) = 0.5 is not above 0.5: background (eval-seg and export verification use >= instead)
    metrics.update(
        torch.tensor([0.0, 0.0, 10.0, -10.0]).view(1, 1, 2, 2), torch.tensor([1.0, 0, 1, 0]).view(1, 1, 2, 2)
    )
    result = metrics.compute()
    assert result["iou"] == 0.5  # TP 1 / (TP 1 + FN 1)
    assert result["pixel_acc"] == 0.75  # 3 of 4 pixels right


def test_dice_term_adds_to_bce():
    logits = torch.zeros(2, 1, 4, 4)
    target = torch.ones(2, 1, 4, 4)
    bce = SegLoss()(logits, target)
    assert bce.item() == pytest.approx(np.log(2), rel=1e-5)
    assert SegLoss(dice_weight=1.0)(logits, target).item() > bce.item() + 0.3


def test_loss_decreases_on_a_tiny_overfit_set(dataset_root):
    from segmin.data.agriseg_loader import AgriSegDataset

    torch.manual_seed(0)
    ds = AgriSegDataset(dataset_root, split="all", image_size=64)
    images = torch.stack([ds[i][0] for i in range(4)])
    masks = torch.stack([ds[i][1] for i in range(4)])
    from segmin.models import build_model

    model = build_model("none")
    ctx = StepContext(model, torch.optim.Adam(model.parameters(), lr=1e-3), SegLoss(), torch.device("cpu"))
    losses = [train_step(ctx, images, masks).mean().item() for _ in range(25)]
    assert losses[-1] < 0.5 * losses[0], losses


# ----------------------------------------------------------------------------- the run folder


def test_fit_writes_checkpoints_logs_and_previews(dataset_root, tmp_path):
    from segmin.train.run import train_model

    out = tmp_path / "run"
    best = train_model(tiny_config(dataset_root), out)
    assert best == out / "best.pt"
    for name in ("best.pt", "last.pt", "metrics.csv", "split.json", "config.yaml"):
        assert (out / name).is_file(), name
    assert sorted(p.name for p in (out / "previews").iterdir()) == ["epoch_001.png", "epoch_002.png"]
    assert any((out / "tensorboard").iterdir())
    rows = list(csv.DictReader((out / "metrics.csv").open()))
    assert [r["epoch"] for r in rows] == ["1", "2"]
    assert all(0.0 <= float(r["val_iou"]) <= 1.0 for r in rows)
    for name in ("best.pt", "last.pt"):  # nothing but tensors and plain data inside
        payload = torch.load(out / name, map_location="cpu", weights_only=True)
        assert payload["model_info"]["backbone_weights"] == "none"
    last = torch.load(out / "last.pt", map_location="cpu", weights_only=True)
    assert last["training_state"]["epoch"] == 2 and last["training_state"]["step"] == 0
    assert isinstance(last["training_state"]["rng"]["torch"], torch.Tensor)
    _model, info = load_model(out / "best.pt")
    assert info["input_size"] == [64, 64] and info["family"] == "vineyards"
    preview = cv2.imread(str(out / "previews" / "epoch_002.png"))
    assert preview.shape == (2 * 64, 4 * 64, 3)


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, map_location="cpu", weights_only=True)["model"]


def _assert_same_weights(a: Path, b: Path) -> None:
    wa, wb = _weights(a), _weights(b)
    assert wa.keys() == wb.keys()
    different = [k for k in wa if not torch.equal(wa[k], wb[k])]
    assert not different, f"{len(different)} tensors differ, e.g. {different[:3]}"


def test_resume_gives_the_same_weights_as_an_uninterrupted_run(dataset_root, tmp_path):
    from segmin.train.run import fit

    config = tiny_config(dataset_root, epochs=3, schedule="step", step_size=1, gamma=0.5, bn_momentum=0.2)
    fit(config, tmp_path / "straight")
    fit(
        tiny_config(dataset_root, epochs=1, schedule="step", step_size=1, gamma=0.5, bn_momentum=0.2),
        tmp_path / "resumed",
    )
    result = fit(config, tmp_path / "resumed", resume=True)
    assert {m.momentum for m in result.model.modules() if isinstance(m, torch.nn.BatchNorm2d)} == {0.2}
    assert [r["epoch"] for r in result.history] == [1, 2, 3]
    _assert_same_weights(tmp_path / "straight" / "last.pt", tmp_path / "resumed" / "last.pt")
    straight = (tmp_path / "straight" / "metrics.csv").read_text().splitlines()
    resumed = (tmp_path / "resumed" / "metrics.csv").read_text().splitlines()
    strip = [lambda lines: [",".join(line.split(",")[:-1]) for line in lines]][0]  # drop the seconds column
    assert strip(straight) == strip(resumed)


def test_weight_averaging_averages_the_last_epochs_recomputes_batchnorm_and_resumes(dataset_root, tmp_path):
    from segmin.train.run import fit, train_model

    one = tiny_config(dataset_root, epochs=1, swa_start_epoch=1, bn_momentum=0.2)
    two = tiny_config(dataset_root, epochs=2, swa_start_epoch=1, bn_momentum=0.2)
    fit(one, tmp_path / "one")
    assert train_model(two, tmp_path / "two") == tmp_path / "two" / "swa.pt"
    first, last = _weights(tmp_path / "one" / "last.pt"), _weights(tmp_path / "two" / "last.pt")
    average = torch.load(tmp_path / "two" / "swa.pt", map_location="cpu", weights_only=True)
    assert average["metrics"]["swa_epochs"] == 2 and 0.0 <= average["metrics"]["val_iou"] <= 1.0
    weights = average["model"]
    parameters = [k for k in weights if not k.endswith(("running_mean", "running_var", "num_batches_tracked"))]
    assert len(parameters) > 100
    for key in parameters:
        torch.testing.assert_close(weights[key], (first[key] + last[key]) / 2)
    # BatchNorm statistics belong to the average, not to the last epoch's weights
    stats = [k for k in weights if k.endswith("running_var")]
    assert sum(not torch.allclose(weights[k], last[k]) for k in stats) > len(stats) // 2
    # the average of an interrupted run continues where it stopped
    fit(two, tmp_path / "one", resume=True)
    _assert_same_weights(tmp_path / "two" / "swa.pt", tmp_path / "one" / "swa.pt")
    # without averaging the run's result stays best.pt, and no swa.pt is written
    assert train_model(tiny_config(dataset_root, epochs=1), tmp_path / "plain") == tmp_path / "plain" / "best.pt"
    assert not (tmp_path / "plain" / "swa.pt").exists()


def test_a_cut_architecture_trains_averages_and_refuses_a_resume_under_another_architecture(dataset_root, tmp_path):
    from segmin.train.run import fit, train_model

    cut = "lraspp_mobilenet_v3_large_cut13"
    result = train_model(tiny_config(dataset_root, epochs=1, swa_start_epoch=1, architecture=cut), tmp_path / "cut")
    model, info = load_model(result)
    assert result.name == "swa.pt" and info["architecture"] == cut
    assert not any(key.startswith("net.backbone.14.") for key in model.state_dict())
    with pytest.raises(ValueError, match="architecture=lraspp_mobilenet_v3_large_cut13, the config says"):
        fit(tiny_config(dataset_root, epochs=2), tmp_path / "cut", resume=True)


def test_ctrl_c_saves_a_checkpoint_and_resume_is_exact(dataset_root, tmp_path, monkeypatch):
    import segmin.train.loop as loop_module
    from segmin.train.run import fit

    config = tiny_config(dataset_root, epochs=2)
    fit(config, tmp_path / "straight")

    real_step = loop_module.train_step
    calls = {"n": 0}

    def interrupting_step(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:  # the first step of epoch 2 (2 steps per epoch)
            raise KeyboardInterrupt
        return real_step(*args, **kwargs)

    monkeypatch.setattr(loop_module, "train_step", interrupting_step)
    result = fit(config, tmp_path / "cut")
    assert result.interrupted
    state = torch.load(tmp_path / "cut" / "last.pt", map_location="cpu", weights_only=True)["training_state"]
    assert (state["epoch"], state["step"]) == (1, 0)
    monkeypatch.setattr(loop_module, "train_step", real_step)
    calls["n"] = 0

    def interrupting_after_one(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real_step(*args, **kwargs)

    monkeypatch.setattr(loop_module, "train_step", interrupting_after_one)
    assert fit(config, tmp_path / "cut", resume=True).interrupted
    state = torch.load(tmp_path / "cut" / "last.pt", map_location="cpu", weights_only=True)["training_state"]
    assert (state["epoch"], state["step"]) == (1, 1)  # mid-epoch: one step of epoch 2 done
    monkeypatch.setattr(loop_module, "train_step", real_step)
    assert not fit(config, tmp_path / "cut", resume=True).interrupted
    _assert_same_weights(tmp_path / "straight" / "last.pt", tmp_path / "cut" / "last.pt")


def test_held_out_validation_domains(tmp_path):
    train_root = write_blob_dataset(tmp_path / "train", "synth_vineyard_a", frames=6)
    val_root = write_blob_dataset(tmp_path / "val", "synth_straight_vineyard", frames=3, seed=1)
    config = tiny_config(train_root, epochs=1)
    config.data.val_root = val_root
    config.data.val_domains = ["synth_vineyards"]
    from segmin.train.loaders import select_frames

    train_frames, val_frames = select_frames(config)
    assert len(train_frames) == 6 and {f.domain for f in val_frames} == {"synth_straight_vineyard"}


def test_a_dataset_too_small_to_validate_on_is_named_as_such(tmp_path, capsys):
    """One frame with val_fraction 0.1 used to be told to "set data.val_fraction > 0": the split
    holds out a frame only from a domain of two or more, so the dataset is what is too small."""
    import yaml

    from segmin.app.cli import main
    from segmin.common.config import to_dict

    root = write_blob_dataset(tmp_path / "one", frames=1)
    data = {"root": str(root), "domains": ["synth_vineyards"], "val_fraction": 0.1}
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(to_dict(tiny_config(root, data=data))))
    assert main(["train", "--config", str(config), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "too small" in err, err
    assert "1 frame(s) (synth_vineyard_a: 1)" in err and "at least 2 frames" in err
    assert "val_fraction=0.1" in err and "set data.val_fraction > 0" not in err
    assert not (tmp_path / "run" / "last.pt").exists()


# ----------------------------------------------------------------------------- configs and CLI


@pytest.mark.parametrize("name", ["trees", "vineyards", "synth_trees", "synth_vineyards", "quick"])
def test_shipped_configs_load(name):
    config = load_train_config(CONFIGS / f"{name}.yaml")
    assert config.data.domains
    if name in ("trees", "vineyards"):
        assert (config.lr, config.epochs, config.image_size, config.batch_size) == (3e-4, 50, 224, 64)
        assert config.backbone_weights == "imagenet" and config.dice_weight == 0 and config.schedule == "none"
    if name == "quick":
        assert config.image_size < 224 and config.epochs <= 15  # a CPU demo: smaller and shorter than the paper


def test_config_is_strict_and_takes_overrides():
    config = load_train_config(CONFIGS / "trees.yaml", ["epochs=3", "data.val_fraction=0.2", "augment.gray_p=0"])
    assert config.epochs == 3 and config.data.val_fraction == 0.2 and config.augment.gray_p == 0
    with pytest.raises(ConfigError, match="epochz"):
        load_train_config(CONFIGS / "trees.yaml", ["epochz=3"])
    with pytest.raises(ConfigError, match="image_size=100: must be a positive multiple of 32"):
        load_train_config(CONFIGS / "trees.yaml", ["image_size=100"])


def test_train_cli_runs_and_resumes(dataset_root, tmp_path, capsys):
    from segmin.app.cli import main

    config = tmp_path / "tiny.yaml"
    import yaml

    from segmin.common.config import to_dict

    config.write_text(yaml.safe_dump(to_dict(tiny_config(dataset_root, epochs=1))))
    out = tmp_path / "cli_run"
    assert main(["train", "--config", str(config), "--out", str(out), "tensorboard=false"]) == 0
    assert "best val IoU" in capsys.readouterr().out
    assert main(["train", "--config", str(config), "--out", str(out), "epochs=2", "--resume"]) == 0
    assert len((out / "metrics.csv").read_text().splitlines()) == 3
    assert main(["train", "--config", str(config), "--out", str(tmp_path / "none"), "--resume"]) == 2


def test_bench_runs_and_reports_both_rates():
    from benchmarks.train import TrainBenchOptions, bench_train, report_lines

    result = bench_train(
        TrainBenchOptions(image_size=64, batch_size=2, threads=1, steps=1, warmup=1, workers=0, repeats=1)
    )
    assert result["model_step_ips"] > 0 and result["full_pipeline_ips"] > 0
    assert result["ratio"] == pytest.approx(result["full_pipeline_ips"] / result["model_step_ips"])
    assert result["model_step_nchw_ips"] > 0
    assert result["channels_last_speedup"] == pytest.approx(result["model_step_ips"] / result["model_step_nchw_ips"])
    verdict = "met" if result["ratio"] >= 0.9 else "NOT met"
    assert f"target full pipeline / model step >= 0.9: {verdict}" in "\n".join(report_lines(result))
    with pytest.raises(ValueError, match="--repeats 0: must be >= 1"):
        TrainBenchOptions(repeats=0)


def test_cpu_training_uses_channels_last_and_can_turn_it_off(tmp_path, dataset_root):
    """channels_last is a speed setting on every device: the same run in both layouts learns the same."""
    from segmin.train.run import fit

    results = {}
    for layout in (True, False):
        config = tiny_config(dataset_root, epochs=1, channels_last=layout, tensorboard=False)
        result = fit(config, tmp_path / f"cl_{layout}")
        state = torch.load(result.best_path, weights_only=True)["model"]
        conv = next(v for k, v in state.items() if v.ndim == 4 and v.shape[1] > 1 and v.shape[-1] > 1)
        results[layout] = (conv.is_contiguous(memory_format=torch.channels_last), result.history[-1]["train_loss"])
    assert results[True][0] and not results[False][0]
    assert results[True][1] == pytest.approx(results[False][1], rel=1e-2)


# ----------------------------------------------------------------------------- resolution ceiling


def test_output_grid_matches_the_models_logit_grid():
    from benchmarks.iou_bound import output_grid
    from segmin.models import build_model

    model = build_model("none").eval()
    for size in (40, 45, 64):
        with torch.no_grad():
            features = model.net.backbone(torch.zeros(1, 3, size, size))
        assert features["low"].shape[-1] == output_grid(size), size


def test_iou_bound_is_exact_on_cell_aligned_masks_and_lower_on_stripes():
    """Masks made of whole 8x8 cells are representable (ceiling ~1); 1-pixel stripes are not."""
    from benchmarks.iou_bound import iou_bound

    rng = np.random.default_rng(0)
    blocky = np.kron(rng.integers(0, 2, (4, 8, 8)), np.ones((8, 8))).astype(np.float32)
    result = iou_bound(blocky, steps=60)
    assert result.grid == 8 and result.frames == 4
    assert result.fitted_iou > 0.93 and result.area_iou > 0.9
    stripes = np.zeros((2, 64, 64), np.float32)
    stripes[:, :, ::2] = 1.0  # every other column: finer than any 8x8 logit grid can draw
    thin = iou_bound(stripes, steps=60)
    assert thin.fitted_iou < 0.7  # a perfect drawing would score 1.0
    assert thin.area_iou == 0.0  # every cell is exactly half covered: logit 0, nothing predicted


def test_bench_iou_bound_prints_both_ceilings(dataset_root, capsys):
    from benchmarks.cli import main

    assert main(["iou-bound", "--root", str(dataset_root), "--sizes", "32", "--frames", "4", "--steps", "20"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.strip().startswith("32"))
    _size, grid, frames, area, fitted = row.split()
    assert (grid, frames) == ("4x4", "4")
    assert 0.3 < float(area) <= 1.0 and 0.3 < float(fitted) <= 1.0  # blobs of 10-28 px: mostly representable


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--frames", "0"], "frames=0"),
        (["--sizes", "4"], "size=4"),
        (["--domains", "no_such_domain"], "no_such_domain"),
    ],
)
def test_bench_iou_bound_rejects_bad_input_with_one_line(dataset_root, capsys, extra, message):
    from benchmarks.cli import main

    assert main(["iou-bound", "--root", str(dataset_root), "--steps", "1", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("benchmarks: error:") and message in err and len(err.splitlines()) == 1


def test_train_refuses_to_replace_an_earlier_run_without_force(dataset_root, tmp_path, capsys):
    """A rerun on an existing --out used to overwrite best.pt/last.pt/metrics.csv silently."""
    import yaml

    from segmin.app.cli import main
    from segmin.common.config import to_dict
    from segmin.train.run import fit

    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(to_dict(tiny_config(dataset_root, epochs=1, tensorboard=False))))
    out = tmp_path / "run"
    assert main(["train", "--config", str(config), "--out", str(out)]) == 0
    before = (out / "last.pt").read_bytes(), (out / "metrics.csv").read_text()
    capsys.readouterr()
    with pytest.raises(FileExistsError, match="--force") as info:
        fit(tiny_config(dataset_root, epochs=1, tensorboard=False), out)
    assert "--resume" in str(info.value) and str(out) in str(info.value)
    assert main(["train", "--config", str(config), "--out", str(out), "--force", "--resume"]) == 2
    assert ((out / "last.pt").read_bytes(), (out / "metrics.csv").read_text()) == before
    (out / "previews" / "stale.png").write_bytes(b"old")
    assert main(["train", "--config", str(config), "--out", str(out), "--force", "seed=1"]) == 0
    assert not (out / "previews" / "stale.png").exists()  # --force starts over: old outputs are gone
    assert (out / "last.pt").read_bytes() != before[0]


def _metrics_without_seconds(run_dir: Path) -> list[str]:
    """metrics.csv without its last column (seconds: wall time, never the same twice)."""
    return [line.rsplit(",", 1)[0] for line in (run_dir / "metrics.csv").read_text().splitlines()]


def _interrupt_with_sigint_after(monkeypatch, step: int) -> None:
    """Ctrl-C as a user sends it, during training step number `step` (counted from 1 over the
    run): the signal lands after that step's weight update, before the step is counted."""
    import signal

    import segmin.train.loop as loop_module

    real_step = loop_module.train_step
    calls = {"n": 0}

    def step_then_sigint(*args, **kwargs):
        result = real_step(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] == step:
            signal.raise_signal(signal.SIGINT)
        return result

    monkeypatch.setattr(loop_module, "train_step", step_then_sigint)


def test_ctrl_c_inside_a_step_finishes_the_step_and_resume_is_exact(
    dataset_root, tmp_path, monkeypatch, sigint_delivered
):
    """A SIGINT landing after the optimizer update but before the step was counted
    used to save "k steps done" with the weights of k+1, so --resume ran a step twice.

    metrics.csv must match too: the interrupted epoch's train_loss is a mean over all its steps,
    those before the Ctrl-C included (their running sums travel in last.pt; they used to restart
    at zero, so the resumed epoch reported the mean of its remaining steps only).
    """
    from segmin.train.run import fit

    config = tiny_config(dataset_root, epochs=2, tensorboard=False)
    fit(config, tmp_path / "straight")
    with monkeypatch.context() as patch:
        _interrupt_with_sigint_after(patch, 3)  # first step of epoch 2 (2 steps per epoch)
        assert fit(config, tmp_path / "cut").interrupted
    state = torch.load(tmp_path / "cut" / "last.pt", map_location="cpu", weights_only=True)["training_state"]
    assert (state["epoch"], state["step"]) == (1, 1)  # the step in flight was finished and counted
    assert not fit(config, tmp_path / "cut", resume=True).interrupted
    _assert_same_weights(tmp_path / "straight" / "last.pt", tmp_path / "cut" / "last.pt")
    assert _metrics_without_seconds(tmp_path / "cut") == _metrics_without_seconds(tmp_path / "straight")


def test_resume_after_ctrl_c_continues_a_cosine_schedule_exactly(dataset_root, tmp_path, monkeypatch, sigint_delivered):
    """--resume restores the LR scheduler: one rebuilt from scratch steps a cosine schedule from
    its start again (epoch 3 trains at 0.56 x lr instead of 0.25 x). The other resume tests use
    a step schedule with step_size 1, where a fresh scheduler happens to land on the same rates."""
    from segmin.train.run import fit

    config = tiny_config(dataset_root, epochs=3, schedule="cosine", tensorboard=False)
    fit(config, tmp_path / "straight")
    with monkeypatch.context() as patch:
        _interrupt_with_sigint_after(patch, 3)  # first step of epoch 2 of 3
        assert fit(config, tmp_path / "cut").interrupted
    assert not fit(config, tmp_path / "cut", resume=True).interrupted
    _assert_same_weights(tmp_path / "straight" / "last.pt", tmp_path / "cut" / "last.pt")
    assert _metrics_without_seconds(tmp_path / "cut") == _metrics_without_seconds(tmp_path / "straight")  # lr column


def test_mid_epoch_checkpoints_let_a_killed_run_resume_exactly(dataset_root, tmp_path, monkeypatch):
    """A kill -9 during the first epoch left nothing to resume from."""
    import segmin.train.loop as loop_module
    from segmin.train.run import fit

    config = tiny_config(dataset_root, epochs=1, batch_size=2, tensorboard=False, checkpoint_every_steps=1)
    fit(config, tmp_path / "straight")
    real_step = loop_module.train_step
    calls = {"n": 0}

    def dying_step(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:  # like kill -9: no handler runs, nothing is saved at this point
            raise SystemExit("killed")
        return real_step(*args, **kwargs)

    monkeypatch.setattr(loop_module, "train_step", dying_step)
    with pytest.raises(SystemExit):
        fit(config, tmp_path / "killed")
    state = torch.load(tmp_path / "killed" / "last.pt", map_location="cpu", weights_only=True)["training_state"]
    assert (state["epoch"], state["step"]) == (0, 2)
    monkeypatch.setattr(loop_module, "train_step", real_step)
    fit(config, tmp_path / "killed", resume=True)
    _assert_same_weights(tmp_path / "straight" / "last.pt", tmp_path / "killed" / "last.pt")
    with pytest.raises(ConfigError, match="checkpoint_every_steps"):
        tiny_config(dataset_root, checkpoint_every_steps=0)


@pytest.mark.parametrize(
    "override, message",
    [
        ("threads=-1", "threads=-1"),
        ("device=gpu", "device='gpu'"),
        ("swa_start_epoch=0", "swa_start_epoch=0"),
        ("swa_start_epoch=9", r"swa_start_epoch=9: must be in \[1, epochs=8\]"),
    ],
)
def test_bad_runtime_settings_are_refused_by_the_config(override, message):
    """Threads=-1 and device=gpu failed (or not) deep inside torch."""
    with pytest.raises(ConfigError, match=message):
        load_train_config(CONFIGS / "quick.yaml", [override])


def test_missing_imagenet_weights_are_reported_before_any_data_is_read(tmp_path, monkeypatch, capsys):
    """The shipped trees/vineyards configs use imagenet; without the cached file the
    run scanned and checked the whole dataset first, then failed with a traceback."""
    from segmin.app.cli import main

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))
    code = main(
        [
            "train",
            "--config",
            str(CONFIGS / "trees.yaml"),
            "--out",
            str(tmp_path / "run"),
            "data.root=/nonexistent/data",
        ]
    )  # reading data would fail with another message
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "mobilenet_v3_large-8738ca79.pth" in err and "$TORCH_HOME/hub/checkpoints/" in err
    assert "/nonexistent" not in err
