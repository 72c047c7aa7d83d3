"""Bad inputs fail with one clear message naming the file or the field."""

from __future__ import annotations

import numpy as np
import pytest

from segmin.common.config import ConfigError


@pytest.mark.parametrize(
    "override, field",
    [
        ("rows.curve_radius=.nan", "rows.curve_radius"),
        ("rows.length=.inf", "rows.length"),
        ("rows.spacing=-.inf", "rows.spacing"),
    ],
)
def test_numeric_config_fields_reject_nan_and_inf_by_name(override, field):
    from segmin.data.synth.spec import load_world_spec

    with pytest.raises(ConfigError, match=f"{field}: .* is not a finite number"):
        load_world_spec("curved_vineyard", [override])


def test_nan_is_refused_in_every_config_family():
    from segmin.nav_eval.sim.config import load_nav_config
    from segmin.train.config import load_train_config

    with pytest.raises(ConfigError, match="lr"):
        load_train_config("quick", ["lr=.nan"])
    with pytest.raises(ConfigError, match="depth_thresholds.straight_vineyard"):
        load_nav_config(overrides=["depth_thresholds.straight_vineyard=.nan"])


def test_a_binary_config_file_is_named(tmp_path):
    from segmin.train.config import load_train_config

    bad = tmp_path / "binary.yaml"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    with pytest.raises(ConfigError, match="binary.yaml: not a text"):
        load_train_config(bad)


@pytest.mark.parametrize("content", [b"\xff\xfe\x00\x01binary", b'{"format": "segmin-split-v1", "train": [3]}'])
def test_a_bad_split_file_is_named(tmp_path, content):
    from segmin.data.agriseg_loader import DatasetError, load_split

    bad = tmp_path / "split.json"
    bad.write_bytes(content)
    with pytest.raises(DatasetError, match="split.json"):
        load_split(bad, [])


def test_dataset_image_size_must_be_positive(tmp_path):
    from segmin.data.agriseg_loader import AgriSegDataset
    from tests.test_train import write_blob_dataset

    root = write_blob_dataset(tmp_path, frames=2, size=16)
    with pytest.raises(ValueError, match="image_size=0"):
        AgriSegDataset(root, split="all", image_size=0)


def test_a_metadata_threshold_that_is_not_a_number_is_named():
    from segmin.export import metadata as md

    meta = {
        md.KEY_FORMAT: md.FORMAT,
        md.KEY_INPUT_LAYOUT: "NHWC",
        md.KEY_CHANNEL_ORDER: "RGB",
        md.KEY_INPUT_SIZE: "64,64",
        md.KEY_THRESHOLD: "abc",
    }
    meta = {k: meta.get(k, "x") for k in md.REQUIRED_KEYS} | meta
    with pytest.raises(ValueError, match="model.onnx: metadata .*'abc' is not a number"):
        md.check_metadata(meta, "model.onnx")


def test_a_numpy_depth_threshold_is_a_number():
    from segmin.nav_eval.runtime.navigator import Navigator, NavigatorConfig, target_column

    mask = np.zeros((8, 16), bool)
    depth = np.ones((8, 16), np.float32)
    assert target_column(mask, depth, method="segmin", depth_threshold=np.float32(5.0)) == 7.5
    Navigator(NavigatorConfig(method="segmind", depth_threshold=np.float32(5.0))).step(mask, depth)
    with pytest.raises(ValueError, match="depth_threshold"):
        NavigatorConfig(method="segmin", depth_threshold=np.float32("nan"))


def test_preview_zero_frames_is_refused(tmp_path, capsys):
    from segmin.app.cli import main

    assert (
        main(["synth", "preview", "--world", "straight_vineyard", "--frames", "0", "--out", str(tmp_path / "p.png")])
        == 2
    )
    assert "--frames: must be >= 1, got 0" in capsys.readouterr().err


@pytest.mark.parametrize(
    "family, refused, accepted, message",
    [
        # straight_vineyard's plants are 1.85-2.1 m tall: a trunk must split below that.
        ("world", "plants.trunk_height=[0.6, 1.85]", "plants.trunk_height=[0.6, 1.84]", "plants.trunk_height"),
        ("train", "augment.crop_ratio=[1.5, 0.75]", "augment.crop_ratio=[0.75, 1.5]", "crop_ratio"),
        ("train", "augment.crop_ratio=[0.0, 1.0]", "augment.crop_ratio=[0.5, 1.0]", "crop_ratio"),
        # A negative margin puts the "left_row" line ahead of the start: every run fails at t = 0.
        ("nav", "run.back_margin_m=-0.5", "run.back_margin_m=0.0", "run.back_margin_m must be >= 0"),
    ],
)
def test_lower_and_upper_limits_are_checked_together(family, refused, accepted, message):
    from segmin.data.synth.spec import load_world_spec
    from segmin.nav_eval.sim.config import load_nav_config
    from segmin.train.config import load_train_config

    load = {
        "world": lambda o: load_world_spec("straight_vineyard", o),
        "train": lambda o: load_train_config("quick", o),
        "nav": lambda o: load_nav_config(overrides=o),
    }[family]
    with pytest.raises(ConfigError, match=message):
        load([refused])
    load([accepted])


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["synth", "--fields", "no_such_world", "--frames", "1"], "no_such_world"),
        (["iou-bound", "--root", ".", "--sizes", "64", "0"], "size=0"),
    ],
)
def test_a_bench_refuses_bad_input_before_printing_its_table(argv, named, capsys) -> None:
    from benchmarks.cli import main

    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == ""  # no table header above the error
    assert named in err and len(err.strip().splitlines()) == 1
