"""Shipped models by name: the registry, `segmin models release / list`, model cards, `--model vineyards`."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from segmin.app.cli import main as segmin_main
from segmin.app.pipeline.cache import StageCache
from segmin.nav_eval.runtime.segmenter import OnnxSegmenter
from segmin.nav_eval.runtime.shipped_models import ENV_MODELS_DIR, resolve_model, shipped_model


@pytest.fixture()
def registry(tmp_path, monkeypatch) -> Path:
    """An empty registry folder in place of the package's (tests never write into the package)."""
    root = tmp_path / "registry"
    monkeypatch.setenv(ENV_MODELS_DIR, str(root))
    return root


def _record(cache: StageCache, stage: str, outputs: dict, seconds: float = 1.0) -> None:
    cache.finished(stage, "hash", seconds, outputs, files={}, reads={})


@pytest.fixture()
def pipeline_run(tmp_path, exported) -> Path:
    """A pipeline run folder as `segmin pipeline` leaves it, with the tiny exported model as vineyards."""
    run = tmp_path / "run"
    cache = StageCache(run)
    (run).mkdir()
    (run / "pipeline.yaml").write_text("profile: tiny\nfamilies: {}\n")
    for split, world, count in (("train", "synth_vineyard_a", 3), ("val", "synth_val_vineyard_a", 2)):
        for i in range(count):
            frame = run / "render" / split / world / f"{world}_1" / "images" / f"Image{i}" / f"Image{i}.png"
            frame.parent.mkdir(parents=True)
            frame.write_bytes(b"png")
    _record(
        cache, "render", {"domains": {"vineyards": {"train": ["synth_vineyard_a"], "val": ["synth_val_vineyard_a"]}}}
    )
    _record(
        cache,
        "train/vineyards",
        {
            "epochs": 2,
            "image_size": 64,
            "backbone_weights": "none",
            "kept": "swa",
            "kept_val_iou": 0.71,
            "architecture": "lraspp_mobilenet_v3_large",
            "machine": "test box, 2 CPU cores",
        },
        seconds=600.0,  # the last process's share only: the training was resumed
    )
    # Every epoch's time, across resumes: 200 + 262 s, where the record has the last process's 600 s.
    rows = "epoch,train_loss,val_iou,seconds\n1,0.5,0.6,200\n2,0.4,0.7,262\n"
    (run / "train" / "vineyards" / "metrics.csv").write_text(rows)
    onnx = run / "export" / "vineyards" / "vineyards.onnx"
    onnx.parent.mkdir(parents=True)
    shutil.copy(exported[0], onnx)
    latency = {"median": 2.5, "p95": 3.0, "threads": 2, "frame_size": [224, 224], "frames": 50}
    _record(
        cache,
        "export/vineyards",
        {"onnx": "somewhere/else/vineyards.onnx", "input_size": [64, 64], "latency_ms": latency},
    )
    real = {
        "images": 8,
        "mean_iou": 0.61,
        "pooled_iou": 0.6,
        "precision": 0.64,
        "recall": 0.8,
        "mean_precision": 0.66,
        "mean_recall": 0.82,
        "threshold": 0.5,
    }
    _record(cache, "real-eval/vineyards", real)
    sheet = np.zeros((40, 90, 3), np.uint8)
    sheet[:, 30:60] = (0, 200, 0)  # the errors panel's green
    cv2.imwrite(str(run / "real-eval" / "vineyards" / "contact_sheet.png"), sheet)
    rows = [
        {"field": "straight_vineyard", "method": "segmind", "success": ok, "mae": mae}
        for ok, mae in ((True, 0.1), (False, 0.3))
    ]
    (run / "nav-eval" / "vineyards").mkdir(parents=True)
    (run / "nav-eval" / "vineyards" / "results.json").write_text(json.dumps({"rows": rows}))
    _record(cache, "nav-eval/vineyards", {"results": "x/results.json", "runs": 2, "successes": 1})
    return run


def test_release_ships_the_model_with_its_card_and_the_name_resolves(pipeline_run, registry, capsys) -> None:
    assert segmin_main(["models", "release", "--run", str(pipeline_run)]) == 0
    shipped = ["vineyards.card.json", "vineyards.md", "vineyards.onnx", "vineyards.real.jpg"]
    assert sorted(p.name for p in registry.iterdir()) == shipped
    sheet = cv2.imread(str(registry / "vineyards.real.jpg"))
    assert sheet.shape == (40, 90, 3) and abs(int(sheet[20, 45, 1]) - 200) < 8 and sheet[20, 10].max() < 8
    segmenter = OnnxSegmenter("vineyards", threads=1)
    assert segmenter.path == registry / "vineyards.onnx"
    assert segmenter.segment(np.zeros((48, 64, 3), np.uint8)).shape == (48, 64)
    card_text = (registry / "vineyards.md").read_text()
    assert segmenter.metadata["model_card"] == card_text
    card = json.loads(segmenter.metadata["model_card_json"])
    assert card == shipped_model("vineyards").card()
    assert card["data"] == {
        "train_worlds": ["synth_vineyard_a"],
        "val_worlds": ["synth_val_vineyard_a"],
        "train_frames": 3,
        "val_frames": 2,
    }
    assert card["recipe"]["profile"] == "tiny" and len(card["recipe"]["config_sha256"]) == 16
    assert card["real_photos"]["shipped_photos"] is False  # its real-eval record names no photo folder
    assert card["closed_loop"] == [
        {
            "field": "straight_vineyard",
            "method": "segmind",
            "runs": 2,
            "successes": 1,
            "mae": pytest.approx(0.2),
            "mae_successful": pytest.approx(0.1),
        }
    ]
    for text in (
        "7.7 min of epochs on test box, 2 CPU cores",
        "mean IoU 0.610",
        "precision 0.640",
        "| straight_vineyard | segmind | 1/2 | 0.200 | 0.100 |",
        "MIT",
        "contact sheet `vineyards.real.jpg` beside this card",
    ):
        assert text in card_text, text
    capsys.readouterr()
    assert segmin_main(["models", "list"]) == 0
    listed = capsys.readouterr().out
    assert "vineyards: vineyards.onnx" in listed and "val IoU 0.710, real IoU 0.610 (precision 0.640)" in listed
    assert "closed loop 1/2 runs succeeded" in listed and "trees: not in this install" in listed


def test_release_never_replaces_a_model_without_force(pipeline_run, registry, capsys) -> None:
    registry.mkdir(parents=True, exist_ok=True)
    (registry / "vineyards.md").write_text("a card left without its model")
    assert segmin_main(["models", "release", "--run", str(pipeline_run)]) == 2  # any file of the family counts
    assert "vineyards.md: already released (use --force" in capsys.readouterr().err
    assert (registry / "vineyards.md").read_text() == "a card left without its model"
    (registry / "vineyards.md").unlink()
    assert segmin_main(["models", "release", "--run", str(pipeline_run)]) == 0
    before = (registry / "vineyards.onnx").read_bytes()
    assert segmin_main(["models", "release", "--run", str(pipeline_run)]) == 2
    assert "already released (use --force" in capsys.readouterr().err
    assert segmin_main(["models", "release", "--run", str(pipeline_run), "--force"]) == 0
    assert (registry / "vineyards.onnx").read_bytes() == before  # the same run gives the same file
    (pipeline_run / "real-eval" / "vineyards" / "contact_sheet.png").unlink()
    assert segmin_main(["models", "release", "--run", str(pipeline_run), "--force"]) == 2
    assert "contact_sheet.png: the scored model's real-photo contact sheet is missing" in capsys.readouterr().err
    (pipeline_run / "real-eval" / "vineyards" / "stage.json").unlink()  # a run that scored no photos
    assert segmin_main(["models", "release", "--run", str(pipeline_run), "--force"]) == 0
    assert not (registry / "vineyards.real.jpg").exists()  # not the replaced model's sheet
    assert "real photos: not measured" in (registry / "vineyards.md").read_text()
    assert segmin_main(["models", "release", "--run", str(pipeline_run), "--families", "apples"]) == 2
    assert "--families apples: not a shipped model name (shipped: vineyards, trees)" in capsys.readouterr().err
    assert segmin_main(["models", "release", "--run", str(registry)]) == 2
    assert "not a segmin pipeline run folder" in capsys.readouterr().err


def _add_trees(run: Path, onnx_bytes: bytes) -> None:
    """A second exported family in the run, its ONNX file holding `onnx_bytes`."""
    cache = StageCache(run)
    _record(cache, "train/trees", {"epochs": 1, "image_size": 64, "kept": "last", "kept_val_iou": 0.5})
    onnx = run / "export" / "trees" / "trees.onnx"
    onnx.parent.mkdir(parents=True)
    onnx.write_bytes(onnx_bytes)
    _record(cache, "export/trees", {"onnx": str(onnx), "input_size": [64, 64]})


def _with_input_size(path: Path, size: str) -> bytes:
    import onnx

    model = onnx.load(str(path))
    next(p for p in model.metadata_props if p.key == "input_size").value = size
    return model.SerializeToString()


def test_a_release_that_fails_on_any_family_writes_nothing(pipeline_run, registry, capsys) -> None:
    """Every family's files are checked before the first is written: a bad second family used to
    leave the first already replaced (the shipped model gone, although the release failed)."""
    registry.mkdir()
    for name in ("vineyards.onnx", "vineyards.md", "vineyards.card.json", "vineyards.real.jpg"):
        (registry / name).write_bytes(b"shipped " + name.encode())
    exported = (pipeline_run / "export" / "vineyards" / "vineyards.onnx").read_bytes()
    trees = pipeline_run / "export" / "trees" / "trees.onnx"
    _add_trees(pipeline_run, exported[: len(exported) // 2])
    for broken, problem in (
        (exported[: len(exported) // 2], "not a readable ONNX model"),
        (
            _with_input_size(pipeline_run / "export" / "vineyards" / "vineyards.onnx", "abc"),
            "metadata input_size='abc'",
        ),
    ):
        trees.write_bytes(broken)
        assert segmin_main(["models", "release", "--run", str(pipeline_run), "--force"]) == 2
        err = capsys.readouterr().err.strip()
        assert f"{trees}: " in err and problem in err and "\n" not in err
        assert sorted(p.name for p in registry.iterdir()) == [
            "vineyards.card.json",
            "vineyards.md",
            "vineyards.onnx",
            "vineyards.real.jpg",
        ]
        assert (registry / "vineyards.onnx").read_bytes() == b"shipped vineyards.onnx"
    # A release killed while writing leaves its temporaries; the next release removes them.
    (registry / ".vineyards.onnx.k1ll3d.tmp").write_bytes(b"half a model")
    (registry / ".trees.card.json.k1ll3d.tmp").write_bytes(b"half a card")
    trees.write_bytes(exported)
    assert segmin_main(["models", "release", "--run", str(pipeline_run), "--force"]) == 0
    assert sorted(p.name for p in registry.iterdir() if p.name.startswith(".")) == []
    assert (registry / "vineyards.onnx").read_bytes() != b"shipped vineyards.onnx" and (
        registry / "trees.onnx"
    ).is_file()


@pytest.mark.parametrize(
    "edit, field",
    [
        ({"real_photos": "good"}, 'field real_photos: expected a JSON object or null, got "good"'),
        ({"synthetic_val_iou": "0.7"}, "field synthetic_val_iou: expected a number or null"),
        ({"latency": {"median": [2.5]}}, "field latency.median: expected a number or null"),
        ({"closed_loop": [{"runs": "2", "successes": 1}]}, "field closed_loop[0].runs: expected a whole number"),
        ({"closed_loop": ["all"]}, "field closed_loop[0]: expected a JSON object"),
    ],
)
def test_models_list_names_the_card_and_the_field_of_a_wrong_type(pipeline_run, registry, capsys, edit, field) -> None:
    assert segmin_main(["models", "release", "--run", str(pipeline_run)]) == 0
    card_path = registry / "vineyards.card.json"
    card_path.write_text(json.dumps(json.loads(card_path.read_text()) | edit))
    capsys.readouterr()
    assert segmin_main(["models", "list"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{card_path}: not a model card ({field}" in err and "\n" not in err


def test_a_name_without_a_file_and_an_unknown_name_are_one_clear_line(registry, tmp_path, capsys) -> None:
    with pytest.raises(ValueError, match="model trees: a shipped model name, but this install has no trees.onnx yet"):
        OnnxSegmenter("trees")
    with pytest.raises(ValueError, match=r"model 'vinyards': no such file, and not a shipped model name \(shipped"):
        OnnxSegmenter("vinyards")
    with pytest.raises(FileNotFoundError, match="missing.onnx: ONNX model not found"):
        resolve_model(tmp_path / "missing.onnx")
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "f_0.png"), np.zeros((8, 8, 3), np.uint8))
    replay = ["replay", "--rgb", str(frames), "--fps", "30", "--method", "segmin", "--depth-threshold", "5"]
    code = segmin_main([*replay, "--model", "vineyards", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "--model vineyards: a shipped model name" in err and len(err.strip().splitlines()) == 1


def test_a_shipped_name_in_a_ros2_parameter_file_is_not_read_from_the_files_folder(tmp_path) -> None:
    from segmin.nav_eval.ros2.params import node_params

    assert node_params({"model": "vineyards"}, base=tmp_path).node.model == "vineyards"
    assert node_params({"model": "mine.onnx"}, base=tmp_path).node.model == str(tmp_path / "mine.onnx")


def test_models_list_runs_without_torch_or_onnx(registry) -> None:
    """The bare robot install has neither: the list reads the cards' JSON only."""
    import subprocess
    import sys

    probe = (
        "import sys; from segmin.app.cli import main; main(['models', 'list']); "
        "print('heavy:', [m for m in ('torch', 'onnx') if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert "vineyards: not in this install" in out and "heavy: []" in out


@pytest.mark.parametrize("name", ["vineyards", "trees"])
def test_the_package_cards_are_what_the_card_code_writes_and_the_onnx_carries(name, monkeypatch) -> None:
    """A card's Markdown, JSON and the ONNX metadata agree, so the card code and the shipped files never drift."""
    from segmin.app.model_card import card_markdown

    monkeypatch.delenv(ENV_MODELS_DIR, raising=False)
    model = shipped_model(name)
    card = model.card()
    assert card is not None and model.present
    assert card_markdown(card) == model.card_markdown.read_text(encoding="utf-8")
    metadata = OnnxSegmenter(name, threads=1).metadata
    assert json.loads(metadata["model_card_json"]) == card
    assert metadata["model_card"] == card_markdown(card)


def test_the_pipeline_report_shows_the_shipped_cards_mae_over_all_and_successful_runs() -> None:
    """A run that left the row early has a short path: the report keeps its MAE apart from the full runs'."""
    from segmin.app.pipeline.report import _closed_loop

    row = {"field": "high_trees", "method": "segmind", "runs": 3, "successes": 0, "mae": 0.5, "mae_successful": None}
    lines = _closed_loop([], [], {"trees": {"closed_loop": [row]}})
    assert "| trees | high_trees | segmind | 0/3 | 0.500 | n/a |" in lines


def test_a_card_released_before_the_looks_were_kept_says_them_all_and_how_the_model_was_chosen() -> None:
    """The shipped cards predate the per-run count: they carry the looks since, and whether the
    model was chosen among candidates scored on the photos (then its figures are no clean test)."""
    from segmin.app.model_card import _looks

    chosen = _looks({"looks": {"in_all": 12, "chosen_with_them": True}})
    assert (
        chosen
        == " looked at 12 times in all for models of this recipe, this model chosen among candidates scored on it"
    )
    assert _looks({"looks": {"in_all": 5, "chosen_with_them": False}}) == (
        " looked at 5 times in all for models of this recipe"
    )
    for name, count in (("vineyards", 12), ("trees", 5)):
        card = shipped_model(name).card()
        assert card is not None and card["real_photos"]["looks"]["in_all"] == count
